"""Two-column pages as a layout-keeping PDF-to-text tool writes them: each page's left column is read before its
right one, its headings in order, every line traced to the file's line; other texts are left as they are."""

from __future__ import annotations

import textwrap

import pytest

from nerfify_ns.paper import ingest
from nerfify_ns.paper.columns import one_column

GUTTER = 56


def _column(paragraphs: list[str]) -> list[str]:
    lines: list[str] = []
    for p in paragraphs:
        lines += [""] if lines else []
        lines += p.splitlines() if "\n" in p else textwrap.wrap(p, 48)
    return lines


def _layout(pages: list[tuple[list[str], list[str]]], header: str = "Fields of Light • {n}") -> str:
    """A pdftotext -layout text: per page a running header, then the two columns side by side."""
    out: list[str] = []
    for n, (left, right) in enumerate(pages, 1):
        out += [" " * 30 + header.format(n=n), ""]
        left_lines, right_lines = _column(left), _column(right)
        for k in range(max(len(left_lines), len(right_lines))):
            a = left_lines[k] if k < len(left_lines) else ""
            b = right_lines[k] if k < len(right_lines) else ""
            out.append((a.ljust(GUTTER) + b).rstrip() if b else a)
        out += ["", ""]
    return "\n".join(out)


_SENTENCE = ("The field is queried at every sample along the ray and its densities are composited with the "
             "accumulated transmittance into the colour of the pixel.")


def _paper() -> str:
    intro = "1 Introduction\n" + "\n".join(textwrap.wrap("Radiance fields model a scene as density and colour. " * 14,
                                                          48))
    method = "2 Method\n" + "\n".join(textwrap.wrap("We propose a field of light. " * 10 + _SENTENCE, 48))
    field = "2.1 Density Field\n" + "\n".join(textwrap.wrap("The density is a softplus of the first output. " * 14,
                                                            48))
    sampler = "2.2 Sampling\n" + "\n".join(textwrap.wrap("We draw 64 samples per ray and 32 more by importance. " * 12,
                                                         48))
    exp = "3 Experiments\n" + "\n".join(textwrap.wrap("We evaluate on eight synthetic scenes with PSNR. " * 14, 48))
    conclusion = "4 Conclusion\n" + "\n".join(textwrap.wrap("A field of light renders sharp images quickly. " * 14, 48))
    return _layout([([intro], [method]), ([field], [sampler]), ([exp], [conclusion])])


def test_each_pages_left_column_is_read_before_its_right_one(tmp_path):
    text = _paper()
    assert text.count("\n") > 40
    joined, origin = one_column(text)
    assert origin is not None and len(origin) == len(joined.split("\n"))
    order = [joined.index(h) for h in ("1 Introduction", "2 Method", "2.1 Density Field", "2.2 Sampling",
                                       "3 Experiments", "4 Conclusion")]
    assert order == sorted(order)
    file_lines = text.splitlines()
    for k, line in enumerate(joined.splitlines()):  # every line's words are on the file's line it names
        if line and not line.startswith("<!--"):
            assert line.split()[0] in file_lines[origin[k] - 1], (line, file_lines[origin[k] - 1])

    path = tmp_path / "paper.txt"
    path.write_text(text)
    doc = ingest(path)
    titles = [s.title for s in doc.sections]
    assert titles[:6] == ["Introduction", "Method", "Density Field", "Sampling", "Experiments", "Conclusion"], titles
    method = next(s for s in doc.sections if s.title == "Method")
    assert any(" ".join(_SENTENCE.split()) in " ".join(p.text.split()) for p in method.paragraphs), method.paragraphs


@pytest.mark.parametrize("text", [
    "\n".join(textwrap.wrap("One column of running text, wrapped at sixty characters. " * 80, 60)),
    "| method | PSNR | SSIM |\n|---|---|---|\n" + "\n".join(f"| ours{k}   |   31.{k}   |   0.9{k} |"
                                                           for k in range(60)),
    "\n".join(f"{k:>3}    {k * 1.5:>8.2f}    {k * 2.25:>8.2f}" for k in range(80)),  # a table of numbers, no pages
])
def test_other_texts_are_left_as_they_are(text):
    assert one_column(text) == (text, None)
