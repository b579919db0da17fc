"""Every grammar terminal, one definition each, grouped by what they are.

A module of this package that defines ``TERMINALS`` is part of the registry: the frame and the families below in
this order, then any other module (a technique added as one file, ``<technique>.py``) in name order."""

import importlib
import pkgutil

from nerfify_ns.registry.terminals import custom, encodings, heads, losses, method, sampling, training, wrappers

_GROUPS = (method, encodings, heads, sampling, losses, wrappers, training)
_OTHERS = tuple(importlib.import_module(f"{__name__}.{m.name}") for m in sorted(pkgutil.iter_modules(__path__),
                                                                             key=lambda m: m.name)
                if m.name not in {g.__name__.rsplit(".", 1)[1] for g in (*_GROUPS, custom)})
MODULES = (*_GROUPS, *(m for m in _OTHERS if hasattr(m, "TERMINALS")), custom)
"""The modules whose ``TERMINALS`` make up the registry, in the order the grammar export lists them."""
