"""Every grammar terminal, one definition each, grouped by what they are."""

from nerfify_ns.registry.terminals import custom, encodings, heads, losses, method, sampling, training, wrappers

MODULES = (method, encodings, heads, sampling, losses, wrappers, training, custom)
"""The modules whose ``TERMINALS`` make up the registry, in the order the grammar export lists them."""
