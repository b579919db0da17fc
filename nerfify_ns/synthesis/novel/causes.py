"""Why a novel part was not built: one cause per part, from the reason its record gives.

    cause_of("'C' (equation (2)): a ray_colour ... the Renderer interface does not give")   # -> "binding"

The causes (``CAUSES``, first match wins, most specific first) are those a person acts on: a ladder rung that
reverted a compiled part (contract, stability, smoke), a production the compiler has no adapter for, a part with
no equation, an equation the reader refused, a size nothing states (width), an operator or a reduction the lowering
does not support, a symbol it cannot bind (the interface does not give it, the paper never names it), the module
disagreeing with the interpreter. A part's record keeps its cause (``HoleResult.cause``), the plan's hole too, and
the benchmark ``nerfify_ns.benchmarks.novelty_causes`` counts them.
"""

from __future__ import annotations

import re

CAUSES: tuple[tuple[str, str], ...] = (
    ("contract rung", r"ladder's contract rung|failed its own contract check|contract check"),
    ("stability rung", r"ladder's stabilit\w* rung"),
    ("smoke rung", r"ladder's smoke rung"),
    ("another ladder rung", r"the ladder's \w+ rung|the ladder failed"),
    ("no adapter for the production", r"no adapter for the \w+ production"),
    ("no terminal for what it states", r"not built: the paper \w+ (?:something|a part) no terminal"),
    ("prose only (no equation)", r"no equation of the paper belongs|names none the reader found"),
    ("equation not read", r"equations not read|could not read Eq|unknown operator|unexpected|parse"),
    ("width", r"the size of '.*' is not fixed|\bwidths?\b.*(?:open|not stated|contradict)|WidthError|"
              r"is known only when the plugin is built"),
    ("reduction", r"\bsum over\b|\bproduct over\b|reduction|\bmax over\b|\bmin over\b|cumulative|packed samples"),
    ("unsupported operator", r"not supported|unsupported|cannot lower|no lowering|operator|"
                             r"the activation '.*' is not one of"),
    ("binding", r"interface does not give|never names|neither defines nor names|could not be bound|: not found|"
                r"binds it to|would be a network|a second \w+|not a quantity|no equation of the part defines"),
    ("check against the interpreter", r"failed its check against the interpreter|gradcheck|rtol"),
)
"""(cause, pattern over the part's reason): the first that matches is the part's cause; 'other' when none does."""

NAMES: tuple[str, ...] = tuple(name for name, _ in CAUSES) + ("other",)

_HINT = re.compile(r"\s*\[the \w+ interface gives:[^\]]*\]\s*$")
_FORMS = re.compile(r"no form of the part compiled:\s*")


def cause_of(reason: str) -> str:
    """The cause of a part left unbuilt, from its recorded reason: the first form's failure when several forms of
    the part were tried (the paper's latest form comes first), the interface hint at the end ignored."""
    text = _HINT.sub("", reason or "")
    if "no form of the part compiled:" in text and not re.match(r"^equations not read", text):
        text = _FORMS.split(text, maxsplit=1)[-1]
        text = text.split(" || ")[0]
    for name, pattern in CAUSES:
        if re.search(pattern, text, re.IGNORECASE):
            return name
    return "other"


def histogram(reasons: list[tuple[str, str]]) -> dict[str, int]:
    """cause -> number of parts, every cause listed (zeros included) in ``NAMES`` order; ``reasons`` holds
    (cause or '', reason) per part not built."""
    out = dict.fromkeys(NAMES, 0)
    for cause, reason in reasons:
        name = cause if cause in out else cause_of(reason)
        out[name] += 1
    return out
