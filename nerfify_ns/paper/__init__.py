"""Paper ingestion: one representation (``Document``) of a PDF, LaTeX, markdown or text paper.

Imports nothing from other nerfify_ns subpackages except ``nerfify_ns.errors`` (and ``nerfify_ns.atomic``).
"""

from nerfify_ns.paper.clean import clean_markdown, key_terms_report
from nerfify_ns.paper.document import (
    Algorithm,
    Caption,
    Citation,
    Document,
    Equation,
    Hyperparameter,
    Location,
    Paragraph,
    Reference,
    ResultTable,
    Section,
)
from nerfify_ns.paper.errors import (
    CorruptPdfError,
    EmptyDocumentError,
    EncryptedPdfError,
    InputTooLargeError,
    MissingLatexFileError,
    NotANerfPaperError,
    NotEnglishError,
    OutsidePaperError,
    PaperError,
    PaperLimitError,
    ScannedPdfError,
    UnsafeArchiveError,
    UnsupportedInputError,
)
from nerfify_ns.paper.hyperparams import extract_from_sentence, extract_hyperparameters, parse_number
from nerfify_ns.paper.ingest import DEFAULT_LIMITS, Limits, ingest
from nerfify_ns.paper.topic import nerf_score, require_nerf_paper

__all__ = [
    "Algorithm", "Caption", "Citation", "CorruptPdfError", "DEFAULT_LIMITS", "Document", "EmptyDocumentError",
    "EncryptedPdfError", "Equation", "Hyperparameter", "InputTooLargeError", "Limits", "Location",
    "MissingLatexFileError", "NotANerfPaperError", "NotEnglishError", "OutsidePaperError", "PaperError",
    "PaperLimitError", "Paragraph", "Reference", "ResultTable",
    "ScannedPdfError", "Section", "UnsafeArchiveError", "UnsupportedInputError", "clean_markdown",
    "extract_from_sentence", "extract_hyperparameters", "ingest", "key_terms_report", "nerf_score",
    "parse_number", "require_nerf_paper",
]
