"""The knowledge base: one card per NeRF technique, and a registry of known papers.

``KnowledgeBase`` (``kb.py``) holds all of it as one object (``KnowledgeBase.load(folder)``), which the
stages take as an argument: detection, citation recovery and plan derivation read the base they are given.

A card (``cards/<name>.yaml``) says what a technique is called (aliases), which paper introduced it
(with arXiv id), which grammar production and terminal(s) it fills, the paper's parameter values,
its key equation, the component implementing it, the signals that reveal it in a paper, and the
cards it requires. ``papers.yaml`` lists known papers and the cards each provides; citation
recovery matches a reference against it by arXiv id, then normalised title.

Imports only ``nerfify_ns.errors`` and the sentence splitter ``nerfify_ns.sentence_split`` from the project (the
grammar is upstream-independent).
"""

from nerfify_ns.knowledge.cards import (
    CARDS_DIR,
    AliasMatch,
    Card,
    Equation,
    HyperparameterMap,
    PaperRef,
    Signals,
    card,
    cards_for_terminal,
    find_by_alias,
    load_card_file,
    load_cards,
    match_aliases,
)
from nerfify_ns.knowledge.errors import CardFormatError, KnowledgeError, PaperRegistryError, UnknownCardError
from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.knowledge.papers import (
    PAPERS_FILE,
    KnownPaper,
    find_papers_by_alias,
    load_papers,
    match_paper,
)
from nerfify_ns.knowledge.text import normalize_arxiv_id, normalize_text, normalize_title

__all__ = [
    "CARDS_DIR", "PAPERS_FILE", "KnowledgeBase",
    "Card", "HyperparameterMap", "PaperRef", "Equation", "Signals", "AliasMatch", "KnownPaper",
    "load_cards", "load_card_file", "card", "cards_for_terminal", "find_by_alias", "match_aliases",
    "load_papers", "match_paper", "find_papers_by_alias",
    "normalize_arxiv_id", "normalize_title", "normalize_text",
    "KnowledgeError", "UnknownCardError", "CardFormatError", "PaperRegistryError",
]
