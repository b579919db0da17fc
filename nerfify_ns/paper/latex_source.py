"""LaTeX sources: find the main file, extract tarballs safely, follow \\input/\\include, expand macros."""

from __future__ import annotations

import re
import tarfile
from bisect import bisect_right
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Optional

from nerfify_ns.paper.errors import MissingLatexFileError, UnsafeArchiveError, UnsupportedInputError

MAX_INPUT_DEPTH = 20


# ----- archives ---------------------------------------------------------------------------------------
def safe_extract(archive: Path, dest: Path) -> Path:
    """Extract a .tar/.tar.gz/.tgz into ``dest``, refusing absolute paths, ``..``, links and devices."""
    try:
        with tarfile.open(archive) as tar:
            members = tar.getmembers()
            for m in members:
                p = PurePosixPath(m.name)
                if p.is_absolute() or ".." in p.parts or m.name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", m.name):
                    raise UnsafeArchiveError(f"{archive.name}: member '{m.name}' would escape the extraction folder; "
                                             "repack the sources with relative paths")
                if m.issym() or m.islnk() or m.isdev() or m.isfifo():
                    raise UnsafeArchiveError(f"{archive.name}: member '{m.name}' is a link or device; "
                                             "repack the sources with plain files only")
            for m in members:
                tar.extract(m, dest, set_attrs=False)
    except tarfile.TarError as e:
        raise UnsupportedInputError(f"{archive.name}: not a readable tar archive ({e}); pass the .tex file or folder") from e
    return dest


# ----- main file --------------------------------------------------------------------------------------
def find_main_file(folder: Path) -> Path:
    """The .tex file with \\documentclass (and \\begin{document}); the biggest such one on ties."""
    candidates = []
    for tex in sorted(folder.rglob("*.tex")):
        head = tex.read_text(encoding="utf-8", errors="replace")
        score = ("\\documentclass" in head) * 2 + ("\\begin{document}" in head)
        if score:
            candidates.append((score, len(head), tex))
    if not candidates:
        raise UnsupportedInputError(f"{folder}: no .tex file with \\documentclass or \\begin{{document}}; "
                                    "pass the main .tex file")
    return max(candidates, key=lambda c: (c[0], c[1]))[2]


# ----- flattening with a line map ---------------------------------------------------------------------
def strip_comments(text: str) -> str:
    """Remove ``%`` comments (not ``\\%``), keeping line breaks so line numbers stay right."""
    return re.sub(r"(?<!\\)%[^\n]*", "", text)


@dataclass
class Flat:
    """The flattened source and, per line of it, the (file, line) it came from."""

    text: str = ""
    origins: list[tuple[str, int]] = field(default_factory=list)
    line_starts: list[int] = field(default_factory=list)

    def where(self, offset: int) -> tuple[str, int]:
        i = max(0, bisect_right(self.line_starts, offset) - 1)
        return self.origins[i] if self.origins else ("", 0)


_INPUT = re.compile(r"\\(?:input|include|subfile)\s*\{([^}]+)\}|\\input\s+([^\s{}\\]+)")


def flatten(main: Path, root: Optional[Path] = None) -> Flat:
    """The main file with every \\input/\\include inlined (comments stripped)."""
    root = root or main.parent
    lines: list[tuple[str, str, int]] = []
    _inline(main, root, lines, depth=0)
    flat = Flat()
    pos = 0
    parts = []
    for text, fname, lineno in lines:
        flat.line_starts.append(pos)
        flat.origins.append((fname, lineno))
        parts.append(text)
        pos += len(text) + 1
    flat.text = "\n".join(parts)
    return flat


def _resolve(name: str, root: Path, here: Path) -> Optional[Path]:
    for base in (root, here):
        for cand in (base / name, base / f"{name}.tex"):
            if cand.is_file():
                return cand
    return None


def _inline(path: Path, root: Path, out: list, depth: int) -> None:
    if depth > MAX_INPUT_DEPTH:
        raise UnsupportedInputError(f"{path.name}: \\input nesting deeper than {MAX_INPUT_DEPTH}; is there a cycle?")
    rel = str(path.relative_to(root)) if path.is_relative_to(root) else path.name
    text = strip_comments(path.read_text(encoding="utf-8", errors="replace"))
    for lineno, line in enumerate(text.split("\n"), start=1):
        pos = 0
        for m in _INPUT.finditer(line):
            name = (m.group(1) or m.group(2)).strip()
            target = _resolve(name, root, path.parent)
            if target is None:
                raise MissingLatexFileError(f"{rel}:{lineno}: \\input/\\include file '{name}' not found; "
                                            "add it to the sources or remove the \\input")
            out.append((line[pos:m.start()], rel, lineno))
            _inline(target, root, out, depth + 1)
            pos = m.end()
        out.append((line[pos:], rel, lineno))


# ----- macros -----------------------------------------------------------------------------------------
def read_group(text: str, i: int) -> tuple[str, int]:
    """The balanced ``{...}`` group starting at (or after blanks from) ``i``: (content, index after it)."""
    while i < len(text) and text[i] in " \t\n":
        i += 1
    if i >= len(text) or text[i] != "{":
        if i < len(text) and text[i] == "\\":
            m = re.match(r"\\[A-Za-z]+|\\.", text[i:])
            return m.group(0), i + len(m.group(0))
        return (text[i], i + 1) if i < len(text) else ("", i)
    depth = 0
    for j in range(i, len(text)):
        if text[j] == "{" and (j == 0 or text[j - 1] != "\\"):
            depth += 1
        elif text[j] == "}" and text[j - 1] != "\\":
            depth -= 1
            if depth == 0:
                return text[i + 1:j], j + 1
    return text[i + 1:], len(text)


@dataclass
class Macro:
    name: str
    nargs: int
    body: str
    default: Optional[str] = None


_DEF_START = re.compile(r"\\(?:(?:re)?newcommand|providecommand|DeclareRobustCommand)\*?\s*|\\def\s*|"
                        r"\\DeclareMathOperator\*?\s*")


def collect_macros(text: str) -> tuple[dict[str, Macro], str]:
    """Macro definitions of ``text`` and the text with them blanked out (line breaks kept)."""
    macros: dict[str, Macro] = {}
    out, pos = [], 0
    for m in _DEF_START.finditer(text):
        if m.start() < pos:
            continue
        parsed = _parse_definition(text, m)
        if parsed is None:
            continue
        macro, end = parsed
        macros[macro.name] = macro
        out.append(text[pos:m.start()])
        out.append("\n" * text.count("\n", m.start(), end))
        pos = end
    out.append(text[pos:])
    return macros, "".join(out)


def _parse_definition(text: str, m: re.Match) -> Optional[tuple[Macro, int]]:
    i = m.end()
    kind = m.group(0).strip()
    if kind.startswith("\\def"):
        nm = re.match(r"\\([A-Za-z]+)((?:#\d)*)", text[i:])
        if not nm:
            return None
        body, end = read_group(text, i + nm.end())
        return Macro(nm.group(1), len(nm.group(2)) // 2, body), end
    name, i = read_group(text, i)
    name = name.strip().lstrip("\\")
    if not re.fullmatch(r"[A-Za-z]+", name):
        return None
    if kind.startswith("\\DeclareMathOperator"):
        body, end = read_group(text, i)
        return Macro(name, 0, f"\\operatorname{{{body}}}"), end
    nargs, default = 0, None
    if (a := re.match(r"\s*\[(\d)\]", text[i:])):
        nargs, i = int(a.group(1)), i + a.end()
        if (d := re.match(r"\s*\[([^\]]*)\]", text[i:])):
            default, i = d.group(1), i + d.end()
    body, end = read_group(text, i)
    return Macro(name, nargs, body, default), end


def expand_macros(text: str, macros: dict[str, Macro], passes: int = 5) -> str:
    """Expand user macros (with arguments and an optional first-argument default), a few passes deep."""
    if not macros:
        return text
    pat = re.compile(r"\\(" + "|".join(sorted(map(re.escape, macros), key=len, reverse=True)) + r")(?![A-Za-z])")
    for _ in range(passes):
        out, pos, changed = [], 0, False
        for m in pat.finditer(text):
            if m.start() < pos:
                continue
            macro = macros[m.group(1)]
            i, args = m.end(), []
            if macro.default is not None:
                opt = re.match(r"\[([^\]]*)\]", text[i:])
                args.append(opt.group(1) if opt else macro.default)
                i += opt.end() if opt else 0
            while len(args) < macro.nargs:
                arg, i = read_group(text, i)
                args.append(arg)
            body = macro.body
            for k, a in enumerate(args, start=1):
                body = body.replace(f"#{k}", a)
            if body[-1:].isalpha() and i < len(text) and text[i:i + 1].isalpha() and body.lstrip().startswith("\\"):
                body += " "
            out.append(text[pos:m.start()] + body)
            pos, changed = i, True
        out.append(text[pos:])
        text = "".join(out)
        if not changed:
            break
    return text
