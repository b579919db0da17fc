"""The checks and the smoke rung run at once: half the cores' threads each, never more than the user allowed."""

import os

from nerfify_ns.verify.ladder import shared_cores


def test_two_processes_at_once_get_half_the_cores_each(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    cores = len(os.sched_getaffinity(0))
    env = shared_cores()
    assert env["OMP_NUM_THREADS"] == env["MKL_NUM_THREADS"] == str(max(1, cores // 2))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert shared_cores()["OMP_NUM_THREADS"] == "1"
    monkeypatch.setenv("OMP_NUM_THREADS", "not a number")
    assert shared_cores()["OMP_NUM_THREADS"] == str(max(1, cores // 2))
