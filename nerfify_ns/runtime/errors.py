"""Typed exceptions of the CPU/offline runtime layer."""

from nerfify_ns.errors import NerfifyError


class RuntimeLayerError(NerfifyError, RuntimeError):
    """Base class for errors raised by :mod:`nerfify_ns.runtime`."""


class LPIPSWeightsError(RuntimeLayerError):
    """AlexNet weights for LPIPS were given but are unusable (wrong file, wrong shapes, bad hash)."""
