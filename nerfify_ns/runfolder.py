"""The run folder's layout: every file name a run writes into its output folder, in one place.

A leaf module (no imports). ``ns-nerfify PAPER`` writes ``nerfify-out/METHOD/``; every module that writes or reads
a file of that folder names it from here (``folder / runfolder.PLAN``), and a test fails when one of these names is
written as a literal anywhere else in the package::

    METHOD/                      the generated plugin package itself (pyproject.toml, METHOD/*.py, README.md)
      plan.yaml                  PLAN: the plan, fitted to the scene (rewritten when the schedule is scaled)
      nerfify.json               PLUGIN_META: the plugin's package, method and files
      paper.md                   PAPER: the cleaned paper
      evidence.json              EVIDENCE: key terms, detections, the plan's derivation
      citations.json, .png       CITATIONS, CITATIONS_FIGURE: the citation graph
      equations.yaml             EQUATIONS: the novel parts as compiled, for a person to correct
      equations/                 EQUATIONS_DIR: one generated component per novel part
      agents.json                AGENTS: the model agents' calls, when --llm ran them
      verify.json                VERIFY: the verification ladder's rungs and repairs
      eval/                      EVAL_DIR: training and checkpoint evaluation
        summary.json             SUMMARY: metrics, iterations, budget (also the demo's top-level summary)
        curve.csv, curve.png     CURVE, CURVE_FIGURE: error against time
        checkpoint_eval.json     CHECKPOINT_EVAL: each checkpoint's metrics
        error_maps.json          ERROR_MAPS: the held-out views' error panels
        consistency.json         CONSISTENCY: multi-view consistency masks
      history.json               PATCH_HISTORY: the patch loop's rounds (--patch-rounds)
      start_plan.yaml            START_PLAN, BEST_PLAN: the patch loop's first and best plans
      best_plan.yaml
      rounds/rNN/                ROUNDS_DIR: one folder per patch round (its plan.yaml, patch.json, eval/)
        patch.json               PATCH
      scene/                     SCENE_DIR: the procedural scene rendered for the run
      run.json                   OUTCOME: which stages ran, failed or were not run, and why
      nerfify.log                LOG: warnings and other packages' output
      report.html, report.json   REPORT_HTML, REPORT_JSON
"""

PLAN = "plan.yaml"
PLUGIN_META = "nerfify.json"
PAPER = "paper.md"
EVIDENCE = "evidence.json"
CITATIONS = "citations.json"
CITATIONS_FIGURE = "citations.png"
EQUATIONS = "equations.yaml"
EQUATIONS_DIR = "equations"
AGENTS = "agents.json"
VERIFY = "verify.json"
EVAL_DIR = "eval"
SUMMARY = "summary.json"
CURVE = "curve.csv"
CURVE_FIGURE = "curve.png"
CHECKPOINT_EVAL = "checkpoint_eval.json"
ERROR_MAPS = "error_maps.json"
CONSISTENCY = "consistency.json"
PATCH_HISTORY = "history.json"
START_PLAN = "start_plan.yaml"
BEST_PLAN = "best_plan.yaml"
ROUNDS_DIR = "rounds"
PATCH = "patch.json"
SCENE_DIR = "scene"
OUTCOME = "run.json"
LOG = "nerfify.log"
REPORT_HTML = "report.html"
REPORT_JSON = "report.json"

FILES: tuple[str, ...] = (PLAN, PLUGIN_META, PAPER, EVIDENCE, CITATIONS, CITATIONS_FIGURE, EQUATIONS, AGENTS, VERIFY,
                          SUMMARY, CURVE, CURVE_FIGURE, CHECKPOINT_EVAL, ERROR_MAPS, CONSISTENCY, PATCH_HISTORY,
                          START_PLAN, BEST_PLAN, PATCH, OUTCOME, LOG, REPORT_HTML, REPORT_JSON)
"""The file names no other module writes as a literal (folder names such as ``eval`` or ``scene`` are also stage
and key names, so only their constants are here)."""
