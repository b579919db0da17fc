"""The wall-clock budget: its option, how the time left becomes iterations, how it composes with --iterations."""

import pytest

from nerfify_ns.budget import (
    MIN_ITERATIONS,
    POST_SECONDS,
    RENDER_COST,
    Budget,
    BudgetError,
    fit_iterations,
    parse_duration,
)
from nerfify_ns.cli import paper_budget


@pytest.mark.parametrize("text, seconds", [("4m", 240), ("90s", 90), ("1.5min", 90), ("0.5h", 1800), ("2", 120),
                                           (" 30 S ", 30)])
def test_durations(text, seconds):
    assert parse_duration(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["", "four minutes", "-1m", "0", "1d", "nan"])
def test_bad_durations_are_one_clear_error(text):
    with pytest.raises(BudgetError, match="--budget"):
        parse_duration(text)


def test_budget_and_iterations_compose():
    default = paper_budget(None, None, None, None)
    assert default.seconds == 240 and default.scale_schedule and default.every is None
    only_iterations = paper_budget(None, 120, None, None)
    assert only_iterations.seconds is None and only_iterations.iterations == 120
    both = paper_budget("2m", 80, 40, None)
    assert both.seconds == 120 and both.iterations == 80 and both.every == 40
    with pytest.raises(BudgetError):
        paper_budget(None, 0, None, None)


def test_the_time_left_becomes_iterations_with_room_for_rendering():
    budget = Budget(iterations=10_000, every=None, seconds=240, checkpoints=3)
    fit = fit_iterations(200.0, 0.5, 15.0, rays_per_checkpoint=8 * 64 * 64, rays_per_iteration=512, budget=budget)
    render = 3 * 8 * 64 * 64 * (0.5 / 512) * RENDER_COST
    expected = int((200.0 - 2 * 15.0 - render - POST_SECONDS) // 0.5)
    assert fit.iterations == expected and fit.every == -(-expected // 3)
    assert fit.render_seconds == pytest.approx(render)
    assert fit.iterations * 0.5 + 2 * 15.0 + fit.render_seconds + POST_SECONDS <= 200.0  # it fits
    assert fit_iterations(200.0, 0.5, 15.0, 32768, 512, budget, most=50).iterations == 50  # --iterations caps it
    assert "fit the 200 s left" in fit.describe()


def test_a_fixed_cadence_pays_for_its_checkpoints():
    fixed = Budget(iterations=10_000, every=10, seconds=240)
    spread = Budget(iterations=10_000, every=None, seconds=240, checkpoints=2)
    a = fit_iterations(200.0, 0.5, 15.0, 32768, 512, fixed)
    b = fit_iterations(200.0, 0.5, 15.0, 32768, 512, spread)
    assert a.iterations < b.iterations and a.every == 10


def test_a_budget_too_short_says_what_it_needs():
    budget = Budget(iterations=10_000, every=None, seconds=60)
    with pytest.raises(BudgetError, match=f"{MIN_ITERATIONS} iterations .* need about .* longer --budget"):
        fit_iterations(20.0, 0.5, 15.0, 32768, 512, budget)


def test_the_time_it_says_it_needs_is_enough():
    """The stated need counts the checkpoints' rendering as the fit does: a view costly to render (a slow base)
    can need more than the time left even though ten training steps alone would fit, and one second more than
    the stated need fits the ten iterations."""
    budget = Budget(iterations=10_000, every=None, seconds=240, checkpoints=2)
    args = (2.48, 15.0, 64 * 64 * 8, 512)  # 2.48 s per 512-ray step, eight 64x64 test views per checkpoint
    with pytest.raises(BudgetError) as raised:
        fit_iterations(150.0, *args, budget)
    need = float(raised.value.args[0].split("need about ")[1].split(" s")[0])
    assert need > 150.0 > 2 * 15.0 + POST_SECONDS + MIN_ITERATIONS * 2.48
    assert fit_iterations(need + 1.0, *args, budget).iterations >= MIN_ITERATIONS


def test_within_budget_says_whether_training_fit_the_wall_clock_budget():
    from nerfify_ns.budget import within_budget

    record = {"seconds": 240.0, "iterations": 300}
    assert within_budget(record, {"status": "ok", "iterations_done": 300}) is True
    # stopped by the limit (the time the budget had left): trained fewer than planned, or failed
    assert within_budget(record, {"status": "failed", "iterations_done": 241}) is False
    assert within_budget(record, {"status": "failed", "iterations_done": 300}) is False  # rendering cut off
    # its limit stopped it after a checkpoint, which was evaluated: the budget did not hold
    assert within_budget(record, {"status": "ok", "iterations_done": 241,
                                  "stopped": "stopped at 241 of 600 iterations: the 215 s limit"}) is False
    # it kept the budget's deadline itself, on a machine slower than the estimate: fewer iterations, in time
    assert within_budget(record, {"status": "ok", "iterations_done": 180, "stopped": ""}) is True
    assert within_budget(None, {"status": "ok", "iterations_done": 300}) is None  # --iterations alone: no budget
    assert within_budget({"seconds": None, "iterations": 300}, {"status": "ok", "iterations_done": 300}) is None
