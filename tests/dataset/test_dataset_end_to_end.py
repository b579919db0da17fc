"""A user's Nerfstudio-format dataset end to end, as a user runs it (``ns-nerfify PAPER --data DIR``), up to the
verification ladder: the format is detected and named in the plan's scene facts and the report, and the smoke
rung trains through Nerfstudio's nerfstudio-data dataparser (not blender-data, which crashed on it)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from nerfify_ns.dataset import read_dataset
from nerfify_ns.dataset.convert import export_dataset
from nerfify_ns.scenes import write_scene

ROOT = Path(__file__).resolve().parents[2]
CLI = Path(sys.executable).with_name("ns-nerfify")
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


@pytest.mark.slow
def test_a_nerfstudio_dataset_passes_the_smoke_rung_through_nerfstudio_data(tmp_path):
    source = read_dataset(write_scene("default", tmp_path / "blender", resolution=32, n_train=12, n_val=1, n_test=3))
    data = export_dataset(source, "nerfstudio", tmp_path / "capture", rgb=True)
    out = tmp_path / "out"
    done = subprocess.run([str(CLI), str(EXAMPLE), "--data", str(data), "--until", "verify", "--out", str(out)],
                          capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "nerfstudio dataset" in done.stdout  # the plan stage's line

    plan = yaml.safe_load((out / "plan.yaml").read_text())
    assert plan["scene"]["format"] == "nerfstudio" and plan["datamanager"]["dataparser"] == "nerfstudio"
    assert plan["evidence"]["scene"].startswith("format: nerfstudio: transforms.json (Nerfstudio format)")

    verify = json.loads((out / "verify.json").read_text())
    smoke = next(r for r in verify["rungs"] if r["name"] == "smoke")
    assert smoke["status"] == "pass", smoke
    config = next((out / "verify").rglob("config.yml")).read_text()
    assert "NerfstudioDataParserConfig" in config and "BlenderDataParserConfig" not in config

    report = json.loads((out / "report.json").read_text())
    assert report["sections"]["paper"]["scene"]["format"] == "nerfstudio"
    assert "transforms.json (Nerfstudio format)" in (out / "report.html").read_text()
