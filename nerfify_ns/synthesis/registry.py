"""Which plugin ``ns-train nerfify-generated`` trains: the one generated last, or $NERFIFY_GENERATED.

The composer records every plugin it writes; the entry point imports the recorded plugin's
config from its folder (no installation needed) and renames the method ``GENERATED_METHOD``
(:mod:`nerfify_ns.runtime.launch`).
"""

from __future__ import annotations

import importlib
import json
import os
import sys
from pathlib import Path
from typing import Optional

from nerfify_ns.errors import NerfifyError
from nerfify_ns.runtime.launch import ENV_GENERATED
from nerfify_ns.runtime.paths import nerfify_cache_dir

__all__ = ["ENV_GENERATED", "GeneratedPluginError", "generated_plugin_dir", "load_plugin_method",
           "record_generated"]


class GeneratedPluginError(NerfifyError):
    """The recorded or named plugin folder cannot be loaded."""


def _record_file() -> Path:
    return nerfify_cache_dir() / "generated" / "last.json"


def record_generated(plugin_dir: Path) -> None:
    """Remember ``plugin_dir`` as the plugin generated last."""
    path = _record_file()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"plugin": str(Path(plugin_dir).absolute())}))
    tmp.replace(path)


def generated_plugin_dir() -> Optional[Path]:
    """$NERFIFY_GENERATED, else the plugin generated last, else None."""
    named = os.environ.get(ENV_GENERATED)
    if named:
        return Path(named)
    try:
        return Path(json.loads(_record_file().read_text())["plugin"])
    except (OSError, ValueError, KeyError):
        return None


def load_plugin_method(plugin_dir: Path):
    """The MethodSpecification of a generated plugin folder, imported from the folder itself."""
    meta_path = Path(plugin_dir) / "nerfify.json"
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
