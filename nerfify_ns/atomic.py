"""Write a folder atomically: build it in a temporary sibling, rename it into place on success.

A leaf module (used by the leaf ``scenes`` package and by the pipeline): a failure leaves no
partial folder behind, and replacing an existing folder (``overwrite``) restores the old one if
the final rename fails. The output path is checked before anything is written: a symbolic link, a
parent that is a file or a folder we may not write into is an :class:`OutputPathError` (one line, nothing
written, no parent folder created).

``overwrite`` replaces only our own output: a folder that carries our marker (:data:`MARKER`, written into the
staging folder last, so it appears with the finished folder in one rename) or, for folders written before the
marker existed, the files only we write (:func:`is_ours`); never ``/``, the home folder, the current folder, an
ancestor of any of them, nor a folder that holds an input of the run. Anything else is an :class:`OverwriteRefused`
(one line, nothing touched). Each staging folder carries :data:`STAGING_MARKER` (our process id and its start
time); a run removes the stale staging folders of its own output that a killed run left behind (ours by name and
marker, their process gone), and puts back an old output that a killed swap had moved aside. Staging folders are
registered while they exist, so an interrupt (:mod:`nerfify_ns.interrupts`) removes them even when it lands between
two statements; the final swap of an old folder for the new one is never cut in the middle by SIGINT or SIGTERM.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import shutil
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from nerfify_ns import interrupts, runfolder
from nerfify_ns.errors import NerfifyError


class OutputExistsError(NerfifyError):
    """The output folder exists and holds something; we never write into it half-way."""


class OutputPathError(NerfifyError):
    """The output path cannot be written: a symbolic link, under a file, or in a folder we may not write to."""


class OverwriteRefused(OutputPathError):
    """``--overwrite`` names something that is not our output, or that holds what must not be removed."""


LOG = logging.getLogger("nerfify")
MARKER = ".nerfify-output.json"
"""Our output marker: written into a staging folder last, so it appears with the finished folder."""
STAGING_MARKER = ".nerfify-staging.json"
"""The marker of a staging folder: the process that owns it (pid and start time)."""
TOOL = "nerfify-ns"
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<kind>partial|killed|old)-(?P<pid>\d+)-[0-9a-f]{8}$")
"""Staging (``.NAME.partial-PID-HEX``), killed (``.killed-``) and swapped-out (``.old-``) folders of ours."""


_staging: set[Path] = set()
"""Staging folders that exist now (removed on an interrupt's clean-up)."""
_interrupted: list[Path] = []
"""Staging folders removed because of an interrupt (for the interrupt's line)."""


def _normal(out: Path) -> Path:
    """``out`` absolute, with ``.`` and ``..`` resolved by name (``--out ..`` is the parent folder by its name)."""
    return Path(os.path.abspath(os.fspath(out)))


def check_target(out: Path, overwrite: bool, exists_error: Callable[[str], Exception] = OutputExistsError,
                 inputs: Iterable[Path | None] = ()) -> None:
    """Refuse an output path we cannot write (:class:`OutputPathError`), an existing non-empty ``out`` (or a
    file there) unless ``overwrite``, and with ``overwrite`` anything but our own output that nothing protects
    (:func:`check_replaceable`; ``inputs``: the run's input files and folders, which it must not remove)."""
    out = _normal(out)
    if out.parent == out:
        raise OverwriteRefused(f"cannot write to {out}: the root folder is never an output folder; choose another")
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
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        if not overwrite:
            raise exists_error(f"{out} exists and is not empty; pass --overwrite (overwrite=True) or choose another")
        check_replaceable(out, inputs)


def _protected(out: Path, inputs: Iterable[Path | None]) -> str | None:
    """Why ``out`` must not be replaced whoever wrote it (None when nothing protects it)."""
    real = out.resolve()
    places = [("the root folder", Path("/"))]
    try:
        places.append(("your home folder", Path.home().resolve()))
    except (RuntimeError, KeyError, OSError):
        pass
    try:
        places.append(("the current folder", Path.cwd().resolve()))
    except OSError:
        pass
    for name, place in places:
        if real == place:
            return f"it is {name}"
        if real in place.parents:
            return f"it holds {name} ({place})"
    for item in inputs:
        if item is None:
            continue
        target = _normal(Path(item)).resolve()
        if real == target or real in target.parents:
            return f"it holds this run's input {item}"
    return None


def _marker(folder: Path, name: str) -> dict | None:
    """The JSON object of our marker ``name`` in ``folder`` (a regular file, not a link), else None."""
    from nerfify_ns import safeio

    path = folder / name
    if path.is_symlink() or not path.is_file():
        return None
    try:
        data = safeio.load_json(path, 64 << 10)
    except safeio.ReadRefused:
        return None
    return data if isinstance(data, dict) and data.get("tool") == TOOL else None


def _legacy(folder: Path) -> bool:
    """A folder written before the marker existed, recognised by files only nerfify-ns writes together: a run
    folder (``run.json`` with its ``stages`` list, and ``plan.yaml`` or ``nerfify.log``), a generated plugin
    (``nerfify.json`` naming its ``files``), a procedural scene (``scene.json`` beside ``transforms_train.json``)."""
    from nerfify_ns import safeio

    def obj(name: str) -> dict | None:
        path = folder / name
        if path.is_symlink() or not path.is_file():
            return None
        try:
            data = safeio.load_json(path, 4 << 20)
        except safeio.ReadRefused:
            return None
        return data if isinstance(data, dict) else None

    run = obj(runfolder.OUTCOME)
    if run is not None and isinstance(run.get("stages"), list) and (
            (folder / runfolder.PLAN).is_file() or (folder / runfolder.LOG).is_file()):
        return True
    plugin = obj(runfolder.PLUGIN_META)
    if plugin is not None and isinstance(plugin.get("files"), list):
        return True
    return obj("scene.json") is not None and (folder / "transforms_train.json").is_file()


def is_ours(folder: Path) -> bool:
    """Whether ``folder`` is an output folder nerfify-ns wrote: it carries :data:`MARKER`, or it is a folder
    written before the marker existed (:func:`_legacy`)."""
    folder = Path(folder)
    if folder.is_symlink() or not folder.is_dir():
        return False
    return _marker(folder, MARKER) is not None or _legacy(folder)


def check_replaceable(out: Path, inputs: Iterable[Path | None] = ()) -> None:
    """Refuse (:class:`OverwriteRefused`) to replace ``out`` unless it is our output folder and nothing protects
    it (``/``, the home or current folder or one that holds them, a folder holding an input)."""
    out = _normal(out)
    why = _protected(out, inputs)
    if why is not None:
        raise OverwriteRefused(f"--overwrite would replace {out}, and {why}; nothing was touched. Choose another "
                               "output folder")
    if not out.is_dir():
        raise OverwriteRefused(f"--overwrite would replace {out}, a file, not an output folder of nerfify-ns; "
                               "nothing was touched. Choose another output folder")
    if not is_ours(out):
        raise OverwriteRefused(f"--overwrite replaces only an output folder of nerfify-ns, and {out} has no "
                               f"{MARKER} (nor a run's files); nothing was touched. Remove it yourself or choose "
                               "another output folder")


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


def _make_parents(out: Path) -> list[Path]:
    """Create the missing parents of ``out``; the folders created, deepest first."""
    missing = [p for p in out.parents if not p.exists()]
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _remove_empty(missing)
        raise OutputPathError(f"cannot create {out.parent}: {exc.strerror or exc}") from None
    return missing


def _remove_empty(folders: list[Path]) -> None:
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


def _process_start(pid: int) -> str | None:
    """The start time of process ``pid`` (clock ticks since boot, from /proc), None when it is gone."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read().decode("ascii", "replace")
        return stat.rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return None


def _alive(pid: int, start: str | None = None) -> bool:
    """Whether process ``pid`` runs (and, given ``start``, is the one that started then: not a reused pid)."""
    from nerfify_ns.runtime.process import pid_alive

    if not pid_alive(pid):
        return False
    if start is None:
        return True
    now = _process_start(pid)
    return now is None or now == start


def _write_marker(folder: Path, name: str, data: dict) -> None:
    with open(folder / name, "x", encoding="utf-8") as f:
        json.dump({"tool": TOOL, **data}, f)


def clean_leftovers(out: Path) -> list[str]:
    """Remove what killed runs left beside ``out``: staging folders (``.NAME.partial-PID-HEX``, ``.killed-``)
    whose marker names a process that is gone, and a swapped-out old output (``.old-``) whose process is gone
    (removed when ``out`` is there, else put back as ``out``). Only folders of ours by name and marker are
    touched. What was done, in words."""
    out = _normal(out)
    done: list[str] = []
    try:
        entries = list(out.parent.iterdir()) if out.parent.is_dir() else []
    except OSError:
        return done
    for entry in entries:
        match = _LEFTOVER.match(entry.name)
        if match is None or match["name"] != out.name or entry.is_symlink() or not entry.is_dir():
            continue
        pid = int(match["pid"])
        if match["kind"] == "old":
            if _alive(pid) or not is_ours(entry):
                continue
            if out.exists() or out.is_symlink():
                _remove_tree(entry)
                done.append(f"removed {entry.name} (an old output a killed run had moved aside)")
            else:
                entry.rename(out)
                done.append(f"put back {out.name} (a killed run had moved it aside)")
            continue
        marker = _marker(entry, STAGING_MARKER)
        if marker is None or marker.get("pid") != pid or _alive(pid, marker.get("start")):
            continue
        _remove_tree(entry)
        done.append(f"removed {entry.name} (a killed run's unfinished output)")
    for line in done:
        LOG.warning("%s: %s", out.parent, line)
    return done


def _publish(staging: Path, out: Path) -> None:
    """Rename ``staging`` to ``out``, swapping out an old ``out`` and putting it back on failure."""
    if not out.exists():
        staging.rename(out)
        return
    trash = out.with_name(f".{out.name}.old-{os.getpid()}-{uuid.uuid4().hex[:8]}")
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


def remove_staging() -> str | None:
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
    out: Path, overwrite: bool = False, exists_error: Callable[[str], Exception] = OutputExistsError,
    inputs: Iterable[Path | None] = (),
) -> Iterator[Path]:
    """Yield a temporary sibling folder that becomes ``out`` only if the block succeeds (carrying
    :data:`MARKER`). ``overwrite`` replaces only our own output (:func:`check_replaceable`); ``inputs``: the
    run's inputs, which it must not remove."""
    out = _normal(out)
    inputs = list(inputs)
    check_target(out, overwrite, exists_error, inputs)
    created = _make_parents(out)
    clean_leftovers(out)
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
        _write_marker(staging, STAGING_MARKER, {"pid": os.getpid(), "start": _process_start(os.getpid())})
        yield staging
        check_target(out, overwrite, exists_error, inputs)  # something may have appeared meanwhile
        (staging / STAGING_MARKER).unlink(missing_ok=True)
        (staging / MARKER).unlink(missing_ok=True)  # copied from a cached folder of ours: written anew
        _write_marker(staging, MARKER, {"marker": 1})  # the same bytes every time: outputs stay reproducible
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
