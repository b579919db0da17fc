"""Where the project's data lives: ``templates/``, ``method_configs/`` and ``grammar_spec.yaml``.

The repository keeps them at its top level. A wheel carries them inside the package, in
``nerfify_ns/_data/`` (the build hook ``hatch_build.py`` maps them there); an editable install reads
them from the checkout. This module is the one place that knows both layouts; everything else asks it.
"""

from __future__ import annotations

from pathlib import Path

from nerfify_ns.errors import NerfifyError

PACKAGE_DIR = Path(__file__).resolve().parent
"""The installed (or checked-out) ``nerfify_ns`` package folder."""
INSTALLED_DATA_DIR = PACKAGE_DIR / "_data"
"""Where a wheel puts the project data."""
CHECKOUT_DIR = PACKAGE_DIR.parent
"""The repository root, when the package is used from a checkout (editable install, ``python -m``)."""


class ProjectDataMissingError(NerfifyError):
    """Neither the installed package nor a checkout holds the project data (a broken install)."""


def _is_checkout(root: Path) -> bool:
    """``root`` is a source tree (it has ``pyproject.toml``), not a site-packages folder that might
    hold a ``templates`` folder of another project."""
    return (root / "pyproject.toml").is_file()


def data_roots() -> tuple[Path, ...]:
    """The folders searched for project data, in order: the wheel's ``_data``, then the checkout."""
    roots = [INSTALLED_DATA_DIR] if INSTALLED_DATA_DIR.is_dir() else []
    if _is_checkout(CHECKOUT_DIR):
        roots.append(CHECKOUT_DIR)
    return tuple(roots)


def project_path(name: str) -> Path:
    """The file or folder ``name`` of the project data (``templates``, ``method_configs``, ...)."""
    for root in data_roots():
        if (root / name).exists():
            return root / name
    searched = ", ".join(str(r) for r in data_roots()) or f"{INSTALLED_DATA_DIR} (missing)"
    raise ProjectDataMissingError(
        f"project data {name!r} not found (searched {searched}); reinstall nerfify-ns "
        "(pip install nerfify-ns, or pip install -e . in a checkout)")


def templates_dir() -> Path:
    """The Jinja2 templates of a plugin, plus ``snippets.yaml``."""
    return project_path("templates")


def method_configs_dir() -> Path:
    """The reference plans (``<name>.yaml``)."""
    return project_path("method_configs")


def grammar_spec_path() -> Path:
    """The grammar of Nerfstudio methods."""
    return project_path("grammar_spec.yaml")
