"""Where the runtime keeps what our setup steps write (converted LPIPS weights, the built kernel)."""

from __future__ import annotations

import os
from pathlib import Path

ENV_CACHE = "NERFIFY_CACHE"


def nerfify_cache_dir() -> Path:
    """``$NERFIFY_CACHE``, default ``~/.cache/nerfify``; filled at setup time, never at run time."""
    return Path(os.environ.get(ENV_CACHE, Path.home() / ".cache" / "nerfify"))
