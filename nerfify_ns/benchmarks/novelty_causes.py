"""Why the novel parts a paper survey found were not built: a histogram of causes over a suite or a folder of papers.

The causes (``synthesis.novel.causes``): a symbol it cannot bind (binding), a size nothing states (width), an
operator or a reduction the lowering does not support, an equation it cannot read, a part with no equation (prose
only), a production without an adapter, the module disagreeing with the interpreter, and the contract / stability /
smoke rung of the ladder (with ``--verify``: the ladder runs, and a part it reverts counts under its rung). Each
part's cause is the one its record keeps (the plan's hole: ``cause``), else read from its reason. Every cause is
printed, zeros included, then one line per part not built.

Run: ``.venv/bin/python -m nerfify_ns.benchmarks.novelty_causes examples/bench/dev.yaml [--out DIR] [--verify]``
(the same runs as ``ns-nerfify survey``: one process per paper, the read stage with the equation compiler).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from nerfify_ns.errors import NerfifyError
from nerfify_ns.interrupts import run_interruptible
from nerfify_ns.nerfifybench.survey import survey, totals, write
from nerfify_ns.synthesis.novel.causes import cause_of, histogram


def not_built(rows: list) -> list[tuple[str, dict]]:
    """(paper id, hole) for every part not built, over the papers the grammar can build."""
    out = []
    for r in rows:
        if r.exit_code == 1 and "failed plan" in r.error:  # a family the grammar cannot build: nothing was tried
            continue
        out += [(r.id, h) for h in r.holes if h.get("status") not in ("implemented", "partly implemented")]
    return out


def report(rows: list) -> str:
    t = totals(rows)
    found = t["found"] if t["items"] else sum(len(r.holes) for r in rows)
    parts = not_built(rows)
    counts = histogram([(str(h.get("cause") or ""), str(h.get("reason") or "")) for _, h in parts])
    lines = [f"{len(rows)} paper(s); novel parts found {found}, built {t['implemented']}; "
             f"parts not built {len(parts)}; papers that raised {t['tracebacks']}"]
    lines += [f"  {n:3d}  {name}" for name, n in counts.items()]
    for pid, h in parts:
        cause = h.get("cause") or cause_of(str(h.get("reason") or ""))
        reason = " ".join(str(h.get("reason") or "").split())
        lines.append(f"  - {pid} {h.get('production', '?')}: {cause}: {reason[:160]}")
    for r in rows:
        if r.error and r.error.startswith("a traceback"):
            lines.append(f"  ! {r.id}: {r.error[:160]}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("target", type=Path, help="a suite file or a folder of papers")
    parser.add_argument("--out", type=Path, default=Path("survey-results"), help="where survey.json/.md are written")
    parser.add_argument("--verify", action="store_true", help="run the ladder too (minutes per paper)")
    args = parser.parse_args()
    try:
        rows = survey(args.target, verify=args.verify)
    except NerfifyError as e:  # a suite or folder we cannot read: one line, nothing written
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    write(rows, args.out)
    print(report(rows))


if __name__ == "__main__":
    run_interruptible(main)
