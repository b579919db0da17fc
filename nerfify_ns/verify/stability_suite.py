"""The stability suite over every component of the knowledge base (every grammar terminal with a torch
implementation, plus our components that fill one), run in a sandboxed probe."""

from __future__ import annotations

from pathlib import Path

from nerfify_ns.verify.rungs import run_probe
from nerfify_ns.verify.verdicts import RungResult


def component_suite(out_dir: Path, *, timeout: float = 300) -> RungResult:
    """Every harnessed component on every case; fails only when a component of ours fails a case."""
    return run_probe(None, ["stability"], Path(out_dir) / "suite", timeout=timeout, suite="all")["stability"]
