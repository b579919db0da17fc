"""Method discovery limited to named entry points: an installed plugin that fails to import breaks Nerfstudio's
discovery in every process, except one started with ``isolation_env`` (the benchmark's reference runs)."""

from __future__ import annotations

import os
import subprocess
import sys

from nerfify_ns.runtime.isolated import isolation_env

DISCOVER = ("from nerfstudio.plugins.registry import discover_methods; "
            "print('methods:', ','.join(sorted(discover_methods()[0])))")


def _broken_plugin(folder):
    """A distribution on the path whose nerfstudio.method_configs entry point raises at import (as kplanes-nerfstudio
    0.5.2 does with Nerfstudio 1.1.5)."""
    (folder / "broken_nerf_plugin.py").write_text("from nerfstudio.field_components import shift_directions_for_tcnn\n")
    info = folder / "broken_nerf_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-nerf-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[nerfstudio.method_configs]\nbroken = broken_nerf_plugin:spec\n")


def test_a_broken_plugin_breaks_discovery_except_in_an_isolated_process(tmp_path, monkeypatch):
    site = tmp_path / "site"
    site.mkdir()
    _broken_plugin(site)
    monkeypatch.setenv("PYTHONPATH", str(site))
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    plain = subprocess.run([sys.executable, "-c", DISCOVER], env=env, capture_output=True, text=True, timeout=300)
    assert plain.returncode != 0 and "shift_directions_for_tcnn" in plain.stderr
    isolated = {**env, **isolation_env(tmp_path / "isolation", [])}
    assert isolated["PYTHONPATH"].endswith(str(site))  # the folder goes first, the rest of the path stays
    ok = subprocess.run([sys.executable, "-c", DISCOVER], env=isolated, capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert "methods: nerfify-generated" in ok.stdout and "broken" not in ok.stdout  # ours (the runtime) is kept
