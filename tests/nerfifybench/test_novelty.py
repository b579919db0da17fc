"""Novelty coverage from the run's records: checks run in the sandbox on the generated component (pass C, fail I,
raise I with the error reported), items without a check are I (never C), absent items M, W within 10% of the paper's
values as derived (before the scene's pruning)."""

from __future__ import annotations

import json

import pytest
import yaml

from nerfify_ns.nerfifybench import load_suite
from nerfify_ns.nerfifybench.novelty import coverage, score_items

COMPONENT = '''
class ScaleFromEquations:
    """Eq. 2 as generated: y = 2 x."""
    def __init__(self, factor=2.0):
        self.factor = factor
    def __call__(self, x):
        return [self.factor * v for v in x]
'''
CHECKS = '''
def doubles(target):
    assert target.cls()([1.0, 2.0]) == [2.0, 4.0]

def triples(target):
    assert target.cls()([1.0]) == [3.0], "Eq. 2 scales by 3"

def raises(target):
    return 1 / 0

def escapes(target):
    import os
    open(os.path.join(os.path.dirname(__file__), "escaped.txt"), "w").write("x")  # the suite folder: read-only
'''
SUITE = '''
papers:
  - id: p
    input: paper.md
    scenes: [default]
    reference: nerfacto
    novelty:
      - {id: scale, kind: equation, weight: 1.0, where: "Eq. 2", check: "checks.py:doubles"}
      - {id: scale-wrong, kind: equation, weight: 0.5, where: "Eq. 2", check: "checks.py:triples"}
      - {id: scale-raises, kind: equation, weight: 0.5, where: "Eq. 2", check: "checks.py:raises"}
      - {id: escapes, kind: equation, weight: 0.5, where: "Eq. 2", check: "checks.py:escapes"}
      - id: hash
        kind: hyperparameter
        weight: 0.5
        where: Sec. 3
        plan: model.field.pos_encoding.hash
        values: {model.field.pos_encoding.hash.num_levels: 16, model.field.pos_encoding.hash.max_res: 2048}
      - {id: absent, kind: loss, weight: 1.0, where: "Eq. 9", plan: model.losses.tv}
'''


@pytest.fixture()
def run_folder(tmp_path):
    """A run folder as the pipeline writes it: plan.yaml (a compiled component implementing Eq. 2, a hash encoding
    whose max_res the scene's pruning shrank), nerfify.json and the component's file in the plugin."""
    run = tmp_path / "run"
    (run / "pkg" / "components").mkdir(parents=True)
    (run / "pkg" / "components" / "scale_equations.py").write_text(COMPONENT)
    (run / "nerfify.json").write_text(json.dumps({"package": "pkg"}))
    plan = {"method": "p", "model": {"field": {
        "pos_encoding": {"hash": {"num_levels": 18, "max_res": 64}},
        "rgb_head": {"custom": {"module": "components.scale_equations", "class": "ScaleFromEquations",
                                "implements": ["Eq. 2"], "source": "compiler", "evidence": "Sec. 3: y = 2 x"}}}},
        "evidence": {"model.field.pos_encoding": "l.3, Sec. 3: \"a hash grid of 16 levels\""},
        "pruned": [{"rule": "small", "path": "model.field.pos_encoding.hash.max_res", "action": "shrunk",
                    "from": 2048, "to": 64, "reason": "a 32 px scene"}]}
    (run / "plan.yaml").write_text(yaml.safe_dump(plan))
    (tmp_path / "suite").mkdir()
    (tmp_path / "suite" / "checks.py").write_text(CHECKS)
    (tmp_path / "suite" / "suite.yaml").write_text(SUITE)
    return run, load_suite(tmp_path / "suite" / "suite.yaml").papers[0]


def test_items_are_scored_from_checks_and_evidence(run_folder, tmp_path):
    run, entry = run_folder
    scores = {s.id: s for s in score_items(entry, run, tmp_path / "work", timeout=120)}
    assert (scores["scale"].status, scores["scale"].how) == ("C", "check-passed")
    assert scores["scale"].path == "model.field.rgb_head.custom" and "y = 2 x" in scores["scale"].evidence
    assert (scores["scale-wrong"].status, scores["scale-wrong"].how) == ("I", "check-failed")
    assert "scales by 3" in scores["scale-wrong"].message
    assert (scores["scale-raises"].status, scores["scale-raises"].how) == ("I", "check-errored")
    assert "ZeroDivisionError" in scores["scale-raises"].message and "checks.py" in scores["scale-raises"].message
    assert scores["escapes"].how == "check-errored" and "Read-only file system" in scores["escapes"].message
    assert not (tmp_path / "suite" / "escaped.txt").exists()  # the check ran in the sandbox
    hash_item = scores["hash"]
    assert (hash_item.status, hash_item.how) == ("I", "no-check") and "16 levels" in hash_item.evidence
    assert hash_item.values["model.field.pos_encoding.hash.max_res"]["match"]  # 2048 before pruning
    assert not hash_item.values["model.field.pos_encoding.hash.num_levels"]["match"]  # 18 vs 16: not within 10%
    assert (scores["absent"].status, scores["absent"].how) == ("M", "not-found")
    cov = coverage(list(scores.values()))
    assert cov["C"] == pytest.approx(1 / 6) and cov["I"] == pytest.approx(4 / 6) and cov["M"] == pytest.approx(1 / 6)
    assert cov["W"] == 0.0 and cov["unchecked"] == 1 and len(cov["check_errors"]) == 2
    weights = 1.0 + 0.5 + 0.5 + 0.5 + 0.5 + 1.0
    assert cov["score"] == pytest.approx((1.0 * 1 + 0.5 * 0.5 * 4 + 0) / weights)


def test_no_plan_means_every_item_is_missing(run_folder, tmp_path):
    _, entry = run_folder
    scores = score_items(entry, None, tmp_path / "work", timeout=60)
    assert {s.status for s in scores} == {"M"} and coverage(scores)["score"] == 0.0
