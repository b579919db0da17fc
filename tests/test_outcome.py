"""The run's outcome: stages that ran, failed or were not run (--until, an earlier failure), and why."""

import json

import pytest

from nerfify_ns.errors import NerfifyError
from nerfify_ns.outcome import FAILED, NOT_RUN, RAN, STAGES, Outcome, Progress, UntilError


class Recorder(Progress):
    """Every progress call, in order."""

    def __init__(self):
        self.calls = []

    def start(self, stage, label, total=None):
        self.calls.append(("start", stage, total))

    def advance(self, done, total=None):
        self.calls.append(("advance", done, total))

    def finish(self, stage, summary, seconds):
        self.calls.append(("finish", stage, summary))

    def fail(self, stage, reason, seconds):
        self.calls.append(("fail", stage, reason))

    def abandon(self, stage):
        self.calls.append(("abandon", stage))


def test_until_stops_after_the_stage_and_says_so(tmp_path):
    progress = Recorder()
    outcome = Outcome("compose", until="plugin", progress=progress)
    for name in STAGES["compose"]:
        if outcome.wants(name):
            with outcome.stage(name, f"doing {name}", total=3) as stage:
                stage.advance(2, 3)
                stage.summary = f"{name} done"
    assert [(r.name, r.status) for r in outcome.records] == [
        ("plan", RAN), ("plugin", RAN), ("verify", NOT_RUN), ("train", NOT_RUN), ("patches", NOT_RUN)]
    assert outcome.record("verify").reason == "stopped after plugin (--until plugin)"
    assert outcome.ok and outcome.headline() == "ran plan, plugin; stopped after plugin (--until plugin)"
    assert progress.calls[:3] == [("start", "plan", 3), ("advance", 2, 3), ("finish", "plan", "plan done")]
    data = json.loads(outcome.write(tmp_path / "run.json").read_text())
    assert data["until"] == "plugin" and data["ok"] is True and data["failed"] is None
    assert [s["status"] for s in data["stages"]] == [RAN, RAN, NOT_RUN, NOT_RUN, NOT_RUN]


def test_a_failed_stage_stops_the_later_ones_and_is_named():
    progress = Recorder()
    outcome = Outcome("compose", progress=progress)
    with outcome.stage("plan", "plan"):
        pass
    with outcome.stage("plugin", "plugin"):
        pass
    with outcome.stage("verify", "ladder") as stage:
        stage.fail("smoke rung, no-learning (-): the photometric loss does not decrease")
    assert not outcome.wants("train")
    assert outcome.record("train").reason == "verify failed"
    assert outcome.failed.name == "verify" and not outcome.ok
    assert outcome.headline().startswith("verify failed: smoke rung, no-learning")
    assert ("fail", "verify", "smoke rung, no-learning (-): the photometric loss does not decrease") in progress.calls
    assert not any(call[0] == "finish" and call[1] == "verify" for call in progress.calls)


def test_expected_errors_fail_the_stage_others_propagate():
    outcome = Outcome("paper", progress=Recorder())
    with outcome.stage("train", "training", failures=(NerfifyError,)):
        raise NerfifyError("ns-eval failed")
    assert outcome.record("train").status == FAILED and outcome.record("train").reason == "ns-eval failed"
    progress = Recorder()
    other = Outcome("paper", progress=progress)
    with pytest.raises(ValueError):
        with other.stage("read", "reading", failures=(NerfifyError,)):
            raise ValueError("a bug")
    assert other.record("read").status == FAILED
    assert progress.calls[-1] == ("abandon", "read")  # the caller reports it (one error line), not the bar


def test_until_must_name_a_stage_of_the_command():
    with pytest.raises(UntilError, match="compose has the stages plan, plugin"):
        Outcome("compose", until="read")
