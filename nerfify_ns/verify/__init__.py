"""Stage 3c: the verification ladder for generated (or hand-written) Nerfstudio plugins.

    from nerfify_ns.verify import run_ladder
    report = run_ladder("nerfify-out/kplanes-static")   # static -> contract -> stability -> smoke (+ repair)
    report.ok, report.failures, report.to_dict()

Plugin code only ever runs in sandboxed subprocesses (``sandbox.py``).
"""

from nerfify_ns.verify.errors import NotAPluginError, VerifyError
from nerfify_ns.verify.ladder import revert_patches, run_ladder
from nerfify_ns.verify.repair import Fixer, Patch, default_fixers
from nerfify_ns.verify.report import RUNGS, Diagnosis, LadderReport, RungResult
from nerfify_ns.verify.suite import component_suite

__all__ = [
    "Diagnosis",
    "Fixer",
    "LadderReport",
    "NotAPluginError",
    "Patch",
    "RUNGS",
    "RungResult",
    "VerifyError",
    "component_suite",
    "default_fixers",
    "revert_patches",
    "run_ladder",
]
