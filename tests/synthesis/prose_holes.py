"""A hole built from sentences of a test's own (``prose.build``, the compiler's result standing for "not
implemented"): the one helper the prose tests share."""

from __future__ import annotations

from nerfify_ns.synthesis.novel import prose
from nerfify_ns.synthesis.novel.implement import HoleResult


def build_hole(production: str, slot: str, sentences: list[str], plan, corr: dict | None = None):
    """``prose.build`` on a hole of ``production`` at ``slot`` whose text (and section, 3 Method) is ``sentences``;
    ``plan`` is changed in place."""
    hole = {"production": production, "slot": slot, "section": "3 Method", "text": " ".join(sentences),
            "claim": "", "where": "Sec. 3"}
    compiled = HoleResult(id="part", slot=slot, production=production, section="3 Method",
                          reason="the compiler has no adapter")
    return prose.build(hole, [(s, "Sec. 3", "3 Method") for s in sentences], plan, corr, compiled)


def assert_option_stated(result, node: dict, before: dict, part: str, terminal: str, option: str, value,
                         sentence: str) -> None:
    """The typed option ``option`` of ``terminal`` is ``value`` in ``node`` (the plan's options after the build),
    nothing else changed from ``before``, and the record quotes ``sentence`` for it."""
    from nerfify_ns.synthesis.novel import IMPLEMENTED

    assert node[option] == value
    assert {k: v for k, v in node.items() if k != option} == {k: v for k, v in before.items() if k != option}
    assert result.status == IMPLEMENTED
    record = next(p for p in result.parts if p["part"] == part)
    assert record["terminal"] == terminal and record["statement"]["quote"] == sentence
    assert record["parameters"][option]["value"] == value
