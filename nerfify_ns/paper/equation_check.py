"""``python -m nerfify_ns.paper.equation_check PAPER OUT_DIR``: read a paper and draw each equation read next to
the PDF region it came from (``equations/eqcheck.py``), with ``equations.html`` to compare them at a glance."""

from __future__ import annotations

import sys
from pathlib import Path

from nerfify_ns.equations.eqcheck import render_checks_html, write_equation_checks
from nerfify_ns.paper import ingest
from nerfify_ns.paper.errors import PaperError


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 2:
        print("usage: python -m nerfify_ns.paper.equation_check PAPER OUT_DIR", file=sys.stderr)
        return 2
    try:
        doc = ingest(argv[0])
    except (PaperError, OSError) as err:  # a paper we cannot read: one line, nothing written
        print(f"equation_check: {argv[0]}: {' '.join(str(err).split())[:300]}", file=sys.stderr)
        return 2
    out = Path(argv[1])
    checks = write_equation_checks(doc, out)
    page = ("<!doctype html><meta charset='utf-8'><title>equations</title>"
            "<style>body{font-family:sans-serif}</style>" + render_checks_html(checks))
    (out / "equations.html").write_text(page, encoding="utf-8")
    for c in checks:
        flag = "" if not c.render_error else f"  [{c.render_error[:80]}]"
        conf = "-" if c.confidence is None else f"{c.confidence:.2f}"
        print(f"({c.number or '-'}) p.{c.page or '-'} {c.method:10s} {conf}  {c.latex[:90]}{flag}")
    print(f"{len(checks)} equations -> {out / 'equations.html'}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
