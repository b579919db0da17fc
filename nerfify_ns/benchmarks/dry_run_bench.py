"""``ns-nerfify PAPER --dry-run`` latency: the whole paper -> plan stage as a user runs it (a new process,
imports included), median over several runs, against the 10 s target for a 15-page PDF.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.dry_run_bench [PDF] [--runs 5] [--pages 15]``
Without a PDF it makes a 15-page two-column one (``ingest_bench.make_two_column_pdf``); the real
papers in ../shared/papers are good inputs too. It also times ingestion alone in this process, so
the share of the process start-up and imports is visible.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from nerfify_ns.benchmarks.ingest_bench import make_two_column_pdf, time_ingest
from nerfify_ns.interrupts import run_interruptible

TARGET_SECONDS = 10.0


def time_dry_run(paper: Path) -> float:
    cli = Path(sys.executable).with_name("ns-nerfify")
    start = time.perf_counter()
    out = subprocess.run([str(cli), str(paper), "--dry-run"], capture_output=True, text=True, timeout=300)
    elapsed = time.perf_counter() - start
    if out.returncode != 0:
        raise SystemExit(f"dry run failed: {out.stdout[-500:]}{out.stderr[-500:]}")
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paper", nargs="?", type=Path)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--pages", type=int, default=15)
    ns = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        paper = ns.paper or make_two_column_pdf(Path(tmp) / "bench.pdf", ns.pages)
        _, ingest_times = time_ingest(paper, ns.runs)
        times = [time_dry_run(paper) for _ in range(ns.runs)]
    median = statistics.median(times)
    name = paper.name if ns.paper else f"{ns.pages}-page two-column PDF"
    print(f"{name}: ns-nerfify --dry-run median {median:.2f} s "
          f"over {ns.runs} runs (min {min(times):.2f}, max {max(times):.2f}); ingestion alone median "
          f"{statistics.median(ingest_times):.2f} s; target {TARGET_SECONDS:.0f} s -> "
          f"{'met' if median < TARGET_SECONDS else 'MISSED'} ({median / TARGET_SECONDS:.2f} of the budget)")


if __name__ == "__main__":
    run_interruptible(main)
