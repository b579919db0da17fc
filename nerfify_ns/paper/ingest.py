"""One entry point: ``ingest(path) -> Document`` for PDF, LaTeX (file, folder, tarball), markdown and text."""

from __future__ import annotations

from pathlib import Path

from nerfify_ns.paper.document import Document
from nerfify_ns.paper.errors import EmptyDocumentError, InputTooLargeError, UnsupportedInputError
from nerfify_ns.paper.limits import DEFAULT_LIMITS, Limits

__all__ = ["DEFAULT_LIMITS", "Limits", "ingest", "input_kind"]
KINDS = {".pdf": "pdf", ".tex": "latex", ".tgz": "latex", ".tar": "latex", ".gz": "latex",
         ".md": "markdown", ".markdown": "markdown", ".txt": "text", ".text": "text"}


def input_kind(path: Path) -> str:
    """pdf | latex | markdown | text, from the path (a folder is LaTeX sources)."""
    if path.is_dir():
        return "latex"
    name = path.name.lower()
    if name.endswith(".gz") and not name.endswith((".tar.gz",)):
        raise UnsupportedInputError(f"{path.name}: a .gz that is not a .tar.gz; pass a .pdf, .tex, a LaTeX folder "
                                    "or .tar.gz, .md or .txt")
    kind = KINDS.get(path.suffix.lower())
    if kind is None:
        raise UnsupportedInputError(f"{path.name}: unsupported input type '{path.suffix or '(none)'}'; pass a .pdf, "
                                    ".tex, a LaTeX folder or .tar.gz, .md or .txt")
    return kind


def _check_size(path: Path, limits: Limits) -> None:
    size = path.stat().st_size
    if size > limits.max_bytes:
        raise InputTooLargeError(f"{path.name}: {size / 2**20:.0f} MB, more than the limit of "
                                 f"{limits.max_bytes / 2**20:.0f} MB; pass the paper alone or raise the limit")
    if size == 0:
        raise EmptyDocumentError(f"{path.name}: the file is empty (0 bytes); check the download")


def ingest(path: str | Path, limits: Limits | None = None) -> Document:
    """Read a paper into a Document; raises a typed PaperError on anything it cannot use: unreadable, too large
    (``limits``, see :mod:`nerfify_ns.paper.limits`), reaching outside the paper, not in English, or empty."""
    path = Path(path)
    limits = limits or DEFAULT_LIMITS
    if not path.exists():
        raise UnsupportedInputError(f"{path}: no such file or folder; check the path")
    if not path.is_file() and not path.is_dir():
        raise UnsupportedInputError(f"{path}: not a regular file or folder; pass the paper file")
    kind = input_kind(path)
    if path.is_file():
        _check_size(path, limits)
    if kind == "pdf":
        from nerfify_ns.paper.pdf import read_pdf
        doc = read_pdf(path, max_pages=limits.max_pages, limits=limits)
    elif kind == "latex":
        from nerfify_ns.paper.latex import read_latex
        doc = read_latex(path, limits)
    elif kind == "markdown":
        from nerfify_ns.paper.markdown import read_markdown
        doc = read_markdown(path, limits)
    else:
        from nerfify_ns.paper.plaintext import read_text
        doc = read_text(path, limits)
    if not doc.title and not doc.abstract and not any(s.paragraphs for s in doc.sections):
        raise EmptyDocumentError(f"{path.name}: no text found; check that it is the paper")
    return doc
