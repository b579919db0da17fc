"""Inputs a user (or a downloaded file) hands to the CLI, each refused in one ``error:`` line with exit 2, in
bounded time and memory, with nothing written: scripted model answers, bench suites and plans that are alias
bombs or 10^5 levels deep, a suite of 2 x 10^6 tasks in under 100 KB, an LLFF ``poses_bounds.npy`` whose header
claims 2^40 rows, an equations.yaml bomb, and a plan whose method name ends in a newline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hostile_cli import alias_bomb, assert_one_error, deep_yaml, run_cli, snapshot

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"


def _refused(tmp_path: Path, args: list, needle: str) -> None:
    before = snapshot(tmp_path)
    done = run_cli(*args, cwd=tmp_path, env={"NERFIFY_LLM_CACHE": str(tmp_path / "cache.sqlite")})
    assert_one_error(done, needle, seconds=60)
    assert snapshot(tmp_path) == before  # no output folder, no staging folder, no cache


@pytest.mark.parametrize("content, needle", [(alias_bomb(), "expands to more than"),
                                             (deep_yaml(), "nests deeper than")], ids=["alias-bomb", "deep"])
def test_scripted_answers_bombs(content, needle, tmp_path):
    (tmp_path / "answers.yaml").write_text(content)
    _refused(tmp_path, [str(EXAMPLE), "--dry-run", "--llm", f"scripted:{tmp_path / 'answers.yaml'}"],
             f"scripted answers {tmp_path / 'answers.yaml'}: cannot read it (the file {needle}")


SUITE_HEAD = "papers:\n  - id: p\n    input: paper.md\n    reference: {method: nerfacto}\n    novelty: []\n"


def _task_flood(path: Path) -> None:
    scenes = ", ".join(f"s{i}" for i in range(100))
    seeds = ", ".join(str(i) for i in range(10_000))
    path.write_text(SUITE_HEAD + f"    scenes: [{scenes}]\n    seeds: [{seeds}]\n")


@pytest.mark.parametrize("make, needle", [
    (lambda p: p.write_text(alias_bomb()), "suite suite.yaml expands to more than"),
    (lambda p: p.write_text(deep_yaml()), "suite suite.yaml nests deeper than"),
    (_task_flood, "papers[0]: the suite expands to more than 5000 runs"),
], ids=["alias-bomb", "deep", "2e6-tasks"])
def test_bench_suite_bombs(make, needle, tmp_path):
    make(tmp_path / "suite.yaml")
    assert make is not _task_flood or (tmp_path / "suite.yaml").stat().st_size < 100_000  # 2 x 10^6 tasks
    _refused(tmp_path, ["bench", "suite.yaml", "--out", "out"], needle)


def test_plan_bombs_and_a_method_name_ending_in_a_newline(tmp_path):
    (tmp_path / "bomb.yaml").write_text(alias_bomb())
    _refused(tmp_path, ["compose", "bomb.yaml", "--until", "plan", "--out", "out"], "expands to more than")
    plan = (ROOT / "method_configs" / "nerfacto.yaml").read_text()
    (tmp_path / "plan.yaml").write_text(plan.replace("method: nerfacto-ref", 'method: "nerfacto-ref\\n"', 1))
    assert '"nerfacto-ref\\n"' in (tmp_path / "plan.yaml").read_text()
    _refused(tmp_path, ["compose", "plan.yaml", "--until", "plan", "--out", "out"], "method must be a lower-case name")


def test_an_equations_file_bomb(tmp_path):
    (tmp_path / "equations.yaml").write_text(alias_bomb())
    _refused(tmp_path, [str(EXAMPLE), "--until", "plan", "--equations", "equations.yaml", "--out", "out"],
             "--equations equations.yaml expands to more than")


def test_an_llff_header_claiming_2_to_the_40_rows(tmp_path):
    data = tmp_path / "llff"
    (data / "images").mkdir(parents=True)
    np.save(data / "poses_bounds.npy", np.zeros((4, 17)))
    raw = (data / "poses_bounds.npy").read_bytes()
    size = int.from_bytes(raw[8:10], "little")
    header = raw[10:10 + size].decode("latin1").replace("(4, 17)", f"({2 ** 40}, 17)")
    header = header.rstrip("\n").rstrip(" ")[: size - 1].ljust(size - 1) + "\n"
    (data / "poses_bounds.npy").write_bytes(raw[:10] + header.encode("latin1") + raw[10 + size:])
    with pytest.raises(MemoryError):  # what the file does to a plain np.load
        np.load(data / "poses_bounds.npy")
    _refused(tmp_path, ["compose", "--method", "nerfacto", "--data", str(data), "--until", "plan", "--out", "out"],
             f"its header claims shape ({2 ** 40}, 17)")


def test_a_resumed_bench_reads_task_results_within_bounds(tmp_path):
    """A bench folder is re-read on resume: a task result that is 10^5 deep, a list, or a FIFO counts as not
    finished (the task runs again), never a traceback."""
    import json
    import os

    from hostile_cli import deep_json

    from nerfify_ns.nerfifybench.executor import finished, task_folder
    from nerfify_ns.nerfifybench.tasks import RESULT, Task

    task = Task("p", "default", "full", 0)
    folder = task_folder(tmp_path, task)
    folder.mkdir(parents=True)
    (folder / RESULT).write_text(json.dumps({"status": "ok", "fingerprint": "f"}))
    assert finished(tmp_path, task, "f") == {"status": "ok", "fingerprint": "f"}
    for bad in (deep_json(), "[1, 2]", "{not json"):
        (folder / RESULT).write_text(bad)
        assert finished(tmp_path, task, "f") is None
    (folder / RESULT).unlink()
    os.mkfifo(folder / RESULT)
    assert finished(tmp_path, task, "f") is None
