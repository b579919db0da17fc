"""A paper's displayed equations as the equation reader read them: one ``Item`` per equation block, in reading
order, each with what the reader made of it (equations or failures with their reasons), and its record in
``equations.yaml`` (``_record_equation``). Nothing here binds or compiles (``binding.py``, ``component.py``)."""

from __future__ import annotations

import copy
import re
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.equations import (
    Equation,
    ParseFailure,
    parse_equations,
    show,
)


@dataclass
class Item:
    """One displayed equation (a block may hold several) and what the reader made of it."""

    number: str
    latex: str
    section: str
    order: int
    where: str
    in_hole: bool
    page: int | None = None
    bbox: list | None = None
    corrected: bool = False
    parsed: list = field(default_factory=list)
    position: int = 0

    def equations(self) -> list[Equation]:
        return [p for p in self.parsed if isinstance(p, Equation)]

    def failures(self) -> list[ParseFailure]:
        return [p for p in self.parsed if isinstance(p, ParseFailure)]


def _norm(latex: str) -> str:
    return re.sub(r"\s+", "", latex or "")


def doc_items(doc: Any) -> list[Item]:
    """Every displayed equation of the paper, in reading order."""
    items = []
    sections = [s.heading for s in getattr(doc, "sections", []) or []]
    for i, e in enumerate(getattr(doc, "equations", []) or []):
        latex = (e.latex or "").strip()
        if not latex:
            continue
        loc = e.loc
        where = ", ".join(x for x in (f"p.{e.page or loc.page}" if (e.page or getattr(loc, "page", None)) else
                                      (f"l.{loc.line}" if getattr(loc, "line", None) else ""),
                                      f"Sec. {e.section}" if e.section else "") if x)
        items.append(Item(number=str(e.number or ""), latex=latex, section=e.section or "",
                          order=getattr(loc, "order", 0) or 0, where=where, in_hole=False,
                          page=e.page or getattr(loc, "page", None), bbox=e.bbox, position=i))
    rank = {s: k for k, s in enumerate(sections)}
    items.sort(key=lambda it: (rank.get(it.section, len(rank)), it.order, it.position))
    for k, it in enumerate(items):
        it.position = k
    return items


def describe(err: BaseException) -> str:
    """An exception as part of a recorded reason: its type and the first 200 characters of its message."""
    message = " ".join(str(err).split())[:200]
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


def _parse(item: Item) -> None:
    """Read an item's equations once; whatever goes wrong is the item's recorded failure, never the run's."""
    if not item.parsed:
        try:
            item.parsed = parse_equations(item.latex, number=item.number or None)
        except Exception as err:  # noqa: BLE001 - the per-equation boundary (parse_equations itself never raises)
            item.parsed = [ParseFailure(f"could not read Eq. {item.number or '?'}: {describe(err)}", None, "",
                                        item.latex[:200], item.number or None)]


def _record_equation(it: Item, attempt_items: list) -> dict:
    reading = "; ".join(show(p) if isinstance(p, Equation) else f"not read: {p}" for p in it.parsed)
    if any(it is a for a in attempt_items if a is not None):
        status = "compiled"
    elif it.failures() and not it.equations():
        status = "not read: " + "; ".join(str(f) for f in it.failures())
    else:
        status = "not needed by the component's outputs"
    out = {"number": it.number, "latex": it.latex, "reading": reading, "status": status, "where": it.where}
    if not it.number:
        out["key"] = f"@{it.position}"
    if it.page:
        out["page"] = it.page
    if it.bbox:
        out["bbox"] = [round(float(v), 2) for v in it.bbox]
    if it.corrected:
        out["corrected"] = True
    return out


def equation_counts(items: list[Item]) -> dict:
    numbered = [it for it in items if it.number]
    read = [it for it in numbered if it.parsed and all(isinstance(p, Equation) for p in it.parsed)]
    return {"numbered": len(numbered), "read": len(read), "displayed": len(items)}


def _apply_corrections(items: list[Item], corr: dict) -> list[Item]:
    """The paper's equations with a person's corrected LaTeX (equations.yaml: equations[].latex)."""
    fixes = {}
    for e in corr.get("equations") or []:
        if isinstance(e, dict) and isinstance(e.get("latex"), str) and (e.get("number") or e.get("key")):
            fixes[str(e.get("number") or e.get("key"))] = e["latex"]
    out = []
    for it in items:
        key = it.number or f"@{it.position}"
        if key in fixes and _norm(fixes[key]) != _norm(it.latex):
            clone = copy.copy(it)
            clone.latex, clone.corrected, clone.parsed = fixes[key], True, []
            out.append(clone)
        else:
            out.append(it)
    return out
