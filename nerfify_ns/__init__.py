"""nerfify-ns: turn a NeRF paper into a trainable, verified Nerfstudio method.

Stages (one sub-package each, imports flow one way):
paper -> knowledge -> grammar -> synthesis -> verify -> evaluate.
``runtime``, ``components`` and ``scenes`` are leaf packages used by everything, including
generated plugins; they import nothing upstream.
"""

__version__ = "0.1.0"
