"""A pip-installed generated plugin trains on the CPU by default on a machine without CUDA: the runtime's
``cpu_default`` reaches the configs of every plugin Nerfstudio discovers, whichever entry point was loaded first
(Nerfstudio keeps the discovered configs apart from its own until every entry point has loaded). Checked with the
real ``ns-train`` of a plugin installed into a folder of the test's own (never the shared environment)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from nerfify_ns.synthesis.compose import compose
from nerfify_ns.synthesis.resources import load_reference_plan


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[str, dict]:
    """A generated plugin installed into its own folder, and the environment that puts it on the path."""
    tmp = tmp_path_factory.mktemp("cpu_default")
    plugin = compose(load_reference_plan("vanilla-nerf"), tmp / "plugin", record=False)
    site = tmp / "site"
    out = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index",
                          "-q", "--target", str(site), str(plugin.out)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-1500:] + out.stderr[-1500:]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")])),
           "CUDA_VISIBLE_DEVICES": ""}
    return plugin.method, env


@pytest.mark.slow
def test_ns_train_of_an_installed_plugin_defaults_to_the_cpu(installed):
    method, env = installed
    ns_train = Path(sys.executable).with_name("ns-train")
    out = subprocess.run([str(ns_train), method, "--help"], capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    text = re.sub(r"[│\s]+", " ", out.stdout)
    found = re.search(r"--machine\.device-type \{cpu,cuda,mps\} .*?\(default: (\w+)\)", text)
    assert found, text[-2000:]
    assert found.group(1) == "cpu"


@pytest.mark.slow
@pytest.mark.parametrize("hash_seed", ["0", "1"])
def test_every_discovered_config_is_on_the_cpu_whichever_entry_point_loads_first(installed, hash_seed):
    """Nerfstudio loads the entry points in the order of a set of names (it changes with the string hash seed)."""
    method, env = installed
    code = ("from nerfstudio.configs.method_configs import all_methods as m; "
            f"print(m[{method!r}].machine.device_type, m['vanilla-nerf'].machine.device_type)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         env={**env, "PYTHONHASHSEED": hash_seed})
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-2:] == ["cpu", "cpu"]
