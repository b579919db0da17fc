"""Which plugin ``ns-train nerfify-generated`` trains, resolved explicitly: never a global "last generated".

$NERFIFY_GENERATED names the plugin folder; without it, the newest plugin under the current directory's
``nerfify-out/`` (a folder with ``nerfify.json`` whose verification did not fail; newest by when it was
written). Two runs in parallel (two terminals, a benchmark's workers) therefore never train each other's
plugin: our own runs always pass the plugin in the variable. The entry point imports the plugin's config from
its folder (no installation needed) and renames the method ``GENERATED_METHOD``
(:mod:`nerfify_ns.runtime.launch`).
"""

from __future__ import annotations

import importlib
import json
import os
import sys
from pathlib import Path

from nerfify_ns import runfolder
from nerfify_ns.errors import NerfifyError
from nerfify_ns.runtime.launch import ENV_GENERATED

__all__ = ["ENV_GENERATED", "OUT_DIR", "GeneratedPluginError", "generated_plugin_dir", "load_plugin_method",
           "newest_plugin", "resolve_generated"]

OUT_DIR = "nerfify-out"
"""The folder, under the current directory, whose newest plugin ``nerfify-generated`` trains by default."""


class GeneratedPluginError(NerfifyError):
    """The recorded or named plugin folder cannot be loaded."""


def _verification_failed(folder: Path) -> bool:
    """Whether the run that wrote ``folder`` records a failed verification (``run.json``)."""
    try:
        stages = json.loads((folder / runfolder.OUTCOME).read_text())["stages"]
        return any(s.get("name") == "verify" and s.get("status") == "failed" for s in stages)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def newest_plugin(root: Path) -> Path | None:
    """The newest plugin folder directly under ``root`` (``nerfify.json`` there, verification not failed;
    staging and hidden folders skipped), or None."""
    found = []
    try:
        entries = list(Path(root).iterdir())
    except OSError:
        return None
    for folder in entries:
        meta = folder / runfolder.PLUGIN_META
        if folder.name.startswith(".") or not meta.is_file() or _verification_failed(folder):
            continue
        try:
            found.append((meta.stat().st_mtime, folder.name, folder))
        except OSError:
            continue
    return max(found)[2].absolute() if found else None


def resolve_generated(cwd: Path | None = None) -> tuple[Path | None, str]:
    """The plugin ``nerfify-generated`` trains and how it was chosen: $NERFIFY_GENERATED, else the newest
    plugin under ``cwd/nerfify-out`` (cwd: the current directory), else (None, why not)."""
    named = os.environ.get(ENV_GENERATED)
    if named:
        return Path(named).absolute(), f"${ENV_GENERATED}"
    root = Path(cwd or Path.cwd()) / OUT_DIR
    plugin = newest_plugin(root)
    if plugin is not None:
        return plugin, f"the newest plugin under {root}"
    return None, f"${ENV_GENERATED} is not set and {root} holds no plugin"


def generated_plugin_dir(cwd: Path | None = None) -> Path | None:
    """$NERFIFY_GENERATED, else the newest plugin under ``cwd/nerfify-out``, else None."""
    return resolve_generated(cwd)[0]


def load_plugin_method(plugin_dir: Path):
    """The MethodSpecification of a generated plugin folder, imported from the folder itself."""
    meta_path = Path(plugin_dir) / runfolder.PLUGIN_META
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        raise GeneratedPluginError(f"{plugin_dir} is not a nerfify plugin folder (no readable nerfify.json); "
                                   f"regenerate it or unset ${ENV_GENERATED}") from None
    module_name, var = meta["config"].split(":")
    for name in [m for m in sys.modules if m == meta["package"] or m.startswith(meta["package"] + ".")]:
        del sys.modules[name]  # a different plugin of the same name may have been imported
    sys.path.insert(0, str(Path(plugin_dir).absolute()))  # stays: saved configs name the plugin's modules
    try:
        return getattr(importlib.import_module(module_name), var)
    except Exception as exc:  # generated code may fail in any way; say which plugin and why
        raise GeneratedPluginError(f"cannot import the plugin in {plugin_dir}: {type(exc).__name__}: {exc}") from None
