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
