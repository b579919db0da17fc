"""Hatchling build hook: a built wheel carries the project data kept at the top of the repository.

``pyproject.toml`` names the data (``project-data``) and where it goes in the wheel (``data-dir``,
``nerfify_ns/_data``). Only standard wheels get it: an editable install reads it from the checkout,
so nothing is copied into site-packages that could go stale (``nerfify_ns/package_data.py`` finds either).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hatchling.builders.hooks.plugin.interface import BuildHookInterface


class ProjectDataHook(BuildHookInterface):
    """Maps each ``project-data`` entry to ``<data-dir>/<entry>`` in a standard wheel."""

    PLUGIN_NAME = "custom"

    def initialize(self, version: str, build_data: dict[str, Any]) -> None:
        """Add the project data to the wheel's forced inclusions (standard builds only)."""
        if version != "standard":
            return
        data_dir = self.config["data-dir"]
        for name in self.config["project-data"]:
            if not (Path(self.root) / name).exists():
                raise FileNotFoundError(f"project data {name!r} is missing from {self.root}")
            build_data["force_include"][name] = f"{data_dir}/{name}"
