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
