"""NerfifyBench: the pipeline measured over many papers against reference implementations, with ablations.

    ns-nerfify bench SUITE.yaml [--ablations no-citations,one-shot] [--ray | --ray-address ADDR] [--out DIR]

A suite (``docs/bench.md``; :mod:`.suite` reads it) lists papers, each with its input, scenes, reference
(a Nerfstudio built-in, an installed plugin's method name, or a plan), reported metrics, budget and novelty items
(with optional numeric checks: small reference functions in the suite folder, run in the sandbox on the generated
component). Every (paper, scene, configuration, seed) is a task (:mod:`.tasks`): the configuration ``full`` or an
ablation runs the pipeline itself (``run_paper`` with its ablation switches) and trains and evaluates the generated
plugin; ``reference`` trains the reference in a process whose method discovery sees only its own entry points
(:mod:`nerfify_ns.runtime.isolated`). Tasks run on an executor (:mod:`.executor`: local processes one at a time, or
Ray tasks with declared CPU/GPU needs), each writing ``tasks/<key>/result.json`` when it finishes, so a killed
bench rerun skips what is done. :mod:`.novelty` scores coverage (C/I/M/W and a weighted score) from the checks and
the plan's evidence links, never from a model; :mod:`.tables` writes ``results.json``, markdown and LaTeX tables in
the layout of the paper's Tables 2-5, and the error-against-time plots.

Imports flow one way: this package uses the pipeline, the evaluation and the runtime; nothing upstream imports it
(the CLI imports it lazily).
"""

from nerfify_ns.nerfifybench.suite import NoveltyItem, PaperEntry, Reference, Suite, SuiteError, load_suite

__all__ = ["NoveltyItem", "PaperEntry", "Reference", "Suite", "SuiteError", "load_suite"]
