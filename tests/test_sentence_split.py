"""The package's one sentence splitter (``nerfify_ns/sentence_split.py``): what it splits, and that no other module
defines its own."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from nerfify_ns import sentence_split
from nerfify_ns.sentence_split import split_sentences

PACKAGE = Path(sentence_split.__file__).parent


def test_abbreviations_and_initials_do_not_end_a_sentence():
    text = "See Fig. 3 and Eq. 2 by Mildenhall et al. for details, e.g. Sec. 4. We then train. A. B. Smith wrote it."
    assert split_sentences(text) == ["See Fig. 3 and Eq. 2 by Mildenhall et al. for details, e.g. Sec. 4.",
                                     "We then train.", "A. B. Smith wrote it."]


def test_a_period_inside_open_inline_math_does_not_end_a_sentence():
    text = r"We decay the learning rate to $0 . 0 0 1$. Next we train. Cost is $O(n) . M$ here."
    assert split_sentences(text) == [r"We decay the learning rate to $0 . 0 0 1$.", "Next we train.",
                                     r"Cost is $O(n) . M$ here."]


def test_sentences_are_exact_substrings_and_a_lower_case_word_continues_one():
    text = "  We use 64 samples. then 128 more!  (Both are fine.)\n"
    parts = split_sentences(text)
    assert parts == ["We use 64 samples. then 128 more!", "(Both are fine.)"]
    assert all(p in text for p in parts)
    assert split_sentences("   ") == []


def test_a_bibliography_entry_splits_into_its_fields():
    entry = "Ben Mildenhall, Pratul P. Srinivasan. NeRF: representing scenes. In Proc. ECCV, vol. 3, pp. 1-9, 2020."
    assert split_sentences(entry, bibliography=True) == [
        "Ben Mildenhall, Pratul P. Srinivasan.", "NeRF: representing scenes.", "In Proc. ECCV, vol. 3, pp. 1-9, 2020."]
    # prose rules would not split before a lower-case word; a bibliography entry's fields may start with one
    assert split_sentences("Smith J. deep fields. arXiv 2020.", bibliography=True) == [
        "Smith J. deep fields.", "arXiv 2020."]


_BOUNDARY = re.compile(r"\(\?<=\[[.!?]{3}\]\)")  # a regular expression's "after a sentence's end" look-behind


def _splitters(path: Path) -> list[str]:
    """What in ``path`` looks like a sentence splitter: a function named for splitting sentences, or a regular
    expression that looks behind for a sentence's end or lists abbreviations such as "et al"."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and re.search(r"split.*sentence|sentence.*split",
                                                                                    node.name, re.IGNORECASE):
            found.append(f"def {node.name} (line {node.lineno})")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and (
                _BOUNDARY.search(node.value) or re.search(r"et al\|", node.value)):
            found.append(f"{node.value[:50]!r} (line {node.lineno})")
    return found


def test_no_other_module_defines_a_sentence_splitter():
    found = [f"{path.relative_to(PACKAGE.parent)}: {what}" for path in sorted(PACKAGE.rglob("*.py"))
             if path != Path(sentence_split.__file__) for what in _splitters(path)]
    assert not found, "split sentences with nerfify_ns.sentence_split.split_sentences:\n" + "\n".join(found)


def test_the_scan_sees_a_splitter(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text('import re\n\ndef _split_sentences(t):\n    return re.split(r"(?<=[.?!])\\s+", t)\n'
                     'ABBREV = r"(?:e\\.g|et al|Fig)\\.$"\n')
    assert len(_splitters(probe)) == 3
    assert _splitters(Path(sentence_split.__file__))  # the home itself is what the scan recognises
