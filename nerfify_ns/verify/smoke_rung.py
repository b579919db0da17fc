"""The smoke-train rung: Nerfstudio's own trainer on a tiny scene, sandboxed; the verdict comes from
the exit code and the run's tensorboard events (iterations reached, finite losses, falling
photometric loss), never from text the plugin prints."""

from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

from nerfify_ns.budget import Limit, pace_margin
from nerfify_ns.dataset import DataLike, as_dataset
from nerfify_ns.runtime.events import ITER_TIME_TAG, LOSS_TAG, Scalars, read_scalars
from nerfify_ns.runtime.launch import (
    ENV_GENERATED,
    GENERATED_METHOD,
    ProgressHook,
    RunLayout,
    progress_poll,
    train_command,
)
from nerfify_ns.runtime.pace import ENV_PACE, WINDOW, Pace
from nerfify_ns.runtime.presets import for_method, plugin_args
from nerfify_ns.runtime.sandbox import Limits, python_cmd, run_sandboxed
from nerfify_ns.verify.checker import PipeReader, decode
from nerfify_ns.verify.plugin import PluginInfo
from nerfify_ns.verify.rungs import limit_diagnoses, sandbox_details
from nerfify_ns.verify.smoke_check import judge_training
from nerfify_ns.verify.verdicts import Diagnosis, RungResult

SMOKE_ARGS = [
    "--pipeline.datamanager.train-num-rays-per-batch",
    "128",
    "--pipeline.datamanager.eval-num-rays-per-batch",
    "128",
    "--pipeline.model.eval-num-rays-per-chunk",
    "256",
    "--steps-per-eval-batch",
    "100000",
    "--steps-per-eval-image",
    "100000",
    "--steps-per-eval-all-images",
    "1000000",
    "--steps-per-save",
    "100000",
    "--machine.device-type",
    "cpu",
    "--mixed-precision",
    "False",
    "--logging.max-buffer-size",
    "1",
]
SMOKE_TAIL_STEPS = 16.0
"""What the recorder does after training (render the probe, time a step at two ray batches), in training steps: a
smoke rung with a time limit keeps that in hand when it stops itself (:func:`smoke_pace`)."""
SMOKE_TAIL_SECONDS = 5.0
"""And what of that tail does not scale with a step (loading the probe's rays, the timing's warm-up passes): fixed
seconds kept in hand besides :data:`SMOKE_TAIL_STEPS`."""
SMOKE_FEWEST = 0.25
"""A smoke rung its time limit cut shorter than this share of its iterations is not judged on them: "not verified:
time"."""
PACE_SLACK_SECONDS = 5.0
"""The process's exit and the sandbox's teardown, beyond the pace's own figures, when the rung checks from outside
that a short run stopped itself at its deadline."""


def smoke_pace(limit: Limit) -> Pace | None:
    """The smoke rung's deadline (None without a time limit): the training stops itself when one more step, the
    recorder's tail (:data:`SMOKE_TAIL_STEPS` steps at the pace measured and :data:`SMOKE_TAIL_SECONDS`) and the
    margin would pass the limit, so a slow method's rung trains as many of its iterations as its share of the
    budget allows, then renders its probe and times its rays, instead of being killed with nothing judged."""
    if limit.seconds is None:
        return None
    return Pace(end=time.time() + limit.seconds, step_seconds=1.0, render_seconds=SMOKE_TAIL_STEPS,
                startup_seconds=SMOKE_TAIL_SECONDS, margin_seconds=pace_margin(limit.seconds))


def recent_step(scalars: Scalars) -> float | None:
    """The median of the last steps' seconds (the pace a run's deadline was judged at: :data:`WINDOW` steps)."""
    times = scalars.get(ITER_TIME_TAG, {})
    steps = [times[s] for s in sorted(times)][2:][-WINDOW:]
    return statistics.median(steps) if steps else None


def stopped_at_deadline(result, limit: Limit, pace: Pace | None, step: float | None) -> bool:
    """Whether a run that trained fewer iterations than asked stopped itself at its deadline, judged from outside:
    it exited cleanly, within its tail, margin and a slack of its limit (measured by our clock) at the pace its
    events show. A run that stops early of its own accord is not excused by it."""
    if pace is None or limit.seconds is None or result.timed_out or result.returncode != 0 or not step:
        return False
    return result.seconds >= (limit.seconds - pace.margin_seconds - pace.startup_seconds
                              - (SMOKE_TAIL_STEPS + 2) * step - PACE_SLACK_SECONDS)


class SmokeCancelled(Exception):
    """The smoke rung was called off while it ran (the ladder's checks running beside it failed)."""


def cancellable(poll, cancel):
    """``poll`` (or nothing) that first raises :class:`SmokeCancelled` once ``cancel`` (an Event) is set: the
    process runner then kills the training's process group."""
    if cancel is None:
        return poll

    def check() -> None:
        if cancel.is_set():
            raise SmokeCancelled("the smoke rung was called off")
        if poll is not None:
            poll()

    return check


LEARNING_RATIO = 0.9
"""The photometric loss over the last quarter must be below this fraction of the first quarter's."""


def warmup_args(plan: dict | None) -> list[str]:
    """ns-train arguments switching off learning-rate warm-up (a 20-step run would never leave it)."""
    args: list[str] = []
    for group, spec in ((plan or {}).get("optimizers") or {}).items():
        scheduler = (spec or {}).get("scheduler") or {}
        flag = f"--optimizers.{group.replace('_', '-')}.scheduler."
        if "cosine_decay" in scheduler:
            args += [flag + "warm-up-end", "0"]
        elif "exponential_decay" in scheduler and (scheduler["exponential_decay"] or {}).get("warmup_steps"):
            args += [flag + "warmup-steps", "0"]
    return args


def hook_schedule_args(plan: dict | None, iterations: int) -> list[str]:
    """ns-train arguments that run the plan's schedule hooks (a warm-up that freezes a part, an annealed scalar)
    over the rung's ``iterations`` instead of the paper's ``trainer.max_num_iterations``: every stage of the
    schedule is reached, so a part a hook holds back is trained inside the rung too."""
    from nerfify_ns.components.schedule_hooks import STEP_SCALE_FIELD

    model = (plan or {}).get("model") or {}
    paper = int(((plan or {}).get("trainer") or {}).get("max_num_iterations") or 0)
    if not model.get("schedule_hooks") or paper <= iterations or iterations <= 0:
        return []
    return [f"--pipeline.model.{STEP_SCALE_FIELD.replace('_', '-')}", f"{iterations / paper:.6g}"]


def photometric(scalars: Scalars) -> dict[int, float]:
    """Sum of the ``rgb`` losses per step (Train Loss Dict/rgb_loss, rgb_loss_coarse/fine), else the total."""
    tags = [t for t in scalars if t.startswith("Train Loss Dict/") and "rgb" in t]
    if not tags:
        return scalars.get(LOSS_TAG, {})
    steps = set.intersection(*(set(scalars[t]) for t in tags))
    return {s: sum(scalars[t][s] for t in tags) for s in sorted(steps)}


class LastStepClock:
    """An ``on_progress`` hook that also notes, on our clock, when the run's events last showed a new step: what
    the process did after it (the recorder's probe and ray timing) is no start-up a later process pays."""

    def __init__(self, then: ProgressHook | None = None) -> None:
        self.then, self.step, self.at = then, -1, None

    def __call__(self, step: int, total: int) -> None:
        if step > self.step:
            self.step, self.at = step, time.perf_counter()
        if self.then is not None:
            self.then(step, total)

    def tail(self, launched: float, wall_seconds: float) -> float:
        """Seconds the process ran after its last step was seen (0 when none was)."""
        return 0.0 if self.at is None else max(0.0, launched + wall_seconds - self.at)


def step_timing(scalars: Scalars, wall_seconds: float, tail_seconds: float = 0.0) -> dict[str, float | None]:
    """What the run measured of its own speed: the median seconds of a training iteration after the first two
    (the first compiles and warms caches), and the seconds the process spent on anything else before its last
    step (sandbox and Nerfstudio start-up, loading the data, the first iteration); ``tail_seconds``: what it ran
    after its last step (:class:`LastStepClock`), kept apart. A budgeted run plans its training from these
    (``nerfify_ns.budget.fit_iterations``). Raw per-step times: the rung logs with a buffer of one step."""
    times = scalars.get(ITER_TIME_TAG, {})
    steps = [times[s] for s in sorted(times)]
    if len(steps) < 3:
        return {"seconds_per_iteration": None, "startup_seconds": None, "tail_seconds": round(tail_seconds, 1)}
    return {"seconds_per_iteration": statistics.median(steps[2:]),
            "startup_seconds": max(0.0, wall_seconds - tail_seconds - sum(steps[1:])),
            "tail_seconds": round(tail_seconds, 1)}


def _head(path: Path, limit: int = 4 << 20) -> str:
    """The start of a file the sandboxed run wrote (bounded: it is read in our process)."""
    with open(path, "rb") as f:
        return f.read(limit).decode("utf-8", errors="replace")


def recorded(cmd: list[str], fd: int) -> list[str]:
    """``ns-train ...`` run through :mod:`nerfify_ns.verify.recorder`, which sends every step to ``fd``."""
    return python_cmd("nerfify_ns.verify.recorder", str(fd), *cmd[1:])


def checked_verdict(r: RungResult, records: list, run_dir: Path, iterations: int, result) -> None:
    """The checker's part of the verdict (:mod:`nerfify_ns.verify.smoke_check`, from the recorded steps and the
    checkpoint, never from the run's own logs) and the escape attempts the sandbox recorded. The checks on the
    run's logs that follow can only add failures (a plugin forging its logs cannot pass that way)."""
    checks, failures, details = judge_training(records, run_dir, iterations)
    r.checks = checks
    r.details.update(details)
    failures = [("escape-attempt", t) for t in result.attempt_sentences()] + failures
    if not result.timed_out and result.returncode == 0 and not checks:
        failures.append(("nothing-checked", "nothing checked: the training delivered no step to judge"))
    for rule, message in failures:
        if rule != "iterations" or not result.timed_out:  # a timeout says so itself
            r.fail(Diagnosis("smoke", rule, message, traceback=result.tail(15)))


def smoke_rung(
    info: PluginInfo,
    scene: DataLike,
    workdir: Path,
    *,
    iterations: int = 20,
    timeout: float = 120,
    extra_args: list[str] | None = None,
    on_progress: ProgressHook | None = None,
    limits: Limits | None = None,
    limit: Limit | None = None,
    cancel=None,
    env: dict[str, str] | None = None,
) -> RungResult:
    """Train the plugin (as ``GENERATED_METHOD``) for ``iterations`` on ``scene`` (a dataset or its folder; the
    dataset's Nerfstudio dataparser) in the sandbox and judge the run. ``limit``: the time limit and where it comes
    from (named in the message when it is reached; default ``timeout`` seconds). ``cancel``: an Event that calls
    the run off (its process group killed, :class:`SmokeCancelled` raised), for a rung run beside the checks;
    ``env``: variables for the run (the thread count of a rung run beside the checks)."""
    limit = limit or Limit(timeout, "the smoke rung")
    timeout = limit.timeout
    r = RungResult("smoke")
    workdir = Path(workdir).resolve()
    start = time.perf_counter()
    scene = as_dataset(scene)
    layout = RunLayout(workdir, GENERATED_METHOD, log_name="train.log")
    cmd = train_command(GENERATED_METHOD, scene, layout, iterations=iterations,
                        method_args=for_method((info.plan or {}).get("base", ""),
                                               [*SMOKE_ARGS, *plugin_args((info.plan or {}).get("base", "")),
                                                *warmup_args(info.plan),
                                                *hook_schedule_args(info.plan, iterations), *(extra_args or [])]))
    pace = smoke_pace(limit)
    env = {**(env or {}), ENV_GENERATED: str(info.root), "NERFIFY_LPIPS_WEIGHTS": "none",
           **({ENV_PACE: pace.to_env()} if pace is not None else {})}
    r.details["threads"] = int(env["OMP_NUM_THREADS"]) if str(env.get("OMP_NUM_THREADS", "")).isdigit() else None
    reader = PipeReader()  # the trainer's steps, recorded for the checker (nerfify_ns.verify.recorder)
    last_step = LastStepClock(on_progress)
    launched = time.perf_counter()
    try:
        result = run_sandboxed(recorded(cmd, reader.write_fd), workdir, timeout=timeout, log_name=layout.log_name,
                               env=env, poll=cancellable(progress_poll(layout.run_dir, iterations, last_step),
                                                         cancel),
                               readonly=[info.root, scene.root], limits=limits, pass_fds=(reader.write_fd,))
    finally:
        records = decode(reader.finish())[0]
    r.seconds = time.perf_counter() - start
    r.details.update(
        {
            "isolation": result.isolation,
            "sandbox": sandbox_details(result),
            "returncode": result.returncode,
            "wall_s": round(result.seconds, 1),
            "log": str(result.log_path),
        }
    )
    run_dir = layout.run_dir
    scalars = read_scalars(run_dir)
    total = scalars.get(LOSS_TAG, {})
    rgb = photometric(scalars)
    reached = max(total) + 1 if total else 0
    r.details.update({"iterations": reached, "iterations_wanted": iterations, "final_loss": total.get(reached - 1),
                      "limit_seconds": limit.seconds, "limit_source": limit.source,
                      **step_timing(scalars, result.seconds, last_step.tail(launched, result.seconds))})
    if limit.seconds is None:
        r.details["sandbox"]["limits"] = {**r.details["sandbox"]["limits"], "timeout_s": None}  # none, not inf
    short = 0 < reached < iterations and stopped_at_deadline(result, limit, pace, recent_step(scalars))
    if short:
        r.details["paced"] = (f"trained {reached} of {iterations} iterations: {limit.describe()} left no time for "
                              f"more at {r.details['seconds_per_iteration']:.2f} s a step")
    judged = reached if short else iterations
    checked_verdict(r, records, layout.run_dir, judged, result)
    _check_steps(r, result, limit, reached, iterations, total, rgb, info, layout, judged)
    if short and (reached < SMOKE_FEWEST * iterations
                  or (r.failures and all(d.rule == "no-learning" for d in r.failures))):
        # too few steps to show learning: not judged, for want of time (the same verdict as a run its limit killed)
        r.failures, r.status = [], "fail"
        r.fail(Diagnosis("smoke", "timeout", f"stopped itself at {reached} of {iterations} iterations after "
                                             f"{result.seconds:.0f} s, too few to judge: {limit.describe()}",
                         traceback=result.tail(15)))
    return r


def _check_steps(r: RungResult, result, limit: Limit, reached: int, iterations: int, total: dict, rgb: dict,
                 info: PluginInfo, layout: RunLayout, judged: int) -> None:
    """The run's process and events judged (after the checker's part): limits, timeout, finite losses, the exit
    code, the method trained, the steps reached (``judged`` of them needed), and learning where the checker had no
    probe."""
    hits = limit_diagnoses("smoke", result, left_running=False)  # ns-train's data workers may still be exiting
    if hits:
        for d in hits:
            d.traceback = result.tail(15)
            r.fail(d)
        return
    if result.timed_out:
        r.fail(
            Diagnosis(
                "smoke",
                "timeout",
                f"stopped at {reached} of {iterations} iterations after {result.seconds:.0f} s: "
                f"{limit.describe()}",
                traceback=result.tail(15),
            )
        )
        return
    bad = sorted(s for s, v in total.items() if not math.isfinite(v))
    if bad:
        r.fail(
            Diagnosis(
                "smoke",
                "non-finite-loss",
                f"the training loss is not finite from step {bad[0]} "
                f"(read from the run's tensorboard events)",
                traceback=result.tail(15),
            )
        )
        return
    if result.returncode != 0:
        r.fail(
            Diagnosis(
                "smoke", "exit-code", f"ns-train exited with {result.returncode}", traceback=result.tail(20)
            )
        )
        return
    config = layout.config
    if config.is_file() and info.package not in _head(config):
        r.fail(
            Diagnosis(
                "smoke",
                "wrong-method",
                f"ns-train did not train {info.package} (the plugin failed to "
                "load and the fallback method ran)",
                traceback=result.tail(15),
            )
        )
        return
    step = r.details.get("checkpoint_step")  # the trainer's last step, read from its checkpoint by the checker
    if reached < judged and not (isinstance(step, int) and step + 1 >= judged):
        # tensorboard's writer may drop the last step's scalars at exit; the checkpoint of that step is the evidence
        r.fail(Diagnosis("smoke", "iterations", f"reached {reached} of {judged} iterations"))
        return
    values = [rgb[s] for s in sorted(rgb)]
    q = max(len(values) // 4, 1)
    first, last = statistics.mean(values[:q]), statistics.mean(values[-q:])
    r.details.update({"photometric_first": first, "photometric_last": last})
    paired = str(r.details.get("judged_on", "")).startswith("the same")
    # the run's own loss, in quarters of steps on different rays, decides only where the checker had no probe to
    # judge the same rays on (the probe's verdict is the stronger one, and it is not the run's own word)
    if not paired and not last < LEARNING_RATIO * first:
        r.fail(
            Diagnosis(
                "smoke",
                "no-learning",
                f"the photometric loss does not decrease: first quarter "
                f"{first:.4g}, last quarter {last:.4g} (needs < {LEARNING_RATIO} x)",
            )
        )
