"""Write a folder atomically: build it in a temporary sibling, rename it into place on success.

A leaf module (used by the leaf ``scenes`` package and by the pipeline): a failure leaves no
partial folder behind, and replacing an existing folder (``overwrite``) restores the old one if
the final rename fails.
"""

from __future__ import annotations

import os
import shutil
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from nerfify_ns.errors import NerfifyError


class OutputExistsError(NerfifyError):
    """The output folder exists and holds something; we never write into it half-way."""


def check_target(out: Path, overwrite: bool, exists_error: Callable[[str], Exception] = OutputExistsError) -> None:
    """Refuse an existing non-empty ``out`` (or a file there) unless ``overwrite``."""
    if out.exists() and not overwrite and (not out.is_dir() or any(out.iterdir())):
        raise exists_error(f"{out} exists and is not empty; pass --overwrite (overwrite=True) or choose another")


def _publish(staging: Path, out: Path) -> None:
    """Rename ``staging`` to ``out``, swapping out an old ``out`` and putting it back on failure."""
    if not out.exists():
        staging.rename(out)
        return
    trash = out.with_name(f".{out.name}.old-{uuid.uuid4().hex[:8]}")
    out.rename(trash)
    try:
        staging.rename(out)
    except BaseException:
        trash.rename(out)
        raise
    if trash.is_dir():
        shutil.rmtree(trash)
    else:
        trash.unlink()


@contextmanager
def atomic_dir(
    out: Path, overwrite: bool = False, exists_error: Callable[[str], Exception] = OutputExistsError
) -> Iterator[Path]:
    """Yield a temporary sibling folder that becomes ``out`` only if the block succeeds."""
    out = Path(out).absolute()
    check_target(out, overwrite, exists_error)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = out.with_name(f".{out.name}.partial-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    staging.mkdir()
    try:
        yield staging
        check_target(out, overwrite, exists_error)  # something may have appeared meanwhile
        _publish(staging, out)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
