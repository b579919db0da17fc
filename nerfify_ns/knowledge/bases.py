"""A paper's own statement of the Nerfstudio model it builds on ("our implementation is based on Instant-NGP").

    statements = find_base_statements(doc, kb)
    statements[0].bases        # ["instant-ngp"]: reference plans (method_configs/) in the order named
    statements[0].quote        # the sentence, exactly as in the paper, with its section and page or line

The statement patterns, the names of each model and the known papers whose citation names one are data
(``bases.yaml``). A model is named by one of its names, by an alias of a known paper that is its code, or
by a citation marker whose reference is such a paper ("we build on [12]"). Only sentences about the
paper's own method count: related work, sentences about someone else's work ("X et al. built on
TensoRF") and contrast clauses ("unlike nerfacto, we ...") do not.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

from nerfify_ns.knowledge.citations import _marker_keys, find_spans
from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.knowledge.sentences import SentenceContext, Unit, sentences
from nerfify_ns.knowledge.text import longest_non_overlapping

_TOKEN = "\u27e6{}\u27e7"
_MARKER = re.compile(r"\[([^\[\]]{1,200})\]")
_ROLE_RANK = {"method": 0, "abstract": 1, "experiments": 2, "conclusion": 3, "prior": 4}


@dataclass
class BaseStatement:
    """A sentence in which the paper names the model(s) it builds on."""

    bases: list[str]          # reference plan names, in the order the sentence names them
    quote: str
    section: str
    page: int | None
    line: int | None
    role: str
    pattern: str

    @property
    def where(self) -> str:
        loc = f"p.{self.page}" if self.page is not None else (f"l.{self.line}" if self.line is not None else "")
        return ", ".join(x for x in (loc, f"Sec. {self.section}" if self.section else "") if x)

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class _Named:
    base: str | None       # the model this target names (None: a citation of some other work)
    start: int
    end: int


def _named_models(sentence: str, kb: KnowledgeBase, ref_bases: dict[str, str | None],
                  ref_keys: set[str]) -> list[_Named]:
    """Every model name, model paper alias and citation marker of ``sentence``, in order."""
    out: list[_Named] = []
    for m in _MARKER.finditer(sentence):
        keys = _marker_keys(m.group(1), ref_keys)
        if keys:
            bases = [b for k in keys if (b := ref_bases.get(k))]
            out.append(_Named(bases[0] if bases else None, m.start(), m.end()))
    spans = find_spans(sentence, kb.base_names)
    spans += [(s, e, kb.base_for_paper(key)) for s, e, key in find_spans(sentence, kb.paper_aliases)]
    for start, end, base in longest_non_overlapping(spans):
        if all(end <= t.start or start >= t.end for t in out):
            out.append(_Named(base, start, end))
    return sorted(out, key=lambda t: t.start)


def _tokenize(sentence: str, named: list[_Named]) -> str:
    parts, pos = [], 0
    for i, t in enumerate(named):
        parts += [sentence[pos:t.start], _TOKEN.format(i)]
        pos = t.end
    return "".join(parts + [sentence[pos:]])


def _about_own_method(role: str, ctx: SentenceContext) -> bool:
    """Whether a sentence speaks about the paper's own method (the filters of citation recovery)."""
    if role in ("title", "ignore") or (role == "prior" and not ctx.own):
        return False
    if ctx.prior and not ctx.usage:
        return False
    return not (role == "experiments" and ctx.comparison and not ctx.usage)


def _bases_in(sentence: str, tokenized: str, named: list[_Named], ctx: SentenceContext,
              kb: KnowledgeBase) -> tuple[list[str], str] | None:
    """(models named, pattern) of the first statement pattern that matches, or None."""
    for name, regex in kb.bases.statements:
        for m in regex.finditer(tokenized):
            idx = [int(i) for i in re.findall(r"\u27e6(\d+)\u27e7", m.group("base"))]
            bases = [named[i].base for i in idx
                     if named[i].base and not ctx.in_contrast(named[i].start, named[i].end)]
            if bases:
                return list(dict.fromkeys(bases)), name
    return None


def find_base_statements(doc: Any, kb: KnowledgeBase | None = None,
                         units: Sequence[Unit] | None = None) -> list[BaseStatement]:
    """Every sentence in which the paper says which model it builds on, the paper's method sections first
    (``units``: the paper's sentences when the caller has read them already)."""
    kb = KnowledgeBase.of(kb)
    refs = {r.key: r for r in getattr(doc, "references", [])}
    ref_bases = {k: kb.base_for_paper(p.key) if (p := kb.match_reference(r)) else None for k, r in refs.items()}
    found: list[tuple[int, int, BaseStatement]] = []
    for order, unit in enumerate(units if units is not None else sentences(doc, kb.rules)):
        if not _about_own_method(unit.role, unit.context):
            continue
        named = _named_models(unit.text, kb, ref_bases, set(refs))
        if not any(t.base for t in named):
            continue
        hit = _bases_in(unit.text, _tokenize(unit.text, named), named, unit.context, kb)
        if hit:
            bases, pattern = hit
            found.append((_ROLE_RANK.get(unit.role, 5), order, BaseStatement(
                bases=bases, quote=unit.text, section=unit.section, page=unit.page, line=unit.line,
                role=unit.role, pattern=pattern)))
    return [s for _r, _o, s in sorted(found, key=lambda x: (x[0], x[1]))]
