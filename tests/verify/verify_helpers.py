"""Shared helpers of the verification-ladder tests: reference plugins composed after pruning for the
tiny scene, and the broken-plugin corpus applied as mutations of them."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

BROKEN = Path(__file__).parent / "broken_plugins"


def compose_reference(name: str, scene: Path, out: Path) -> Path:
    from nerfify_ns.synthesis.compose import compose
    from nerfify_ns.synthesis.prune import prune_plan
    from nerfify_ns.synthesis.resources import load_reference_plan
    from nerfify_ns.synthesis.scene_probe import probe_scene

    plan = prune_plan(load_reference_plan(name), probe_scene(scene))
    return compose(plan, out, overwrite=True, record=False).out


def corpus(hostile: bool = False) -> list:
    """The corpus entries: the broken ones, or (``hostile``) those trying to escape the sandbox, which their
    own test runs with canaries (tests/verify/test_verify_hostile.py)."""
    return sorted(p.stem for p in BROKEN.glob("*.yaml") if bool(load_case(p.stem).get("hostile")) == hostile)


def load_case(name: str) -> dict:
    return yaml.safe_load((BROKEN / f"{name}.yaml").read_text())


def broken_plugin(name: str, reference: Path, dest: Path, outside: Path, **canaries: object) -> Path:
    """A copy of ``reference`` with the mutations of corpus entry ``name`` applied (each must match);
    ``{OUTSIDE}`` and ``{NAME}`` for each of ``canaries`` (``PORT=...``) are replaced in the new text."""
    case = load_case(name)
    shutil.copytree(reference, dest)
    package = next(p for p in dest.iterdir() if (p / "config.py").is_file())
    for m in case["mutations"]:
        path = package / m["file"]
        text = path.read_text()
        assert m["old"] in text, f"corpus {name}: {m['old']!r} not in {m['file']} (a template changed?)"
        new = m["new"].replace("{OUTSIDE}", str(outside))
        for key, value in canaries.items():
            new = new.replace("{" + key + "}", str(value))
        path.write_text(text.replace(m["old"], new))
    return dest
