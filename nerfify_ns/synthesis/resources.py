"""The synthesis stage's data: Jinja2 templates, base models, reference plans (terminal code lives in the
terminal registry, ``nerfify_ns/registry``).

They live at the top of the repository (``templates/``, ``method_configs/``); :mod:`nerfify_ns.package_data`
finds them there or, in an installed wheel, inside the package.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from nerfify_ns import package_data as data
from nerfify_ns.errors import NerfifyError


class UnknownReferencePlanError(NerfifyError):
    """No reference plan of that name in method_configs/."""


def templates_dir() -> Path:
    """The folder of the plugin templates (``*.j2``, ``bases.yaml``)."""
    return data.templates_dir()



def bases() -> dict[str, dict]:
    """What the plugin templates read of each base model (its one definition: ``nerfify_ns/registry/bases.yaml``)."""
    from nerfify_ns.registry.bases import plugin_facts

    return plugin_facts()


def reference_plans() -> list[str]:
    """Names of the reference plans (``method_configs/<name>.yaml``)."""
    return sorted(p.stem for p in data.method_configs_dir().glob("*.yaml"))


def reference_plan_path(name: str) -> Path:
    """The file of reference plan ``name``; :class:`UnknownReferencePlanError` if there is none."""
    path = data.method_configs_dir() / f"{name}.yaml"
    if not path.is_file():
        raise UnknownReferencePlanError(
            f"no reference plan {name!r}; known: {', '.join(reference_plans())} (method_configs/)")
    return path


def load_reference_plan(name: str) -> dict:
    """Reference plan ``name`` as a mapping."""
    return yaml.safe_load(reference_plan_path(name).read_text())
