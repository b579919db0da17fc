"""``ns-train nerfify-generated`` resolves its plugin explicitly: $NERFIFY_GENERATED, else the
newest plugin under the current directory's ``nerfify-out/``; never a global "last generated" file that two
parallel runs race through. Its first line says which plugin it trains."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from nerfify_ns.runtime.launch import ENV_GENERATED, GENERATED_METHOD
from nerfify_ns.synthesis.plugin_lookup import newest_plugin, resolve_generated

NS_TRAIN = Path(sys.executable).with_name("ns-train")


def fake_plugin(folder: Path, mtime: float, verify: str = "ran") -> Path:
    folder.mkdir(parents=True)
    (folder / "nerfify.json").write_text(json.dumps({"method": folder.name, "package": folder.name}))
    (folder / "run.json").write_text(json.dumps({"stages": [{"name": "verify", "status": verify}]}))
    os.utime(folder / "nerfify.json", (mtime, mtime))
    return folder.absolute()


def test_the_variable_else_the_newest_plugin_under_nerfify_out(tmp_path, monkeypatch):
    monkeypatch.delenv(ENV_GENERATED, raising=False)
    plugin, why = resolve_generated(tmp_path)
    assert plugin is None and "holds no plugin" in why and ENV_GENERATED in why

    out = tmp_path / "nerfify-out"
    old = fake_plugin(out / "old", 1_000)
    new = fake_plugin(out / "new", 2_000)
    fake_plugin(out / "broken", 3_000, verify="failed")  # failed its verification: never trained by default
    fake_plugin(out / ".newer.partial-1-abc", 4_000)  # a run in progress
    (out / "notes").mkdir()
    assert newest_plugin(out) == new
    assert resolve_generated(tmp_path) == (new, f"the newest plugin under {out}")
    os.utime(old / "nerfify.json", (5_000, 5_000))
    assert resolve_generated(tmp_path)[0] == old

    monkeypatch.setenv(ENV_GENERATED, str(new))
    assert resolve_generated(tmp_path) == (new, f"${ENV_GENERATED}")


@pytest.mark.slow
def test_ns_train_says_on_its_first_line_which_plugin_it_trains(tmp_path):
    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.resources import load_reference_plan

    first = compose(load_reference_plan("vanilla-nerf"), tmp_path / "nerfify-out" / "first").out
    second = compose(load_reference_plan("tensorf"), tmp_path / "nerfify-out" / "second").out
    os.utime(first / "nerfify.json", (1_000, 1_000))
    env = {k: v for k, v in os.environ.items() if k != ENV_GENERATED}

    def first_line(**extra) -> str:
        done = subprocess.run([str(NS_TRAIN), GENERATED_METHOD, "--help"], cwd=tmp_path, capture_output=True,
                              text=True, timeout=300, env={**env, **extra})
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout.splitlines()[0]

    assert first_line() == (f"{GENERATED_METHOD}: training the plugin {second} (the newest plugin under "
                            f"{tmp_path / 'nerfify-out'})")
    assert first_line(**{ENV_GENERATED: str(first)}) == \
        f"{GENERATED_METHOD}: training the plugin {first} (${ENV_GENERATED})"
