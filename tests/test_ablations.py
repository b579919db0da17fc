"""Each ablation is a real switch of the pipeline: a cheap test per ablation shows that it changes what the
pipeline does (the plan's base, the citations followed, the holes compiled, the stages run, the composition)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nerfify_ns.ablations import ABLATIONS, NAMES, AblationError, Ablations
from nerfify_ns.knowledge.citations import build_citation_graph
from nerfify_ns.knowledge.detect import detect_techniques
from nerfify_ns.paper import ingest
from nerfify_ns.synthesis.plan_from_paper import derive_plan

ROOT = Path(__file__).resolve().parents[1]
GLINTFIELD = ROOT / "examples" / "glintfield_paper.md"  # states its base (nerfacto) and cites what it adopts
GRIDLITE = ROOT / "examples" / "gridlite_paper.md"


def test_names_parse_and_unknown_names_are_refused():
    assert Ablations.parse("").full and Ablations.parse("no-citations, one-shot").names == ("no-citations", "one-shot")
    assert set(Ablations.of(NAMES).names) == set(NAMES) == {a.name for a in ABLATIONS} and len(NAMES) == 7
    with pytest.raises(AblationError, match="unknown ablation 'no-ladder'; known: no-reference-plans"):
        Ablations.parse("no-ladder")


@pytest.fixture(scope="module")
def glintfield():
    doc = ingest(GLINTFIELD)
    return doc, detect_techniques(doc)


def test_no_reference_plans_starts_from_the_plainest_base(glintfield):
    doc, detections = glintfield
    graph = build_citation_graph(doc, detections)
    assert derive_plan(doc, detections, graph).base == "nerfacto"  # the paper states it
    ablated = derive_plan(doc, detections, graph, reference_plans=False)
    assert ablated.base == "vanilla-nerf" and "ablation no-reference-plans" in ablated.base_reason


def test_no_citations_follows_no_reference(glintfield):
    doc, detections = glintfield
    full, ablated = build_citation_graph(doc, detections), build_citation_graph(doc, detections, follow=False)
    taken = {c.card for c in full.resolution.taken}
    assert full.uses and not ablated.uses and ablated.target_paper is None
    lost = taken - {c.card for c in ablated.resolution.taken}
    assert "appearance_embedding" in lost  # adopted from a cited work: gone without citation recovery
    # what the cited work supplied is now reported as not recovered (the paper's own parts, its holes, do not depend
    # on its citations: they come from its claims and its equations' structure)
    plain, recovered = derive_plan(doc, detections, ablated), derive_plan(doc, detections, full)
    assert set(plain.missing) > set(recovered.missing)
    assert [h["production"] for h in plain.holes] == [h["production"] for h in recovered.holes]


class _StandIns:
    """Stand-ins for the expensive stages (ladder, training, patch loop) that record whether they were called."""

    def __init__(self, monkeypatch):
        from nerfify_ns import verify
        from nerfify_ns.evaluate import patch_loop, run_eval

        self.calls = []
        monkeypatch.setattr(verify, "run_ladder", self._ladder)
        monkeypatch.setattr(run_eval, "evaluate_run", self._evaluate)
        monkeypatch.setattr(patch_loop, "run_patch_loop", self._patches)

    def _ladder(self, *args, **kwargs):
        self.calls.append("verify")
        raise RuntimeError("stand-in ladder")  # a full run gets this far: the test below sees it

    def _evaluate(self, *args, **kwargs):
        self.calls.append("train")
        return {"status": "failed", "reason": "stand-in evaluation"}

    def _patches(self, *args, **kwargs):
        self.calls.append("patches")
        raise RuntimeError("stand-in patch loop")


def test_no_verify_and_no_visual_feedback_skip_their_stages(tmp_path, monkeypatch):
    """With both switched off, the plugin goes straight to training (a stand-in) and no patch loop runs although
    --patch-rounds asks for one; run.json says which ablations and why the stages did not run. Without them the
    ladder runs (its stand-in raises, which the full pipeline propagates)."""
    from nerfify_ns.budget import Budget
    from nerfify_ns.pipeline import PaperOptions, run_paper

    budget = Budget(iterations=2, every=2, scene={"resolution": 16, "n_train": 4, "n_val": 1, "n_test": 1})
    stand_ins = _StandIns(monkeypatch)
    result = run_paper(GRIDLITE, tmp_path / "ablated", options=PaperOptions(budget=budget, patch_rounds=1,
                                                                            ablations=Ablations.parse("no-verify,no-visual-feedback")))
    assert stand_ins.calls == ["train"]
    run = json.loads((result.out / "run.json").read_text())
    assert run["ablations"] == ["no-verify", "no-visual-feedback"]
    stages = {s["name"]: s for s in run["stages"]}
    assert stages["verify"]["reason"] == "switched off (ablation no-verify)"
    assert stages["train"]["status"] == "failed"
    stand_ins.calls.clear()
    with pytest.raises(RuntimeError, match="stand-in ladder"):
        run_paper(GRIDLITE, tmp_path / "full", options=PaperOptions(budget=budget, patch_rounds=1))
    assert stand_ins.calls == ["verify"]


def test_no_equations_leaves_every_hole_to_the_base():
    from nerfify_ns.pipeline import PaperOptions, run_paper

    full = run_paper(GLINTFIELD, options=PaperOptions(dry_run=True))
    ablated = run_paper(GLINTFIELD, options=PaperOptions(dry_run=True, ablations=Ablations.parse("no-equations")))
    assert full.implementation.records and not ablated.implementation.records
    assert not any("custom" in json.dumps(h) for h in ablated.plan.get("holes") or [] if h.get("status"))


def test_one_shot_composition_writes_what_the_file_dag_would_refuse(tmp_path, monkeypatch):
    """The file DAG parses and formats each file as it is written (a template bug stops composition); one shot
    renders every file in one pass and leaves a broken file for the ladder's static rung."""
    from nerfify_ns.synthesis import compose
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = load_reference_plan("vanilla-nerf")
    (tmp_path / "dag").mkdir(), (tmp_path / "one").mkdir()
    dag = compose.write_plugin(plan, tmp_path / "dag")
    one = compose.write_plugin(plan, tmp_path / "one", one_shot=True)
    assert json.loads((tmp_path / "one" / "nerfify.json").read_text())["composition"] == "one-shot"
    model = f"{dag.package}/model.py"
    assert (tmp_path / "dag" / model).read_text() != (tmp_path / "one" / model).read_text()  # not formatted

    render = compose._render

    def broken_model(env, f, ctx, plan, sources):
        text = render(env, f, ctx, plan, sources)
        return text + "\ndef broken(:\n" if f.path.endswith("model.py") else text

    monkeypatch.setattr(compose, "_render", broken_model)
    (tmp_path / "dag2").mkdir(), (tmp_path / "one2").mkdir()
    with pytest.raises(compose.CompositionError, match="does not parse"):
        compose.write_plugin(plan, tmp_path / "dag2")
    compose.write_plugin(plan, tmp_path / "one2", one_shot=True)
    assert "def broken(:" in (tmp_path / "one2" / model).read_text()
    assert one.files == dag.files or set(one.files) == set(dag.files)


def test_no_agents_sets_the_model_agents_aside():
    """With agents given (a stand-in for ``nerfify_ns.agents.Agents``), the planner is asked for a plan; with the
    ablation no-agents it is not, and the dry run's plan is the deterministic one."""
    from nerfify_ns.pipeline import PaperOptions, run_paper

    class StandInAgents:
        warnings: list = []

        def __init__(self):
            self.calls = []

        def plan(self, doc, derived):
            self.calls.append("plan")
            return derived.plan

        def summary(self):
            return "stand-in"

    agents = StandInAgents()
    run_paper(GRIDLITE, options=PaperOptions(dry_run=True, agents=agents))
    assert agents.calls == ["plan"]
    agents.calls.clear()
    run_paper(GRIDLITE, options=PaperOptions(dry_run=True, agents=agents, ablations=Ablations.parse("no-agents")))
    assert agents.calls == []
