"""The hostile part of the broken-plugin corpus (``hostile: true`` in tests/verify/broken_plugins/): plugins that
try to forge their verdict (patch ``torch.isfinite``/``math.isnan``/``numpy.isfinite`` and write fake probe events
around a NaN colour head; turn NaN only from the 31st call; are right only where they detect the sandbox) or to
escape when imported, and then those that swallow
the failure of ``setns``, ``mount``, a connect to our loopback or a write to ``/dev`` (named by the seccomp
supervisor). Escapes run the static rung's sandboxed probe (no training): remount the root
read-write and write outside, write to /dev, join the parent's network namespace and connect to its loopback,
connect to a unix socket under /tmp, read /etc/shadow and a secret of the user, flood the console with markup
and terminal escapes, fork many processes, daemonize children that outlive the rung, and map more memory
than the tree may have.

Safe even when the sandbox fails: the canaries are the test's own (a file outside the plugin, a TCP listener
on our loopback, a unix socket, a secret file, a marker in child command lines; memory at 1 GiB a child, a
few processes). Each case asserts the verdict (the ladder fails at the expected rung and rule, naming what
was tried), the canaries (nothing written, nothing received, nothing read, no process left on the host,
the plugin folder unchanged), that nothing of the plugin's reaches verify.json or the console unescaped,
and the isolation recorded."""

from __future__ import annotations

import hashlib
import io
import os
import socket
import threading
import time
import uuid
from pathlib import Path

import pytest
from rich.console import Console
from verify_helpers import broken_plugin, corpus, load_case

from nerfify_ns.runtime.sandbox import Limits, available_modes
from nerfify_ns.verify import run_ladder
from nerfify_ns.verify.command import print_report

BASE = "kplanes-static"
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif("bwrap" not in available_modes(),
                                 reason="needs root and bubblewrap (scripts/setup.sh installs it): without them "
                                        "these escapes are not expected to be stopped")]


class Canaries:
    """What the plugin may try to reach: a TCP listener and a unix socket of ours (recording what arrives), a
    secret file, a file in /dev, a file outside the plugin and a marker for its processes' command lines."""

    def __init__(self, tmp: Path) -> None:
        tag = uuid.uuid4().hex[:8]
        self.outside = tmp / "escaped.txt"
        self.secret = tmp / "secret.txt"
        self.secret.write_text(f"canary-secret-{tag}\n")
        self.secret.chmod(0o600)
        self.dev = Path(f"/dev/nerfify-canary-{tag}")
        self.unix_path = f"/tmp/nerfify-hostile-{tag}.sock"
        self.marker = f"641.{uuid.uuid4().int % 10**6}"
        self.received: list = []
        self.tcp = socket.socket()
        self.tcp.bind(("127.0.0.1", 0))
        self.tcp.listen(8)
        self.unix = socket.socket(socket.AF_UNIX)
        self.unix.bind(self.unix_path)
        self.unix.listen(8)
        for s in (self.tcp, self.unix):
            s.settimeout(0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            for s in (self.tcp, self.unix):
                try:
                    conn, _ = s.accept()
                except OSError:
                    continue
                conn.settimeout(1)
                try:
                    self.received.append(conn.recv(100) or b"<connected>")
                except OSError:
                    self.received.append(b"<connected>")
                conn.close()

    @property
    def values(self) -> dict:
        return {"PORT": self.tcp.getsockname()[1], "UNIX": self.unix_path, "SECRET": self.secret,
                "DEVCANARY": self.dev, "MARKER": self.marker}

    def processes(self) -> list:
        """Host processes carrying the marker in their command line."""
        found = []
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                try:
                    cmd = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ")
                except OSError:
                    continue
                if self.marker.encode() in cmd:
                    found.append(cmd.decode(errors="replace"))
        return found

    def close(self) -> None:
        time.sleep(0.3)  # a connection in flight is still recorded
        self._stop.set()
        self._thread.join()
        self.tcp.close()
        self.unix.close()
        os.unlink(self.unix_path)
        self.dev.unlink(missing_ok=True)


def snapshot(folder: Path) -> dict:
    """Every file of ``folder`` and its hash (what must not change)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def shadow_first_line() -> str:
    try:
        return Path("/etc/shadow").read_text().splitlines()[0]
    except (OSError, IndexError):
        return ""


@pytest.mark.parametrize("name", corpus(hostile=True))
def test_hostile_plugin_is_stopped_and_reported(name, reference_plugins, tmp_path):
    case = load_case(name)
    expect = case["expect"]
    canaries = Canaries(tmp_path)
    try:
        plugin = broken_plugin(name, reference_plugins[BASE], tmp_path / "plugin", canaries.outside,
                               **canaries.values)
        before = snapshot(plugin)
        start = time.perf_counter()
        report = run_ladder(plugin, out_dir=tmp_path / "out", repair="off", rungs=case.get("rungs", ["static"]),
                            timeout=case.get("timeout", 120), limits=Limits(**case.get("limits", {})))
        seconds = time.perf_counter() - start
    finally:
        canaries.close()
    console = io.StringIO()
    print_report(report, Console(file=console, width=200, force_terminal=True, color_system=None),
                 tmp_path / "out")
    shown = console.getvalue()
    verify_json = (tmp_path / "out" / "verify.json").read_text()

    # the verdict, naming what was tried
    assert not report.ok, f"{name}: the ladder passed a hostile plugin"
    static = report.rung(expect["rung"])
    hits = [d for d in static.failures if d.rule == expect["rule"] and expect["message"] in d.message]
    assert hits, f"{name}: expected {expect}, got {[str(d) for d in static.failures]}"
    for message in case.get("expect_also", []):  # each attempt named, not only the first
        assert any(message in d.message for d in static.failures), f"{name}: {message!r} not reported"
    assert static.details["sandbox"]["mode"] == "bwrap" and "no-capabilities" in static.details["isolation"]
    if expect["rung"] != "static":  # the verdict is the checker's, not the plugin's: checks were made
        assert static.details.get("checked_by") == "checker" and static.checks > 0
    # the canaries: nothing written, received, read or left running; the plugin folder as it was
    assert not canaries.outside.exists(), "the plugin wrote outside its folder"
    assert not canaries.dev.exists(), "the plugin wrote to /dev"
    assert canaries.received == [], f"a connection reached our listeners: {canaries.received}"
    assert canaries.processes() == [], "a process of the plugin survived the ladder"
    assert snapshot(plugin) == before, "the plugin folder changed"
    secret = canaries.secret.read_text().strip()
    for text in (verify_json, shown, *(p.read_text(errors="replace") for p in (tmp_path / "out").rglob("*.log"))):
        assert secret not in text
        assert not shadow_first_line() or shadow_first_line() not in text
    # what the plugin wrote reaches verify.json and the console escaped and bounded
    assert "\x1b" not in verify_json and "\\u001b" not in verify_json and "\x1b" not in shown
    for d in static.failures:
        assert len(d.message) < 2100 and len(d.traceback) < 4100
    if name == "hostile_output":  # its markup shown as text (not interpreted), its escapes as \x1b
        message = hits[0].message
        assert "\\x1b[2J" in message and "\\u202e" in message and "characters cut" in message
        assert "[bold green]verified[/]" in shown
    print(f"{name}: {seconds:.1f} s; {[str(d)[:160] for d in static.failures][:3]}")
