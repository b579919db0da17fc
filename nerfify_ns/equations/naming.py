"""Identifiers of generated code: ours, never the paper's text.

A symbol key from a paper ('W_Delta^f', 'hat C', or anything a hostile paper names) becomes
``<prefix>_<sanitised>``: lower-case ASCII letters, digits and single underscores, at most 24 characters
after the prefix, made unique with a counter; the key itself only ever appears in generated source through
``render.safe_comment``. ``Names.mapping`` keeps identifier -> key for the caller.
"""

from __future__ import annotations

import keyword
import re

_NOT_SAFE = re.compile(r"[^a-z0-9]+")
_CLASS = re.compile(r"[A-Z][A-Za-z0-9]{0,63}")
MAX_LEN = 24

#: names the generated source may use besides the identifiers of ``Names`` (tested by the safety test)
RESERVED = frozenset({
    "torch", "nn", "math", "self", "super", "range", "float", "min", "max", "abs", "next", "x", "xs", "dim", "like",
    "inclusive", "n", "shape", "ref", "parts", "n_rays", "n_samples", "_exclusive_cumsum", "_exclusive_cumprod",
    "_before_mask", "_cat_features", "_sample_ones", "forward", "reset_parameters", "__init__",
})


def sanitize(key: str) -> str:
    text = key.replace("'", " prime ").replace("*", " star ").replace("^", " ")
    text = _NOT_SAFE.sub("_", text.lower()).strip("_")
    text = text[:MAX_LEN].strip("_")
    return text or "x"


def class_name_ok(name: str) -> bool:
    return bool(_CLASS.fullmatch(name)) and not keyword.iskeyword(name)


class Names:
    """Unique generated identifiers per (prefix, key)."""

    def __init__(self):
        self.taken: set[str] = set(RESERVED)
        self.by_key: dict[tuple[str, str], str] = {}
        self.mapping: dict[str, str] = {}

    def get(self, prefix: str, key: str) -> str:
        if (prefix, key) in self.by_key:
            return self.by_key[prefix, key]
        return self.fresh(prefix, key)

    def fresh(self, prefix: str, key: str) -> str:
        base = f"{prefix}_{sanitize(key)}"
        name, n = base, 1
        while name in self.taken:
            n += 1
            name = f"{base}_{n}"
        self.taken.add(name)
        self.by_key[prefix, key] = name
        self.mapping[name] = key
        return name
