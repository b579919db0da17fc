"""The ladder's sandbox: :mod:`nerfify_ns.runtime.sandbox` (bubblewrap as an unprivileged user in fresh
namespaces, a cgroup per run limiting the whole process tree; the weaker ``unshare`` fallback), re-exported
here for the rungs that run plugin code."""

from __future__ import annotations

from nerfify_ns.runtime.sandbox import (DEFAULT_MEMORY, MODES, Limits, SandboxError, SandboxResult,
                                        available_modes, best_mode, python_cmd, run_sandboxed, sandbox_env)

__all__ = ["DEFAULT_MEMORY", "MODES", "Limits", "SandboxError", "SandboxResult", "available_modes", "best_mode",
           "isolation_available", "python_cmd", "run_sandboxed", "sandbox_env"]


def isolation_available() -> bool:
    """True when a process can get its own namespaces here (``bwrap``, or the ``unshare`` fallback)."""
    return best_mode() != "none"
