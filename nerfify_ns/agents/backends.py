"""The capability table (``backends.yaml``) as typed records: what each backend takes and how."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import yaml

STRUCTURED_MODES = ("openai_json_schema", "anthropic_tool", "vllm_structured", "ollama_format",
                    "llamacpp_json_schema", "llamacpp_gbnf", "none")


@dataclass(frozen=True)
class Backend:
    """One row of the capability table (see ``backends.yaml`` for each field)."""

    name: str
    sdk: str
    base_url: str | None
    key_env: str | None
    key_required: bool
    structured: str
    strict_schema: bool
    images: bool
    seed: bool
    local: bool


@lru_cache(maxsize=1)
def _table() -> dict:
    return yaml.safe_load(resources.files("nerfify_ns.agents").joinpath("backends.yaml").read_text())


def backends() -> dict[str, Backend]:
    """Every backend of the table, by name."""
    out = {}
    for name, row in _table()["backends"].items():
        if row["structured"] not in STRUCTURED_MODES:
            raise ValueError(f"backends.yaml: {name}: unknown structured mode {row['structured']!r}")
        out[name] = Backend(name=name, **row)
    return out


def price(model: str) -> tuple[float, float] | None:
    """(input, output) USD per million tokens of ``model`` when its list price is known, else None."""
    row = (_table().get("prices") or {}).get(model)
    return (float(row[0]), float(row[1])) if row else None
