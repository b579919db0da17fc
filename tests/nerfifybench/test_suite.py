"""The suite file: the repository's suites load; every malformed suite is one line naming the key (exit 2, nothing
written from the command line)."""

from __future__ import annotations

from pathlib import Path

import pytest

from nerfify_ns.nerfifybench import SuiteError, load_suite
from nerfify_ns.nerfifybench.suite import equation_numbers

ROOT = Path(__file__).resolve().parents[2]
SUITES = ROOT / "examples" / "bench"

GOOD = """
budget: {iterations: 4, every: 2}
papers:
  - id: p1
    input: paper.md
    scenes: [default]
    reference: nerfacto
    novelty:
      - {id: a, kind: equation, weight: 1.0, where: "Eqs. 1-3", check: "checks.py:ok"}
"""


def write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "checks.py").write_text("def ok(target):\n    return True\n")
    path = tmp_path / "suite.yaml"
    path.write_text(text)
    return path


def test_the_repository_suites_load():
    tiny = load_suite(SUITES / "tiny.yaml")
    assert [p.id for p in tiny.papers] == ["gridlite", "glintfield"] and tiny.papers[0].budget.iterations == 6
    dev = load_suite(SUITES / "dev.yaml")  # the papers live in ../shared (not checked here: a row failure)
    assert {p.id for p in dev.papers} == {"nerf", "bionerf", "gh_nerf", "seathru_nerf", "nerfplayer", "hexplane",
                                          "dynerf", "deformable_3dgs", "scaffold_gs", "4dgs"}
    assert all(p.novelty for p in dev.papers) and all(
        i.check for p in dev.papers for i in p.novelty if i.kind == "equation" and p.id in
        ("nerf", "bionerf", "gh_nerf", "seathru_nerf"))


def test_a_good_suite_is_typed(tmp_path):
    suite = load_suite(write(tmp_path, GOOD))
    (paper,) = suite.papers
    assert paper.input == tmp_path / "paper.md" and paper.reference.method == "nerfacto"
    assert paper.novelty[0].equations == ("1", "2", "3") and paper.novelty[0].check == (tmp_path / "checks.py", "ok")
    assert paper.budget.iterations == 4 and paper.seeds == (0,)


@pytest.mark.parametrize("old,new,message", [
    ("kind: equation", "kind: eqn", "papers[0].novelty[0].kind: 'eqn' is not one of equation, loss"),
    ("weight: 1.0", "weight: 2", "papers[0].novelty[0].weight: expected a number in [0.0, 1.0], got 2"),
    ("    scenes: [default]\n", "", "papers[0]: missing required key 'scenes'"),
    ("reference: nerfacto", "reference: {method: a, plan: b.yaml}", "give exactly one of 'method'"),
    ("reference: nerfacto", "reference: nerfacto\n    refrence: x", "papers[0]: unknown key 'refrence'"),
    ("checks.py:ok", "../checks.py:ok", "is outside the suite folder"),
    ("checks.py:ok", "nope.py:ok", "check file 'nope.py' not found"),
    ("checks.py:ok", "checks.py", "expected FILE.py:FUNCTION"),
    ("id: p1", "id: P 1", "papers[0].id: 'P 1' is not an id"),
    ("iterations: 4", "iterations: 0", "budget.iterations must be at least 1, got 0"),
    ("budget: {iterations: 4, every: 2}", "budget: {iterations: 4, every: 2}\nseeds: []",
     "seeds: expected a non-empty"),
    ("papers:", "papers: 3\nx:", "unknown key 'x'"),
])
def test_malformed_suites_are_one_line(tmp_path, old, new, message):
    assert old in GOOD
    with pytest.raises(SuiteError) as info:
        load_suite(write(tmp_path, GOOD.replace(old, new)))
    text = str(info.value)
    assert message in text and "\n" not in text and text.startswith("suite.yaml: ")


def test_not_yaml_or_missing(tmp_path):
    with pytest.raises(SuiteError, match="not valid YAML"):
        load_suite(write(tmp_path, "papers: [\n"))
    with pytest.raises(SuiteError, match="not found"):
        load_suite(tmp_path / "none.yaml")


def test_equation_numbers():
    assert equation_numbers("Sec. 3, Eqs. 1-3, 7") == ("1", "2", "3", "7")
    assert equation_numbers("Eq. (4) and Eq. 10") == ("4", "10")
    assert equation_numbers("Appendix, Eq. A.2") == ("A.2",)
    assert equation_numbers("Sec. 3.2") == ()


def test_the_command_refuses_a_bad_suite_in_one_line(tmp_path, capsys):
    from nerfify_ns.cli import _run

    path = write(tmp_path, GOOD.replace("kind: equation", "kind: eqn"))
    assert _run(["bench", str(path), "--out", str(tmp_path / "out")]) == 2
    out = capsys.readouterr().out.strip()
    assert out.startswith("error:") and "'eqn' is not one of" in out and len(out.splitlines()) == 1
    assert _run(["bench", str(write(tmp_path, GOOD)), "--ablations", "no-ladder", "--out", str(tmp_path / "out")]) == 2
    assert "unknown ablation 'no-ladder'" in capsys.readouterr().out and not (tmp_path / "out").exists()
