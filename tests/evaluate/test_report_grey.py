"""The report's headline says when the renders are grey: a run that trained but renders nothing a person
recognises is not reported in green."""

import json

from nerfify_ns import runfolder
from nerfify_ns.evaluate.report import GREY_RENDER_RATIO, read_outcome


def _run(tmp_path, ratio):
    (tmp_path / runfolder.OUTCOME).write_text(json.dumps({"ok": True, "headline": "ran read, train", "stages": []}))
    (tmp_path / runfolder.EVAL_DIR).mkdir()
    summary = {"status": "ok", "diagnostics": {"colour_spread_ratio": ratio}}
    (tmp_path / runfolder.EVAL_DIR / runfolder.SUMMARY).write_text(json.dumps(summary))
    return read_outcome(tmp_path, {})


def test_grey_renders_make_the_headline_partial_and_say_so(tmp_path):
    outcome = _run(tmp_path, GREY_RENDER_RATIO / 3)
    assert outcome["partial"] and outcome["headline"].startswith("Renders grey: foreground colour spread 0.17x")


def test_coloured_renders_leave_the_headline_as_it_was(tmp_path):
    outcome = _run(tmp_path, 0.79)
    assert not outcome["partial"] and outcome["headline"] == "ran read, train"


def test_the_console_line_of_the_train_stage_says_grey_first():
    """The train stage's summary (the console's line) opens with the same verdict as the report's headline."""
    from types import SimpleNamespace

    from nerfify_ns.pipeline import _judge_evaluation

    def line(ratio):
        stage = SimpleNamespace(summary="", fail=None)
        summary = {"status": "ok", "iterations_done": 20, "seconds": 12.0, "psnr": 10.2, "ssim": 0.5, "lpips": None,
                   "diagnostics": {"colour_spread_ratio": ratio, "colour_spread": 0.02, "colour_spread_gt": 0.12}}
        _judge_evaluation(summary, stage)
        return stage.summary

    assert line(0.17).startswith("renders grey (foreground colour spread 0.17x the ground truth's); 20 iterations")
    assert line(0.79).startswith("20 iterations in 12.0 s")


def test_parts_whose_smoke_rung_ran_out_of_time_are_built_not_verified(tmp_path):
    """The ladder's smoke rung stopped by its time limit ("not verified: time"): the headline says the parts were
    built and passed the rungs before it, not that they were verified, in the partial colour."""
    (tmp_path / runfolder.OUTCOME).write_text(json.dumps({"ok": True, "headline": "ran read, train", "stages": []}))
    sections = {"equations": {"holes": 2, "implemented": 2}}

    def ladder(verdict):
        rungs = [{"name": "static", "status": "pass", "details": {}},
                 {"name": "smoke", "status": "fail", "details": {"verdict": verdict} if verdict else {}}]
        (tmp_path / runfolder.VERIFY).write_text(json.dumps({"ok": verdict is None, "rungs": rungs}))
        return read_outcome(tmp_path, sections)

    unverified = ladder("not verified: time")
    assert unverified["partial"]
    assert unverified["headline"].startswith("Novel parts: 2 of 2 found built; the smoke rung not verified: time")
    verified = ladder(None)
    assert not verified["partial"] and verified["headline"].startswith("Novel parts: 2 of 2 found built and verified")
    (tmp_path / runfolder.VERIFY).write_text('{"rungs": "not a list"}')  # damaged: no traceback, no claim of time
    assert read_outcome(tmp_path, sections)["headline"].startswith("Novel parts: 2 of 2 found built and verified")
