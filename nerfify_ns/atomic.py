"""Write a folder atomically: build it in a temporary sibling, rename it into place on success.

A leaf module (used by the leaf ``scenes`` package and by the pipeline): a failure leaves no
partial folder behind, and replacing an existing folder (``overwrite``) restores the old one if
the final rename fails. The output path is checked before anything is written: a symbolic link, a
parent that is a file or a folder we may not write into is an :class:`OutputPathError` (one line, nothing
written, no parent folder created). Staging folders are registered while they exist, so an interrupt
(:mod:`nerfify_ns.interrupts`) removes them even when it lands between two statements; the final swap of
an old folder for the new one is never cut in the middle by SIGINT or SIGTERM.
"""

from __future__ import annotations

import errno
import os
import shutil
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator, List, Optional, Set

from nerfify_ns import interrupts
from nerfify_ns.errors import NerfifyError


class OutputExistsError(NerfifyError):
    """The output folder exists and holds something; we never write into it half-way."""


class OutputPathError(NerfifyError):
    """The output path cannot be written: a symbolic link, under a file, or in a folder we may not write to."""


_staging: Set[Path] = set()
"""Staging folders that exist now (removed on an interrupt's clean-up)."""
_interrupted: List[Path] = []
"""Staging folders removed because of an interrupt (for the interrupt's line)."""


def check_target(out: Path, overwrite: bool, exists_error: Callable[[str], Exception] = OutputExistsError) -> None:
    """Refuse an output path we cannot write (:class:`OutputPathError`) and an existing non-empty ``out`` (or a
    file there) unless ``overwrite``."""
    out = Path(out).absolute()
    if out.is_symlink():
        raise OutputPathError(f"{out} is a symbolic link (to {os.readlink(out)}); give the folder it points to, "
                              "or another path")
    for parent in out.parents:
        if parent.exists() or parent.is_symlink():
            if not parent.is_dir():
                raise OutputPathError(f"cannot write {out}: {parent} is not a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                why = "a read-only file system" if _read_only_fs(parent) else "no permission to write there"
                raise OutputPathError(f"cannot write {out}: {parent} is not writable ({why})")
            break
    if out.exists() and not overwrite and (not out.is_dir() or any(out.iterdir())):
        raise exists_error(f"{out} exists and is not empty; pass --overwrite (overwrite=True) or choose another")


def _read_only_fs(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def check_writable_dir(folder: Path) -> Path:
    """Create ``folder`` (and its parents) for a command that writes into it, or raise :class:`OutputPathError`
    saying why it cannot be (nothing is created then)."""
    folder = Path(folder).absolute()
    if folder.is_dir() and not folder.is_symlink():
        if not os.access(folder, os.W_OK | os.X_OK):
            why = "a read-only file system" if _read_only_fs(folder) else "no permission to write there"
            raise OutputPathError(f"cannot write into {folder} ({why})")
        return folder
    if folder.exists() and not folder.is_dir():
        raise OutputPathError(f"cannot write into {folder}: it is a file")
    check_target(folder, overwrite=True)
    _make_parents(folder)
    try:
        folder.mkdir()
    except OSError as exc:
        raise OutputPathError(f"cannot create {folder}: {exc.strerror or exc}") from None
    return folder


def _make_parents(out: Path) -> List[Path]:
    """Create the missing parents of ``out``; the folders created, deepest first."""
    missing = [p for p in out.parents if not p.exists()]
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(missing)
        raise OutputPathError(f"cannot create {out.parent}: {exc.strerror or exc}") from None
    return missing


def _remove_empty(folders: List[Path]) -> None:
    for folder in folders:  # deepest first
        try:
            folder.rmdir()
        except OSError:
            pass


def _remove_tree(path: Path) -> None:
    """Remove ``path`` for good, even while the last writers (children being killed) still add files."""
    for _ in range(20):
        shutil.rmtree(path, ignore_errors=True)
        if not path.exists() and not path.is_symlink():
            return
        time.sleep(0.05)


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
    if trash.is_dir() and not trash.is_symlink():
        shutil.rmtree(trash)
    else:
        trash.unlink()


def remove_staging() -> Optional[str]:
    """Remove every staging folder still there (an interrupt's clean-up); what was removed, in words."""
    removed = len(_interrupted)
    for staging in list(_staging):
        if staging.exists():
            _remove_tree(staging)
            removed += 1
        _staging.discard(staging)
    _interrupted.clear()
    return f"removed {removed} unfinished output folder{'s' if removed != 1 else ''}" if removed else None


interrupts.on_cleanup(remove_staging, order=10)


@contextmanager
def atomic_dir(
    out: Path, overwrite: bool = False, exists_error: Callable[[str], Exception] = OutputExistsError
) -> Iterator[Path]:
    """Yield a temporary sibling folder that becomes ``out`` only if the block succeeds."""
    out = Path(out).absolute()
    check_target(out, overwrite, exists_error)
    created = _make_parents(out)
    staging = out.with_name(f".{out.name}.partial-{os.getpid()}-{uuid.uuid4().hex[:8]}")
    with interrupts.held():
        try:
            staging.mkdir()
        except OSError as exc:
            _remove_empty(created)
            reason = "a read-only file system" if exc.errno == errno.EROFS else exc.strerror or str(exc)
            raise OutputPathError(f"cannot write {out}: {reason}") from None
        _staging.add(staging)
    try:
        yield staging
        check_target(out, overwrite, exists_error)  # something may have appeared meanwhile
        with interrupts.held():  # never half-swapped: an interrupt waits for the renames
            _publish(staging, out)
            _staging.discard(staging)
    except BaseException as exc:
        with interrupts.held():
            _remove_tree(staging)
            _staging.discard(staging)
            _remove_empty(created)
            if isinstance(exc, interrupts.Interrupted):
                _interrupted.append(staging)
        raise
