"""Why the novel parts a paper survey found were not built: a histogram of causes over a suite or a folder of papers
(no adapter for the production, prose only, a symbol it cannot bind, a size not stated, an equation it cannot read,
a reduction, the contract / stability / smoke rung), read from each part's recorded reason.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.novelty_causes examples/bench/dev.yaml [--out DIR]``
(the same runs as ``ns-nerfify survey``: one process per paper, the read stage with the equation compiler).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from nerfify_ns.interrupts import run_interruptible
from nerfify_ns.nerfifybench.survey import survey, totals, write


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("target", type=Path, help="a suite file or a folder of papers")
    parser.add_argument("--out", type=Path, default=Path("survey-results"))
    args = parser.parse_args()
    rows = survey(args.target)
    write(rows, args.out)
    t = totals(rows)
    found = t["found"] if t["items"] else sum(len(r.holes) for r in rows)
    print(f"{len(rows)} paper(s); novel parts found {found}, built {t['implemented']}")
    for name, n in t["not_built_causes"].items():
        print(f"  {n:3d}  {name}")


if __name__ == "__main__":
    run_interruptible(main)
