"""The synthesis stage's data: Jinja2 templates, terminal snippets, base models, reference plans.

They live at the top of the repository (``templates/``, ``method_configs/``) and are reached
through the package (symlinked into ``nerfify_ns/synthesis``) so an installed copy finds them.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Dict, List

import yaml

from nerfify_ns.errors import NerfifyError


class UnknownReferencePlanError(NerfifyError):
    """No reference plan of that name in method_configs/."""


def _root(name: str) -> Path:
    return Path(str(resources.files("nerfify_ns.synthesis").joinpath(name)))


def templates_dir() -> Path:
    return _root("templates")


@lru_cache(maxsize=1)
def snippets() -> Dict[str, dict]:
    return yaml.safe_load((templates_dir() / "snippets.yaml").read_text())


@lru_cache(maxsize=1)
def bases() -> Dict[str, dict]:
    return yaml.safe_load((templates_dir() / "bases.yaml").read_text())


def reference_plans() -> List[str]:
    """Names of the reference plans (``method_configs/<name>.yaml``)."""
    return sorted(p.stem for p in _root("method_configs").glob("*.yaml"))


def reference_plan_path(name: str) -> Path:
    path = _root("method_configs") / f"{name}.yaml"
    if not path.is_file():
        raise UnknownReferencePlanError(
            f"no reference plan {name!r}; known: {', '.join(reference_plans())} (method_configs/)")
    return path


def load_reference_plan(name: str) -> dict:
    return yaml.safe_load(reference_plan_path(name).read_text())
