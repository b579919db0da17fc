"""The base models, defined once (``bases.yaml``): the registry's ``Base`` terminals, the plugin templates' facts,
the CPU smoke presets and the reference plans with the names papers give them all read this one file (the knowledge
base reads ``reference_plans`` as data: ``knowledge/patterns.py``)."""

from __future__ import annotations

import copy
from functools import cache
from importlib import resources
from typing import Any

import yaml


@cache
def _bases() -> dict[str, dict[str, Any]]:
    return yaml.safe_load(resources.files("nerfify_ns.registry").joinpath("bases.yaml").read_text(encoding="utf-8"))


def base_definitions() -> dict[str, dict[str, Any]]:
    """Every base model's definition, by name, in the grammar's order (a copy: callers may edit it)."""
    return copy.deepcopy(_bases())


def plugin_facts() -> dict[str, dict[str, Any]]:
    """What the plugin templates read of each base: its module and classes, the pipeline and datamanager of
    Nerfstudio's own method config, how the generated field is installed (``plugin`` of ``bases.yaml``)."""
    out = {}
    for name, base in base_definitions().items():
        module, model_class = base["model"].rsplit(".", 1)
        config_module, config_class = base["config"].rsplit(".", 1)
        facts = {"module": module, "model_class": model_class, "config_class": config_class}
        if config_module != module:
            facts["config_module"] = config_module
        out[name] = {**facts, **base.get("plugin", {})}
    return out


def smoke_presets() -> dict[str, dict[str, Any]]:
    """The CPU smoke preset of each base's built-in Nerfstudio method (``smoke`` of ``bases.yaml``)."""
    return {name: base["smoke"] for name, base in base_definitions().items() if base.get("smoke")}
