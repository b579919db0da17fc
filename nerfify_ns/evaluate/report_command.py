"""``ns-nerfify report RUN_DIR``: (re-)render ``report.html`` and ``report.json`` of a run folder."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import tyro
from rich.console import Console

from nerfify_ns.evaluate.report import ReportError, write_report
from nerfify_ns.safetext import clean


@dataclass
class Report:
    """Write a self-contained report (report.html, images inlined, opens offline; and report.json) of a
    nerfify run folder: paper and plan, citation graph, components and holes, verification ladder,
    stability cases, metrics, error against time, error maps, consistency maps and the patch-loop
    history. Its top states the run's outcome (run.json: which stages ran, which failed and why); parts
    that are absent are reported as "not run"."""

    run_dir: tyro.conf.Positional[Path]
    """The run folder (the output of 'ns-nerfify PAPER', e.g. nerfify-out/<method>)."""
    quiet: bool = False
    """Print nothing but errors."""

    def main(self) -> None:
        from nerfify_ns.atomic import check_writable_dir

        if not Path(self.run_dir).is_dir():
            raise ReportError(f"{self.run_dir} is not a folder; pass the output folder of 'ns-nerfify PAPER'")
        check_writable_dir(self.run_dir)  # report.html and report.json are written into it
        html_path, json_path = write_report(self.run_dir)
        if not self.quiet:
            outcome = json.loads(json_path.read_text())["outcome"]
            console = Console(width=120)
            # the headline is the run folder's text: terminal escapes and control characters shown, not obeyed
            console.print(f"outcome: {clean(outcome['headline'], 1000, newlines=False)}", highlight=False,
                          markup=False, soft_wrap=True)
            console.print(f"report: {clean(html_path, newlines=False)}\n        {clean(json_path, newlines=False)}",
                          highlight=False, markup=False, soft_wrap=True)
