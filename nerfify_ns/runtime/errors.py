"""Typed exceptions of the CPU/offline runtime layer."""


class RuntimeLayerError(RuntimeError):
    """Base class for errors raised by :mod:`nerfify_ns.runtime`."""


class LPIPSWeightsError(RuntimeLayerError):
    """AlexNet weights for LPIPS were given but are unusable (wrong file, wrong shapes, bad hash)."""
