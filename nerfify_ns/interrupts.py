"""SIGINT and SIGTERM end a command cleanly: children stopped, staging folders removed, one line, 130 or 143.

A leaf module (standard library only). A command installs the handlers first (:func:`install`); from then on
either signal, the first time it arrives:

1. runs the registered interrupt hooks (:func:`on_interrupt`): :mod:`nerfify_ns.runtime.process` registers
   one that sends SIGKILL to every child process group we started (training, its data workers, sandboxes),
   so nothing keeps running while the stack unwinds;
2. raises :class:`Interrupted` (a ``BaseException``, so no ``except Exception`` swallows it) in the main
   thread: ``atomic_dir`` removes its staging folder on the way out, ``run_process`` reaps its child;
3. the command's top level catches it (:func:`exit_interrupted`): it reaps what is left, removes any staging
   folder still registered (:mod:`nerfify_ns.atomic`), prints one line and exits with 128 + the signal
   (130 for SIGINT, 143 for SIGTERM).

A second signal during the clean-up changes nothing (it is ignored, so the clean-up finishes). A block that
must not be cut in the middle (starting a child and registering it; renaming a finished folder into place)
runs under :func:`held`: a signal arriving inside waits until the block ends.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals that interrupt a command."""


class Interrupted(BaseException):
    """The command received SIGINT or SIGTERM; raised in the main thread by the handler."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        self.name = signal.Signals(self.signum).name
        super().__init__(self.name)

    @property
    def exit_code(self) -> int:
        """128 + the signal: 130 for SIGINT, 143 for SIGTERM (the shell's convention)."""
        return 128 + self.signum


_hooks: list[Callable[[], object]] = []
_cleanups: list[tuple[int, Callable[[], str | None]]] = []


class _State:
    held = 0
    pending: int | None = None
    received: int | None = None


_state = _State()


def on_interrupt(hook: Callable[[], object]) -> None:
    """Run ``hook`` inside the signal handler, before :class:`Interrupted` is raised (it must be quick and
    must not wait for locks: send signals, set flags)."""
    if hook not in _hooks:
        _hooks.append(hook)


def on_cleanup(cleanup: Callable[[], str | None], order: int = 50) -> None:
    """Run ``cleanup`` at the top level after an interrupt (reap children, remove folders), lower ``order``
    first (children are stopped, 0, before their folders are removed, 10); it returns what it did in a few
    words for the interrupt's line, or None/'' when it had nothing to do."""
    if all(c is not cleanup for _, c in _cleanups):
        _cleanups.append((order, cleanup))
        _cleanups.sort(key=lambda item: item[0])


def received() -> int | None:
    """The signal received, if one was."""
    return _state.received


def _fire(signum: int) -> None:
    _state.received = signum
    for hook in list(_hooks):
        try:
            hook()
        except Exception:  # a failing hook must not stop the others, nor the interrupt
            pass
    raise Interrupted(signum)


def _handler(signum: int, frame) -> None:
    if _state.received is not None:
        return  # already unwinding: let the clean-up finish
    if _state.held:
        _state.pending = _state.pending or signum
        return
    _fire(signum)


@contextlib.contextmanager
def held() -> Iterator[None]:
    """Hold SIGINT/SIGTERM until the block ends (then the interrupt happens, if one came)."""
    if threading.current_thread() is not threading.main_thread():
        yield  # handlers run in the main thread only; nothing to hold here
        return
    _state.held += 1
    try:
        yield
    finally:
        _state.held -= 1
        if not _state.held and _state.pending is not None and _state.received is None:
            signum, _state.pending = _state.pending, None
            _fire(signum)


def install() -> None:
    """Install the handlers of :data:`SIGNALS` (main thread only; a no-op elsewhere)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in SIGNALS:
        signal.signal(signum, _handler)


def reset() -> None:
    """Forget a received signal and restore the default handlers (tests running several commands in one
    process)."""
    _state.held, _state.pending, _state.received = 0, None, None
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def clean_up() -> list[str]:
    """Run the registered clean-ups; what each did."""
    done = []
    for _, cleanup in list(_cleanups):
        try:
            what = cleanup()
        except Exception as exc:  # report it on the line, do not lose the exit code
            what = f"clean-up failed: {type(exc).__name__}: {exc}"
        if what:
            done.append(what)
    return done


def interrupted_line(exc: Interrupted, done: list[str]) -> str:
    """The one line an interrupted command prints."""
    return f"interrupted: {exc.name}" + (f"; {', '.join(done)}" if done else "")


def exit_interrupted(exc: Interrupted, print_line: Callable[[str], None] = None) -> int:
    """Clean up after ``exc``, print its one line (stderr by default) and return the exit code."""
    line = interrupted_line(exc, clean_up())
    if print_line is None:
        print(line, file=sys.stderr, flush=True)
    else:
        print_line(line)
    return exc.exit_code


def run_interruptible(main: Callable[[], object], print_line: Callable[[str], None] = None) -> object:
    """Run ``main()`` with the handlers installed; on SIGINT/SIGTERM clean up, print one line and exit
    130/143 (for ``python -m`` entry points such as the benchmarks)."""
    install()
    try:
        result = main()
    except Interrupted as exc:
        sys.exit(exit_interrupted(exc, print_line))
    except KeyboardInterrupt:  # arrived before the handlers were installed
        sys.exit(exit_interrupted(Interrupted(signal.SIGINT), print_line))
    if _state.received is not None:  # raised somewhere that swallowed it: still an interrupted run
        sys.exit(exit_interrupted(Interrupted(_state.received), print_line))
    return result
