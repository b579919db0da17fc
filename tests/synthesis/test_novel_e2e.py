"""The equation compiler inside ``ns-nerfify PAPER``: the run folder's equations.yaml, --equations reruns, the
report; one representative paper through every rung in CI (slow); the shared papers through every rung and a
training run whose loss falls (bench lane: minutes each on a CPU)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml
from novel_papers import GATENERF

from nerfify_ns.budget import Budget
from nerfify_ns.pipeline import PaperOptions, RunOptions, run_compose, run_paper
from nerfify_ns.synthesis.novel import IMPLEMENTED, NOT_IMPLEMENTED, implement_holes
from nerfify_ns.synthesis.novel.records import EquationsFileError

PAPERS = Path(__file__).resolve().parents[2].parent / "shared" / "papers"
SMALL = Budget(iterations=20, every=20, cpu_presets=True,
               train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
               scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})


@pytest.fixture()
def gatenerf(tmp_path) -> Path:
    path = tmp_path / "gatenerf.md"
    path.write_text(GATENERF)
    return path


def test_the_run_folder_records_and_a_corrupted_equation_leaves_the_base_part(gatenerf, tmp_path):
    """--until plan: equations.yaml and the rendered equations are written; a person's corrupted equation (an
    unknown operator) is reported with its reason, the run finishes with the base's backbone; fixing it compiles it."""
    first = run_paper(gatenerf, tmp_path / "first", options=PaperOptions(until="plan", budget=SMALL))
    assert first.outcome.failed is None
    records = yaml.safe_load((first.out / "equations.yaml").read_text())
    (hole,) = records["holes"]
    assert hole["status"] == IMPLEMENTED and (first.out / "equations" / "backbone.py").is_file()
    assert hole["equations"][0]["image"] == "backbone/eq0.png"
    assert (first.out / "equations" / "backbone" / "eq0.png").is_file()
    assert yaml.safe_load((first.out / "plan.yaml").read_text())["model"]["field"]["MLPField"]["backbone"]["custom"]
    report = json.loads((first.out / "report.json").read_text())
    assert report["outcome"]["headline"].startswith("Novel parts: 1 of 1 found built and verified")
    assert report["sections"]["equations"]["implemented"] == 1

    good = hole["equations"][1]["latex"]
    hole["equations"][1]["latex"] = good.replace(r"\tanh(", r"\mathcal{F}(")
    corrected = tmp_path / "equations.yaml"
    corrected.write_text(yaml.safe_dump(records, sort_keys=False))
    broken = run_paper(gatenerf, tmp_path / "broken", options=PaperOptions(until="plan", budget=SMALL,
                                                                           equations=corrected))
    assert broken.outcome.failed is None
    (hole_b,) = yaml.safe_load((broken.out / "equations.yaml").read_text())["holes"]
    assert hole_b["status"] == NOT_IMPLEMENTED and "unknown operator" in hole_b["reason"]
    assert "custom" not in yaml.safe_load((broken.out / "plan.yaml").read_text())["model"]["field"]["MLPField"][
        "backbone"]  # the base's part stands in

    records = yaml.safe_load((broken.out / "equations.yaml").read_text())
    records["holes"][0]["equations"][1]["latex"] = good
    corrected.write_text(yaml.safe_dump(records, sort_keys=False))
    fixed = run_paper(gatenerf, tmp_path / "fixed", options=PaperOptions(until="plan", budget=SMALL,
                                                                         equations=corrected))
    (hole_f,) = yaml.safe_load((fixed.out / "equations.yaml").read_text())["holes"]
    assert hole_f["status"] == IMPLEMENTED


def test_a_bad_equations_file_writes_nothing(gatenerf, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("- not: a mapping\n")
    with pytest.raises(EquationsFileError):
        run_paper(gatenerf, tmp_path / "out", options=PaperOptions(until="plan", equations=bad))
    assert not (tmp_path / "out").exists()


def test_the_cli_refuses_a_bad_equations_file_in_one_line(gatenerf, tmp_path):
    import subprocess
    import sys

    bad = tmp_path / "equations.yaml"
    bad.write_text("holes: 3\n")
    cli = Path(sys.executable).with_name("ns-nerfify")
    out = subprocess.run([str(cli), str(gatenerf), "--equations", str(bad), "--out", str(tmp_path / "out")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 2 and "--equations" in out.stdout + out.stderr and "not an equations.yaml" in \
        out.stdout + out.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_paper_never_seen_passes_every_rung(gatenerf, tmp_path):
    """GateNeRF's compiled backbone (gates and a memory) in the plugin: static, contract, stability and smoke."""
    result = run_paper(gatenerf, tmp_path / "run", options=PaperOptions(until="verify", budget=SMALL))
    assert result.outcome.failed is None, result.outcome.failed
    ladder = json.loads((result.out / "verify.json").read_text())
    assert ladder["ok"] and [r["name"] for r in ladder["rungs"]] == ["static", "contract", "stability", "smoke"]
    cases = [c for r in ladder["rungs"] for c in (r.get("details") or {}).get("cases", [])]
    assert any(str(c.get("component", "")).startswith("custom BackboneFromEquations") and c["status"] == "pass"
               for c in cases)


# ------------------------------------------------------------------------------------------ bench lane
def _loss_fell(out: Path) -> tuple[bool, str]:
    from nerfify_ns.runtime.events import losses, read_scalars

    runs = [p.parent for p in (out / "eval" / "train").rglob("events.out.tfevents*")]
    assert runs, "no training events"
    values = [v for _, v in sorted(losses(read_scalars(runs[0])).items())]
    k = max(1, len(values) // 5)
    first, last = sum(values[:k]) / k, sum(values[-k:]) / k
    ok = all(math.isfinite(v) for v in values) and last < first
    return ok, f"{len(values)} losses, mean of the first 20% {first:.4f}, of the last 20% {last:.4f}"


def _kept(built, trained) -> bool:
    """Whether the plan that trained holds the part as it was built: the same compiled component (module and
    class; the run adds scene facts such as the background to its parameters), or the same terminals and typed
    options with the same values."""
    if not isinstance(built, dict) or not isinstance(trained, dict):
        return built == trained
    if "custom" in built:
        ours, theirs = built["custom"], trained.get("custom") or {}
        return (ours.get("module"), ours.get("class")) == (theirs.get("module"), theirs.get("class"))
    return set(built) == set(trained) and all(
        _kept(v, trained[k]) if isinstance(v, dict) else v == trained[k] for k, v in built.items())


def _at(plan: dict, slot: str):
    """The plan's node at a record's dotted ``slot`` (None when the path is gone)."""
    node = plan
    for key in slot.split("."):
        node = node.get(key) if isinstance(node, dict) else None
    return node


@pytest.mark.bench
@pytest.mark.parametrize("paper", ["bionerf/bionerf.pdf", "gh_nerf/gh_nerf.pdf", "seathru_nerf/seathru_condensed.md",
                                   "seathru_nerf/seathru_nerf_appendix.pdf"])
def test_shared_papers_compiled_parts_pass_every_rung_and_train(paper, tmp_path):
    """Every part of the paper that was built passes static, contract, stability and smoke, stays in the plan the
    training ran (never reverted), and the training's loss falls; each found part not built has its recorded
    reason."""
    from nerfify_ns.paper import ingest
    from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

    path = PAPERS / paper
    if not path.is_file():
        pytest.skip(f"real paper {path} not present (../shared/papers is outside the project and never committed)")
    doc = ingest(path)
    implementation = implement_holes(doc, plan_from_paper(doc).plan)
    built = [r for r in implementation.records if r.status != NOT_IMPLEMENTED]
    assert built and implementation.sources, [(r.id, r.status, r.reason) for r in implementation.records]
    unbuilt = [r.id for r in implementation.records if r.status == NOT_IMPLEMENTED and not r.reason.strip()]
    assert not unbuilt, f"found parts not built without a recorded reason: {unbuilt}"
    budget = Budget(iterations=80, every=80, cpu_presets=True, timeout=3600,
                    train_args=("--pipeline.datamanager.train-num-rays-per-batch", "256"),
                    scene={"resolution": 32, "n_train": 12, "n_val": 2, "n_test": 2})
    result = run_compose(implementation.plan, tmp_path / "run", options=RunOptions(budget=budget),
                         sources=implementation.sources)
    assert result.outcome.failed is None, result.outcome.failed
    ladder = json.loads((result.out / "verify.json").read_text())
    assert ladder["ok"] and [(r["name"], r["status"]) for r in ladder["rungs"]] == [
        ("static", "pass"), ("contract", "pass"), ("stability", "pass"), ("smoke", "pass")], ladder["rungs"]
    trained = yaml.safe_load((result.out / "plan.yaml").read_text())
    # a part is built as a compiled component (``custom``) or, from its sentences, as the typed options of a terminal
    # (a backbone's ``hidden_norm``, a ``field_blend`` wrapper): either way the plan that trained still holds it
    reverted = [r.slot for r in built if not _kept(_at(implementation.plan, r.slot), _at(trained, r.slot))]
    assert not reverted, f"built parts missing from the plan that trained: {reverted}"
    ok, what = _loss_fell(result.out)
    assert ok, what
