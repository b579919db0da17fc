"""A paper's novel parts compiled from its equations into components of the plugin.

    from nerfify_ns.synthesis.novel import implement_holes
    result = implement_holes(doc, derived.plan, corrections=read_corrections(path))
    result.plan       # holes filled through the `custom` alternative where their equations compiled
    result.sources    # {"components.<name>": source} for write_plugin / run_compose
    result.records    # per hole: equations as read, bindings, sizes, status, reason (equations.yaml)

Modules: ``notation.yaml`` / ``notation.py`` (what symbols stand for: the shared table, the cards, the paper's own
sentences), ``widths.py`` (sizes from the equations), ``adapters.py`` (a production's interface around the
compiled module), ``implement.py`` (orchestration and placement) with ``items.py`` (the equations as read),
``binding.py`` (selection, bindings, sizes), ``component.py`` (compile, check, wiring), ``results.py`` (the
records), ``causes.py`` (why a part was not built), ``records.py`` (equations.yaml: the record a person corrects,
and the cache of what compiled).
"""

from nerfify_ns.synthesis.novel.implement import (
                                                  IMPLEMENTED,
                                                  NOT_IMPLEMENTED,
                                                  PARTLY,
                                                  HoleResult,
                                                  Implementation,
                                                  implement_holes,
)

__all__ = ["IMPLEMENTED", "NOT_IMPLEMENTED", "PARTLY", "HoleResult", "Implementation", "implement_holes"]
