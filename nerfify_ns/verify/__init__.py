"""Stage 5 (``verify``): the verification ladder for generated (or hand-written) Nerfstudio plugins.

    from nerfify_ns.verify import run_ladder
    report = run_ladder("nerfify-out/kplanes-static")   # static -> contract -> stability -> smoke (+ repair)
    report.ok, report.failures, report.to_dict()
    run_ladder(folder, repair="propose")   # repair a scratch copy only: report.proposal, report.diff

Plugin code only ever runs in sandboxed subprocesses (``sandbox.py``).
"""

from nerfify_ns.verify.errors import NotAPluginError, VerifyError
from nerfify_ns.verify.ladder import REPAIR_MODES, RepairMode, revert_patches, run_ladder
from nerfify_ns.verify.repair import CodePatch, Fixer, PlanEdit, default_fixers, record_in_plan
from nerfify_ns.verify.stability_suite import component_suite
from nerfify_ns.verify.verdicts import RUNGS, Diagnosis, LadderReport, RungResult

__all__ = [
    "CodePatch",
    "Diagnosis",
    "Fixer",
    "LadderReport",
    "NotAPluginError",
    "PlanEdit",
    "REPAIR_MODES",
    "RUNGS",
    "RepairMode",
    "RungResult",
    "VerifyError",
    "component_suite",
    "default_fixers",
    "record_in_plan",
    "revert_patches",
    "run_ladder",
]
