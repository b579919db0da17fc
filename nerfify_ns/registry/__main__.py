"""``python -m nerfify_ns.registry [PATH]``: write the grammar export (default: the checkout's grammar_spec.yaml)."""

from __future__ import annotations

import sys
from pathlib import Path

from nerfify_ns.registry.core import default_registry


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    target = Path(args[0]) if args else Path(__file__).resolve().parents[2] / "grammar_spec.yaml"
    target.write_text(default_registry().export_yaml())
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
