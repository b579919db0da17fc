"""A novelty item's check, run in the sandbox on the generated component.

A check is a function in a file of the suite folder (``check: checks/bionerf.py:memory``) that takes one
:class:`Target` and returns ``None``/``True`` (the generated part agrees with the reference written from the paper)
or ``False`` / raises ``AssertionError`` (it does not); any other exception is a check error, reported as the row's
failure. The generated component is untrusted code, so the check runs in a subprocess through
:func:`nerfify_ns.runtime.sandbox.run_sandboxed` (no network, read-only file system but its own folder, memory,
process and time limits), with the suite folder and the run folder readable::

    python -m nerfify_ns.nerfifybench.checkrun SPEC.json     # writes result.json beside SPEC.json

:class:`Target` gives the check ``cls`` (the generated class, loaded from the plugin's component file; None when the
item is found in the plan only), ``params`` (the plan's constructor parameters of the component), ``record`` (the
hole's record from ``equations.yaml``), ``plan`` (the plan as a dict), ``path`` and ``value`` (the item's plan path
and the value there).
"""

from __future__ import annotations

import importlib.util
import json
import sys
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nerfify_ns import runfolder

RESULT = "result.json"


@dataclass
class Target:
    """What a check is given."""

    cls: type | None
    """The generated component's class (None when the item is a plan entry, not a compiled component)."""
    plan: dict
    """The run's plan (plan.yaml)."""
    path: str
    """The item's plan path."""
    value: Any
    """The plan's value at ``path``."""
    params: dict = field(default_factory=dict)
    """The component's parameters in the plan (``custom.params``)."""
    record: dict | None = None
    """The hole's record in equations.yaml (equations as read, bindings, sizes), when compiled."""


def _component_file(run_dir: Path, custom: dict) -> Path | None:
    meta = run_dir / runfolder.PLUGIN_META
    if not meta.is_file() or not custom.get("module"):
        return None
    package = json.loads(meta.read_text())["package"]
    path = run_dir / package / (custom["module"].replace(".", "/") + ".py")
    return path if path.is_file() else None


def _record(run_dir: Path, custom: dict | None) -> dict | None:
    import yaml

    path = run_dir / runfolder.EQUATIONS
    if custom is None or not path.is_file():
        return None
    holes = (yaml.safe_load(path.read_text()) or {}).get("holes") or []
    return next((h for h in holes if (h.get("component") or {}).get("module") == custom.get("module")), None)


def run_check(item, plan: dict, path: str, custom: dict | None, run_dir: Path, work: Path, *,
              timeout: float) -> dict:
    """Run ``item``'s check in the sandbox; ``{"status": "pass"|"fail"|"error", "message": ...}``."""
    from nerfify_ns.runtime.sandbox import python_cmd, run_sandboxed
    from nerfify_ns.safetext import clean

    work = Path(work).resolve()
    work.mkdir(parents=True, exist_ok=True)
    check_file, func = item.check
    spec = {"check": str(check_file), "function": func, "path": path, "plan": plan,
            "component": str(_component_file(run_dir, custom)) if custom else None,
            "class": (custom or {}).get("class"), "params": (custom or {}).get("params") or {},
            "record": _record(run_dir, custom)}
    (work / "spec.json").write_text(json.dumps(spec, default=str))
    (work / RESULT).unlink(missing_ok=True)
    result = run_sandboxed(python_cmd("nerfify_ns.nerfifybench.checkrun", str(work / "spec.json")), work,
                           timeout=timeout, log_name="check.log",
                           readonly=[Path(check_file).parent, Path(run_dir).resolve()])
    out = work / RESULT
    if out.is_file() and out.stat().st_size < 1 << 16:  # written inside the sandbox: read as untrusted
        try:
            data = json.loads(out.read_text())
        except ValueError:
            data = {}
        status = data.get("status") if isinstance(data, dict) else None
        if status in ("pass", "fail", "error"):
            return {"status": status, "message": clean(str(data.get("message", "")), 400, newlines=False)}
    why = "timed out" if result.timed_out else f"exit code {result.returncode}"
    return {"status": "error",
            "message": clean(f"the check process failed ({why}): {result.tail(5)}", 400, newlines=False)}


def _load(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def main(spec_path: str) -> int:
    spec_file = Path(spec_path)
    spec = json.loads(spec_file.read_text())
    out = spec_file.parent / RESULT

    def finish(status: str, message: str = "") -> int:
        out.write_text(json.dumps({"status": status, "message": message[:1000]}))
        return 0

    try:
        cls = None
        if spec.get("component"):
            cls = getattr(_load(Path(spec["component"]), "nerfify_bench_component"), spec["class"])
        _, value = _lookup(spec["plan"], spec["path"])
        target = Target(cls=cls, plan=spec["plan"], path=spec["path"], value=value, params=spec.get("params") or {},
                        record=spec.get("record"))
        sys.path.insert(0, str(Path(spec["check"]).parent))  # a check file's neighbours (its shared references)
        check = getattr(_load(Path(spec["check"]), "nerfify_bench_check"), spec["function"])
    except Exception as exc:  # noqa: BLE001 - a component or check that cannot be loaded is a check error
        return finish("error", f"loading: {type(exc).__name__}: {exc}")
    try:
        verdict = check(target)
    except AssertionError as exc:
        return finish("fail", f"AssertionError: {exc}")
    except Exception as exc:  # noqa: BLE001 - the check raised: an error, reported as the row's failure
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        return finish("error", f"{type(exc).__name__}: {exc} ({Path(frame.filename).name}:{frame.lineno})")
    if verdict is False:
        return finish("fail", "the check returned False")
    return finish("pass")


def _lookup(plan: Any, path: str):
    from nerfify_ns.nerfifybench.novelty import lookup

    return lookup(plan, path)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
