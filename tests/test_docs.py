"""The documentation stays a user's README plus pages under docs/ that say what the code does now.

Checked: README.md is under 20 KB; every relative link (and image) of README.md and docs/*.md points to a file of
the repository that exists, and an anchor to a heading of that file; README, docs, and the docstrings and comments of
the package, templates, scripts and tests name no issue number and no commit hash (a history of fixes belongs to
the version control, not to the text that describes the code). Data is not prose: hashes inside file names, string
literals of code (SHA-256 values, canaries) and numbers are not looked at.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
README_MAX_BYTES = 20 * 1024

ISSUE_REFERENCE = re.compile(r"\bissues?\s*#?\s*\d+|\(#\d+\)", re.IGNORECASE)
"""The word issue (or issues) followed by a number, with or without '#', and a bare '#' number in parentheses."""
TOKEN = re.compile(r"[A-Za-z0-9_./-]+")
"""A word with the characters of paths and file names, so a hash inside a file name is part of a longer word."""
HASH_LIKE = re.compile(r"[0-9a-f]{7,40}")


def markdown_files() -> list[Path]:
    return [README, *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "nerfify_ns").rglob("*.md"))]


def commit_hashes(text: str) -> list[str]:
    """Words that read as an abbreviated or full commit hash: 7 to 40 hex digits, at least one digit and one letter
    (so '1000000' and 'defaced' are not), standing alone (not part of a file name or path)."""
    found = []
    for match in TOKEN.finditer(text):
        word = match.group(0).strip("./-")
        if HASH_LIKE.fullmatch(word) and re.search(r"\d", word) and re.search(r"[a-f]", word):
            found.append(word)
    return found


def problems(text: str) -> list[str]:
    """Issue references and commit hashes in a piece of prose."""
    return ([f"issue reference {m.group(0)!r}" for m in ISSUE_REFERENCE.finditer(text)]
            + [f"commit-hash-like word {w!r}" for w in commit_hashes(text)])


def python_prose(source: str) -> list[tuple[int, str]]:
    """(line, text) of every comment and every string that stands as a statement (module, class, function and
    attribute docstrings) of a Python source; other string literals are data."""
    prose = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            prose.append((tok.start[0], tok.string))
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
                and isinstance(node.value.value, str)):
            prose.append((node.lineno, node.value.value))
    return prose


HASH_COMMENT = re.compile(r"(?:^|\s)#(?![!{])(.*)$")
"""A '#' comment of YAML or shell: at the start of a line or after whitespace (not a '#!' line, not Jinja '{#')."""


def hash_comments(source: str) -> list[tuple[int, str]]:
    return [(no, m.group(1)) for no, line in enumerate(source.splitlines(), 1)
            if (m := HASH_COMMENT.search(line))]


def code_files() -> list[Path]:
    roots = [ROOT / "nerfify_ns", ROOT / "templates", ROOT / "scripts", ROOT / "method_configs", ROOT / "tests"]
    files = [ROOT / "grammar_spec.yaml", ROOT / "hatch_build.py", ROOT / ".ci" / "run"]
    for root in roots:
        files += [p for p in root.rglob("*") if p.is_file() and p.suffix in {".py", ".yaml", ".yml", ".sh", ".j2"}
                  and "__pycache__" not in p.parts and "broken_plugins" not in p.parts and "data" not in p.parts]
    return sorted(f for f in files if f.exists())


def prose_of(path: Path) -> list[tuple[int, str]]:
    source = path.read_text(encoding="utf-8", errors="replace")
    if not problems(source):
        return []  # nothing that reads as an issue or a hash anywhere in the file: no need to parse it
    if path.suffix == ".py":
        try:
            return python_prose(source)
        except (SyntaxError, tokenize.TokenError):
            return [(1, source)]  # a file that does not parse is checked whole
    if path.suffix == ".j2":
        return [(1, source)]  # a template's text becomes the generated plugin's docstrings and comments
    return hash_comments(source)


# -- the detectors themselves -------------------------------------------------------------------------------------

@pytest.mark.parametrize("text", [
    "against what issue 14 asked", "(issues 4 and 6)", "Issue #12's done-when", "fixed in (#31)",
    "from a fresh clone (at 82b74c4)", "again at 2c3ab2f: 18 min", "checkout 99defa6.",
    "commit 0d01ab7bd5e8c2a41f1d5c7a7e9a0b3c4d5e6f70",
])
def test_the_detectors_catch_issue_numbers_and_commit_hashes(text):
    assert problems(text)


@pytest.mark.parametrize("text", [
    "torchvision's `alexnet-owt-7be5be79.pth`", "range [1, 10000000]", "a numbered issue list", "the issues found",
    "sha256 a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b", "0xC000003E", "deadbeefcafe",
    "`.NAME.partial-PID-HEX`", "/tmp/run/.out.partial-123-0123abcd", "1.0e-06", "ulimit -v 6291456",
])
def test_the_detectors_leave_data_alone(text):
    assert not problems(text)


def test_python_prose_is_comments_and_docstrings_not_literals():
    source = ('"""Module (issue 3)."""\nX = "sk-canary-7f3a9c1e5b"  # issue 4\nY = 1\n'
              '"""Y\'s docstring at 1a2b3c4d."""\n')
    prose = " ".join(text for _, text in python_prose(source))
    assert "issue 3" in prose and "issue 4" in prose and "1a2b3c4d" in prose
    assert "7f3a9c1e5b" not in prose


# -- the README ---------------------------------------------------------------------------------------------------

def test_the_readme_is_under_20_kb():
    size = README.stat().st_size
    assert size < README_MAX_BYTES, (f"README.md is {size} bytes ({size / 1024:.1f} KB); keep it a user's page under "
                                     f"{README_MAX_BYTES // 1024} KB and move the rest to docs/")


# -- links --------------------------------------------------------------------------------------------------------

FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^#{1,6}\s+(.+?)\s*#*\s*$", re.MULTILINE)


def without_code(text: str) -> str:
    return INLINE_CODE.sub("", FENCE.sub("", text))


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: its text (links reduced to their text) lower-cased, everything but
    letters, digits, '_', '-' and spaces removed, spaces turned into '-'."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    result = set()
    for heading in HEADING.findall(FENCE.sub("", path.read_text(encoding="utf-8"))):
        base = slug(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        result.add(base if n == 0 else f"{base}-{n}")
    return result


def dead_links(path: Path, root: Path = ROOT) -> list[str]:
    dead = []
    root = root.resolve()
    for target in LINK.findall(without_code(path.read_text(encoding="utf-8"))):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):  # http:, https:, mailto: ...
            continue
        file_part, _, anchor = target.partition("#")
        resolved = (path.parent / file_part).resolve() if file_part else path
        if root not in resolved.parents and resolved != root:
            dead.append(f"{target}: outside the repository")
        elif not resolved.exists():
            dead.append(f"{target}: no such file")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            dead.append(f"{target}: no heading with anchor #{anchor} in {resolved.relative_to(root)}")
    return dead


def test_the_link_checker_finds_dead_links(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "a.md").write_text("# A page\n\n## The sandbox (`x/y.py`)\n")
    page = tmp_path / "README.md"
    page.write_text("[ok](docs/a.md) [ok](docs/a.md#the-sandbox-xypy) [web](https://example.org) `[no](code.md)`\n"
                    "[gone](docs/b.md) [bad anchor](docs/a.md#nope) [out](../shared/DESIGN.md)\n```\n[x](y.md)\n```\n")
    assert [d.split(":")[0] for d in dead_links(page, tmp_path)] == [
        "docs/b.md", "docs/a.md#nope", "../shared/DESIGN.md"]


@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_to_files_that_exist(path):
    dead = dead_links(path)
    assert not dead, f"{path.relative_to(ROOT)}: dead links: " + "; ".join(dead)


# -- no issue numbers or commit hashes ----------------------------------------------------------------------------

@pytest.mark.parametrize("path", markdown_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_documentation_names_no_issue_number_or_commit_hash(path):
    found = [f"line {no}: {p}" for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             for p in problems(line)]
    assert not found, f"{path.relative_to(ROOT)}: " + "; ".join(found)


def test_docstrings_and_comments_name_no_issue_number_or_commit_hash():
    found = [f"{path.relative_to(ROOT)}:{no}: {p}" for path in code_files() for no, text in prose_of(path)
             for p in problems(text)]
    assert not found, "say what the code does, not which issue or commit it came from:\n" + "\n".join(found)


def test_the_index_maps_every_page_of_docs():
    index = ROOT / "docs" / "index.md"
    linked = {(index.parent / target.partition("#")[0]).resolve()
              for target in LINK.findall(without_code(index.read_text(encoding="utf-8")))}
    unlisted = [p.name for p in sorted((ROOT / "docs").glob("*.md")) if p != index and p.resolve() not in linked]
    assert not unlisted, f"docs/index.md does not link {', '.join(unlisted)}"
