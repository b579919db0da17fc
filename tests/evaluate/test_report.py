"""evaluate_run (error against time, error maps, consistency) and the self-contained HTML report."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from nerfify_ns.evaluate.report import NOT_RUN, parse_markdown_tables, write_report
from nerfify_ns.evaluate.run_eval import image_diagnostics

NO_WEIGHTS_ENV = {"NERFIFY_LPIPS_WEIGHTS": "none"}
HOSTILE = '<script>alert("x")</script> & <img src=http://example.com/x.png>'
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
SECTIONS = ["paper", "citations", "components", "equations", "verification", "stability", "metrics", "curve",
            "error_maps", "consistency", "patches"]


# ------------------------------------------------------------------------------ fast


def test_image_diagnostics_locate_the_error():
    rng = np.random.default_rng(0)
    gt = np.zeros((32, 32, 4))
    gt[8:24, 8:24, :3] = rng.uniform(size=(16, 16, 3))  # textured object on a transparent background
    gt[8:24, 8:24, 3] = 1.0
    pred = np.ones((32, 32, 3))
    pred[8:24, 8:24] = gt[8:24, 8:24, :3]
    pred[:4, :4] = 0.0  # a dark blotch on the background
    d = image_diagnostics(pred, gt)
    assert d["background_error_share"] == pytest.approx(1.0) and d["background_fraction"] == pytest.approx(0.75)
    assert d["foreground_psnr"] is None or d["foreground_psnr"] > 60
    blurred = np.ones((32, 32, 3))
    blurred[8:24, 8:24] = gt[8:24, 8:24, :3].mean(axis=(0, 1))  # the object's mean colour, no texture
    b = image_diagnostics(blurred, gt)
    assert b["sharpness"] < 0.5 and b["background_error_share"] < 0.05


def test_report_of_an_empty_folder_says_not_run(tmp_path):
    html_path, json_path = write_report(tmp_path)
    report = json.loads(json_path.read_text())
    assert sorted(report["not_run"]) == sorted(SECTIONS)
    text = html_path.read_text()
    assert text.count(NOT_RUN) >= len(SECTIONS) and "<img" not in text


def test_markdown_parts_table():
    text = "# x\n\n| file | part |\n|---|---|\n| `config.py` | method |\n| `field.py` | field |\n\nafter\n| a |\n"
    assert parse_markdown_tables(text) == [{"file": "config.py", "part": "method"},
                                           {"file": "field.py", "part": "field"}]


# ------------------------------------------------------------------------------ a real run folder (slow)


def _small_parts(run: Path) -> None:
    """The parts of a run folder other stages write, as small files in their formats."""
    plan = yaml.safe_load((run / "plan.yaml").read_text())
    plan["holes"] = [{"production": "Regularizers", "text": f"a novel prior {HOSTILE}"}]
    plan["paper"] = {"title": "A Test Paper", "year": 2024, "arxiv": "2401.00001"}
    (run / "plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    (run / "paper.md").write_text(f"# Method\n\nWe render {HOSTILE}.\n\n## Losses\n\n$$L = \\sum_r |C - C'|^2$$\n")
    (run / "evidence.json").write_text(json.dumps([
        {"card": "hash_grid", "title": "Multiresolution hash encoding", "production": "PosEncoding",
         "terminals": ["hash"], "status": "used", "used": True, "confidence": 0.93,
         "evidence": [{"quote": f"we use a hash grid {HOSTILE}", "section": "3.1", "page": 4, "line": None,
                       "kind": "alias", "detail": "hash grid", "role": "method", "weight": 1.0, "usage": True}]}]))
    (run / "citations.json").write_text(json.dumps({
        "graph": {"directed": True, "nodes": [{"id": "target"}, {"id": "instant-ngp"}],
                  "links": [{"source": "target", "target": "instant-ngp", "relation": "uses",
                             "components": ["hash_grid"]}]},
        "resolution": {"filled": ["PosEncoding"]}, "uses": []}))
    (run / "equations.yaml").write_text(yaml.safe_dump({
        "paper": "A Test Paper", "summary": "0 of 1 novel parts implemented from the paper's equations",
        "equations": {"numbered": 1, "read": 1, "displayed": 1}, "seconds": 0.1,
        "holes": [{"id": "prior", "production": "Regularizers", "slot": "model.losses", "status": "not implemented",
                   "reason": f"no equation names the prior {HOSTILE}",
                   "equations": [{"number": "1", "reading": "L = \\sum_r |C - C'|^2", "status": "read",
                                  "where": "Losses"}]}]}, sort_keys=False))
    img = np.full((60, 120, 3), 255, np.uint8)
    img[20:40, 10:30] = (31, 119, 180)
    img[20:40, 90:110] = (255, 127, 14)
    img[29:31, 30:90] = 0
    Image.fromarray(img).save(run / "citations.png")
    (run / "verify.json").write_text(json.dumps({
        "plugin": str(run / "plugin"), "ok": False,
        "rungs": [{"name": "static", "status": "pass", "seconds": 1.2, "checks": 4, "failures": [], "notes": [],
                   "details": {}},
                  {"name": "stability", "status": "fail", "seconds": 3.4, "checks": 2, "notes": [],
                   "failures": [{"rung": "stability", "rule": "finite", "message": "NaN density at far=1e5",
                                 "component": "field", "case": "far_1e5"}],
                   "details": {"cases": [{"component": "field", "case": "near_equals_far", "status": "pass",
                                          "problems": []},
                                         {"component": "field", "case": "far_1e5", "status": "fail",
                                          "problems": ["NaN density"]}]}}],
        "failures": [{"rung": "stability", "rule": "finite", "message": "NaN density at far=1e5",
                      "component": "field"}], "patches": [], "notes": [], "rounds": []}))
    (run / "patches").mkdir()
    (run / "patches" / "history.json").write_text(json.dumps({
        "noise_definition": "spread of 2 seeds", "stopped": "round budget (1) spent", "best_psnr": 14.6,
        "rounds": [{"round": 0, "psnr": 10.65, "psnr_runs": [10.5, 10.8], "noise": 0.3,
                    "diagnoses": [{"name": "floaters"}, {"name": "blur_high_frequency"}], "kept": "more_samples"}],
        "entries": [
            {"round": 0, "diagnosis": {"name": "floaters"}, "patch": {"rule": "add_distortion_loss", "edits": [
                {"op": "add", "path": "model.losses.distortion", "value": {"weight": 0.002}}]},
             "psnr_before": 10.65, "psnr_after": 10.75, "noise": 0.3, "decision": "rejected",
             "reason": "PSNR change +0.10 dB does not exceed the noise threshold 0.30 dB"},
            {"round": 0, "diagnosis": {"name": "blur_high_frequency"}, "patch": {"rule": "more_samples", "edits": []},
             "psnr_before": 10.65, "psnr_after": 14.6, "noise": 0.3, "decision": "kept", "reason": "+3.95 dB"}]}))


def _references(text: str):
    """The tags of an HTML page and every URL-valued attribute (src, href, srcset, ...)."""
    from html.parser import HTMLParser

    tags, refs = set(), []

    class Collect(HTMLParser):
        def handle_starttag(self, tag, attrs):
            tags.add(tag)
            refs.extend(v or "" for k, v in attrs if k in ("src", "href", "srcset", "poster", "action", "data",
                                                            "background", "xlink:href"))

    Collect().feed(text)
    return tags, refs


def _chromium(args, tmp: Path, timeout: float = 90) -> subprocess.CompletedProcess:
    binary = shutil.which("chromium")
    return subprocess.run([binary, *CHROMIUM_FLAGS, f"--user-data-dir={tmp / 'chromium-profile'}", *args],
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_evaluate_run_and_report_open_offline_in_chromium(tiny_scene, tmp_path):
    """A real 20-iteration run of a composed nerfacto plan (32x32, 2 test views; about 1-2 min on 2 shared
    cores), small JSON files for the other stages, the report, and headless Chromium loading it."""
    from nerfify_ns.evaluate.run_eval import evaluate_run
    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene

    run = tmp_path / "run"
    plan = prune_plan(load_reference_plan("nerfacto"), probe_scene(tiny_scene))
    plan["trainer"]["mixed_precision"] = False
    run.mkdir()
    (run / "plan.yaml").write_text(yaml.safe_dump(plan, sort_keys=False))
    plugin = compose(plan, run / "plugin", record=False)
    summary = evaluate_run(plugin.out, tiny_scene, run / "eval", iterations=20, every=10, label="nerfacto-ref",
                           seed=0, env=NO_WEIGHTS_ENV, timeout=600)
    assert summary["status"] == "ok", summary
    assert "no-network" in summary["isolation"]  # the plugin trains in the sandbox
    assert summary["psnr"] > 8 and 0 < summary["ssim"] <= 1 and summary["seconds"] > 0
    assert json.loads((run / "eval" / "summary.json").read_text())["psnr"] == summary["psnr"]
    for name in ("curve.csv", "curve.png", "error_maps.json", "consistency.json", "r_0_errors.png",
                 "r_1_inconsistent.png", "renders/r_0_depth.npy"):
        assert (run / "eval" / name).is_file(), name
    assert [row.split(",")[1] for row in (run / "eval" / "curve.csv").read_text().split()[1:]] == ["11", "20"]
    _small_parts(run)

    html_path, json_path = write_report(run)
    report = json.loads(json_path.read_text())
    assert report["not_run"] == []
    sections = report["sections"]
    assert sections["metrics"]["psnr"] == pytest.approx(summary["psnr"])
    assert sections["verification"]["status"] == "fail"
    assert [c["case"] for c in sections["stability"]["cases"]] == ["near_equals_far", "far_1e5"]
    assert [e["decision"] for e in sections["patches"]["entries"]] == ["rejected", "kept"]
    assert sections["components"]["holes"][0]["production"] == "Regularizers"
    assert "config.py" in " ".join(sections["components"]["files"]) and sections["components"]["parts"]
    assert sections["error_maps"]["views"] == 2 and len(sections["curve"]["points"]) == 2
    assert sections["paper"]["evidence"][0]["quote"].startswith("we use a hash grid")
    # 1 citation graph + 1 curve + 2 error panels + 2 consistency masks; the best and the worst view's panels
    # again at the top of the report
    assert len(report["images"]) == 8 and len(set(report["images"])) == 6, report["images"]

    text = html_path.read_text()
    assert "&lt;script&gt;" in text and "&lt;img src=http://example.com" in text  # text is escaped
    tags, refs = _references(text)
    assert not tags & {"script", "link", "iframe", "object", "embed", "base"}, tags
    assert refs and all(r.startswith(("data:image/", "#")) for r in refs), [r[:40] for r in refs]
    css = "".join(re.findall(r"<style>(.*?)</style>", text, re.S))
    assert css and "url(" not in css and "@import" not in css
    assert sum(r.startswith("data:image/png;base64,") for r in refs) == 8

    if shutil.which("chromium") is None:
        pytest.skip("chromium not installed (apt-get install -y chromium); the report itself was checked")
    # the images decode in a real browser: an inline script (in a copy) writes the results into the DOM
    probe = tmp_path / "probe.html"
    probe.write_text(text.replace("</body>", "<script>window.addEventListener('load', () => {"
                                  "document.body.setAttribute('data-images', [...document.images].map("
                                  "i => i.complete && i.naturalWidth > 0).join(','));});</script></body>"))
    dom = _chromium(["--virtual-time-budget=5000", "--dump-dom", probe.as_uri()], tmp_path)
    match = re.search(r'data-images="([^"]*)"', dom.stdout)
    assert match, dom.stderr[-2000:]
    assert match.group(1).split(",") == ["true"] * 8
    shot = tmp_path / "report.png"
    _chromium(["--window-size=1200,2400", f"--screenshot={shot}", html_path.as_uri()], tmp_path)
    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(float)
    assert pixels.shape[:2] == (2400, 1200) and pixels.std() > 10  # not blank


def test_report_command_is_a_tyro_command(tmp_path):
    import tyro

    from nerfify_ns.evaluate.report_command import Report

    command = tyro.cli(Report, args=[str(tmp_path), "--quiet"])
    assert command.run_dir == tmp_path and command.quiet
    command.main()
    assert (tmp_path / "report.html").is_file() and (tmp_path / "report.json").is_file()
