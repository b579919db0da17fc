"""Typed errors of the knowledge base; each message says what is wrong and what to do."""

from __future__ import annotations

from nerfify_ns.errors import NerfifyError


class KnowledgeError(NerfifyError):
    """Base of every knowledge-base error."""


class UnknownCardError(KnowledgeError):
    """No card has this name."""


class CardFormatError(KnowledgeError):
    """A card file is not valid YAML or lacks a field, or a field has the wrong type."""


class PaperRegistryError(KnowledgeError):
    """papers.yaml is malformed (a missing field, a duplicate key)."""
