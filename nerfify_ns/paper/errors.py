"""Typed errors of the paper-ingestion stage; each message is one line: the problem, then what to do."""

from __future__ import annotations

from nerfify_ns.errors import NerfifyError


class PaperError(NerfifyError):
    """Base of every ingestion error."""


class UnsupportedInputError(PaperError):
    """Not a file/folder we can read, or an unknown extension."""


class InputTooLargeError(PaperError):
    """The file is larger, or has more pages, than the configured limits."""


class EncryptedPdfError(PaperError):
    """The PDF is password-protected."""


class CorruptPdfError(PaperError):
    """The PDF cannot be opened or parsed."""


class ScannedPdfError(PaperError):
    """The PDF holds page images but (almost) no text layer."""


class EmptyDocumentError(PaperError):
    """The input holds no usable text."""


class MissingLatexFileError(PaperError):
    """An \\input/\\include names a file that is not there."""


class UnsafeArchiveError(PaperError):
    """An archive member would be written outside the extraction folder (absolute path, '..', link)."""


class NotANerfPaperError(PaperError):
    """The document does not look like a NeRF / radiance-field paper."""


class PaperLimitError(InputTooLargeError):
    """Reading the paper went past one of the limits of ``paper/limits.py`` (archive size or files, include depth or
    count, macro expansion, bibliography, text size); the message names the limit and the file."""


class OutsidePaperError(UnsafeArchiveError):
    """An ``\\input``/``\\include``/``\\subfile``/``\\import``/``\\bibliography`` (or a source file found in the paper's
    folder) names a file outside the paper's folder or archive: an absolute path, a ``..`` escape, a link that
    leads out of it, ``/proc``, ``/sys``, ``/dev`` or anything that is not a regular file. Never read."""


class NotEnglishError(PaperError):
    """The paper's text is not in English (another script, or too few common English words)."""
