"""Method discovery limited to named entry points, for a process and every Python process it starts.

Nerfstudio's ``discover_methods`` loads every ``nerfstudio.method_configs`` entry point installed, unguarded: one
plugin that fails to import (``kplanes-nerfstudio`` 0.5.2 imports ``shift_directions_for_tcnn``, which Nerfstudio
1.1.5 removed) breaks every ``ns-train`` and ``ns-eval`` in the environment. A reference run of the benchmark is
therefore started with :func:`isolation_env`: a folder holding a ``sitecustomize.py`` goes first on
``PYTHONPATH`` and ``$NERFIFY_METHODS_ONLY`` names the entry points the process may see (the reference's own, plus
``nerfify-generated``, whose import activates our CPU/offline runtime); Python imports ``sitecustomize`` at start-up
in that process, its data-loader workers and its evaluation subprocess alike, and it filters
``importlib.metadata.entry_points`` for that group. Built-in methods are not entry points and stay visible.
"""

from __future__ import annotations

import importlib.metadata as metadata
import os
from collections.abc import Iterable
from pathlib import Path

ENV_ONLY = "NERFIFY_METHODS_ONLY"
GROUP = "nerfstudio.method_configs"
SITECUSTOMIZE = "import nerfify_ns.runtime.isolated as _isolated\n_isolated.apply_from_env()\n"


def apply(allowed: Iterable[str]) -> None:
    """Make ``importlib.metadata.entry_points(group=GROUP)`` return only the entry points named in ``allowed``."""
    from nerfify_ns.runtime.launch import GENERATED_METHOD  # ours, always kept: its import activates the runtime

    allowed = set(allowed) | {GENERATED_METHOD}
    original = getattr(metadata.entry_points, "__wrapped__", metadata.entry_points)

    def entry_points(**params):
        found = original(**params)
        if params.get("group") != GROUP:
            return found
        return metadata.EntryPoints(ep for ep in found if ep.name in allowed)

    entry_points.__wrapped__ = original  # type: ignore[attr-defined]
    metadata.entry_points = entry_points


def apply_from_env() -> None:
    """:func:`apply` with the names in ``$NERFIFY_METHODS_ONLY`` (comma-separated) when it is set."""
    if ENV_ONLY in os.environ:
        apply(n for n in os.environ[ENV_ONLY].split(",") if n)


def isolation_env(folder: Path, methods: Iterable[str] = ()) -> dict[str, str]:
    """Environment variables for a process that sees only ``methods`` (entry-point names) among the installed
    plugins; writes ``folder/sitecustomize.py``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(SITECUSTOMIZE)
    path = os.pathsep.join(p for p in (str(folder.resolve()), os.environ.get("PYTHONPATH", "")) if p)
    return {ENV_ONLY: ",".join(methods), "PYTHONPATH": path}
