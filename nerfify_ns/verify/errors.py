"""Typed errors of the verification ladder."""

from __future__ import annotations

from nerfify_ns.errors import NerfifyError


class VerifyError(NerfifyError):
    """The ladder itself cannot run (not a plugin folder, unknown rung, a probe that left no result)."""


class NotAPluginError(VerifyError):
    """The folder holds no recognisable Nerfstudio plugin (no pyproject.toml entry point, no nerfify.json)."""
