"""The sandbox (nerfify_ns/runtime/sandbox.py) against root-level tricks, with plain Python commands (no torch,
a fraction of a second each): an unprivileged user with no capability, a read-only root with nothing secret in
it, no network and no way back to ours, private /tmp and /dev/shm, a minimal /dev that cannot be written, limits
on the whole process tree (cgroup, else rlimits), no process surviving the run, bounded and escaped output.

Each test states the escape it tries and asserts the state of a canary the test owns (a file outside the run
folder, a listener, a socket, the host's process table), not only what the sandboxed command printed."""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
import uuid
from pathlib import Path

import pytest

from nerfify_ns.runtime.sandbox import (
    SANDBOX_UID,
    Limits,
    SandboxError,
    TreeCgroup,
    _own_cgroups,
    available_modes,
    run_sandboxed,
    seccomp_filter,
)

BWRAP = "bwrap" in available_modes()
needs_bwrap = pytest.mark.skipif(not BWRAP, reason="needs root and bubblewrap (scripts/setup.sh installs it)")
needs_unshare = pytest.mark.skipif("unshare" not in available_modes(), reason="needs root and unshare")
CGROUP = TreeCgroup.create(Limits()) if BWRAP else None
if CGROUP is not None:
    CGROUP.remove()
needs_cgroup = pytest.mark.skipif(CGROUP is None, reason="needs a writable memory and pids cgroup (root)")


def run_py(code: str, work: Path, **kw):
    """Run Python ``code`` sandboxed; its stdout parsed as JSON (the last line), and the result."""
    r = run_sandboxed([sys.executable, "-c", code], work, timeout=kw.pop("timeout", 60), **kw)
    lines = r.log_path.read_text(errors="replace").strip().splitlines()
    try:
        out = json.loads(lines[-1]) if lines else None
    except ValueError:
        out = None
    return out, r


def marker_processes(marker: str) -> list:
    """Host processes whose command line contains ``marker``."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmd = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            if marker in cmd:
                found.append((entry, cmd))
    return found


@needs_bwrap
def test_unprivileged_user_without_capabilities(tmp_path):
    code = ("import os, json; st = dict(l.split(':\\t') for l in open('/proc/self/status').read().splitlines() "
            "if ':\\t' in l); print(json.dumps({'ids': [os.getuid(), os.geteuid(), os.getgid(), os.getgroups()], "
            "'caps': [st['CapEff'], st['CapPrm'], st['CapBnd'], st['CapInh'], st['CapAmb']], "
            "'nnp': st['NoNewPrivs'], 'pid': os.getpid(), 'ppid': os.getppid()}))")
    out, r = run_py(code, tmp_path / "w")
    assert r.mode == "bwrap" and r.returncode == 0, r.tail()
    assert out["ids"] == [SANDBOX_UID, SANDBOX_UID, SANDBOX_UID, []]
    assert set(out["caps"]) == {"0000000000000000"} and out["nnp"] == "1"
    assert out["pid"] < 10 and out["ppid"] == 1  # a PID namespace of its own
    for tag in ("bwrap", f"uid-{SANDBOX_UID}", "no-capabilities", "no-new-privs", "no-network", "read-only-fs",
                "pid-namespace"):
        assert tag in r.isolation


@needs_bwrap
def test_filesystem_read_only_private_and_without_secrets(tmp_path):
    outside = tmp_path / "outside.txt"
    secret = tmp_path / "secret.txt"
    secret.write_text("canary-secret")
    home_canary = Path.home() / f".nerfify-canary-{uuid.uuid4().hex[:8]}"
    host_tmp = f"/tmp/nerfify-canary-{uuid.uuid4().hex[:8]}"
    dev_canary = f"/dev/nerfify-canary-{uuid.uuid4().hex[:8]}"
    home_canary.write_text("home")
    try:
        code = f"""
import os, json, subprocess
res = {{}}
for p in ["/usr/x", "/etc/x", "/x", "/root/x", {str(outside)!r}, {dev_canary!r}, "/proc/sys/kernel/hostname"]:
    try:
        open(p, "w").write("escaped"); res[p] = "wrote"
    except OSError as e:
        res[p] = e.errno
for p in ["/etc/shadow", "/etc/gshadow", "/etc/sudoers", {str(secret)!r}, {str(home_canary)!r}]:
    res["read " + p] = os.path.exists(p)
res["remount"] = subprocess.run(["mount", "-o", "remount,rw", "/"], capture_output=True).returncode
res["root"] = sorted(os.listdir("/root"))
open("inside.txt", "w").write("ok")
open({host_tmp!r}, "w").write("tmp")
open("/dev/shm/x", "w").write("shm")
print(json.dumps(res))
"""
        out, r = run_py(code, tmp_path / "w")
        assert r.returncode == 0, r.tail()
        assert not outside.exists() and not Path(dev_canary).exists() and not Path(host_tmp).exists()
        assert all(v != "wrote" for k, v in out.items() if k.startswith("/")), out
        assert not any(v for k, v in out.items() if k.startswith("read ")), out
        assert out["remount"] != 0
        assert set(out["root"]) <= {".pyenv", ".cache"}, out["root"]  # only what the interpreter needs
        inside = tmp_path / "w" / "inside.txt"
        assert inside.read_text() == "ok" and inside.stat().st_uid == os.getuid()  # handed back to us
    finally:
        home_canary.unlink(missing_ok=True)
        Path(dev_canary).unlink(missing_ok=True)
        Path(host_tmp).unlink(missing_ok=True)


@needs_bwrap
def test_no_network_no_way_back_to_ours(tmp_path):
    received = []
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(5)
    server.settimeout(0.2)
    port = server.getsockname()[1]
    unix_path = f"/tmp/nerfify-test-{uuid.uuid4().hex[:8]}.sock"
    unix = socket.socket(socket.AF_UNIX)
    unix.bind(unix_path)
    unix.listen(5)
    unix.settimeout(0.2)
    stop = threading.Event()

    def accept():
        while not stop.is_set():
            for s in (server, unix):
                try:
                    conn, _ = s.accept()
                    received.append(conn.recv(100))
                    conn.close()
                except OSError:
                    pass

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        code = f"""
import ctypes, json, os, socket
res = {{}}
libc = ctypes.CDLL(None, use_errno=True)
try:
    os.open("/proc/1/ns/net", os.O_RDONLY)
except OSError as e:
    res["open 1"] = e.errno
for addr in [("127.0.0.1", {port}), ("1.1.1.1", 80)]:
    try:
        socket.create_connection(addr, timeout=3).sendall(b"escaped"); res[str(addr)] = "connected"
    except OSError as e:
        res[str(addr)] = e.errno
try:
    u = socket.socket(socket.AF_UNIX); u.connect({unix_path!r}); u.sendall(b"escaped"); res["unix"] = "connected"
except OSError as e:
    res["unix"] = e.errno
print(json.dumps(res))
"""
        out, r = run_py(code, tmp_path / "w")
        time.sleep(0.5)
    finally:
        stop.set()
        thread.join()
        server.close()
        unix.close()
        os.unlink(unix_path)
    assert r.returncode == 0, r.tail()
    assert received == [], "a connection reached the test's listener"
    assert "connected" not in out.values() and "joined" not in out.values(), out
    assert out["open 1"] == 13  # the sandbox's init is root's: not even its namespace file opens
    if "seccomp-supervised" in r.isolation:  # each inet connect named, the unix one (no such socket here) not
        assert {a["detail"] for a in r.attempts if a["call"] == "connect"} == {f"127.0.0.1:{port}", "1.1.1.1:80"}


ESCAPES = {
    "mount": 'libc.mount(b"none", b"/", None, 32 | 1, None)',
    "umount2": 'libc.umount2(b"/usr", 2)',
    "pivot_root": 'libc.pivot_root(b"/tmp", b"/tmp")',
    "setns": 'libc.setns(os.open("/proc/self/ns/net", os.O_RDONLY), 0)',
    "unshare": "libc.unshare(0x00020000)",
    "ptrace": "libc.ptrace(16, 1, 0, 0)",
    "bpf": "libc.syscall(BPF, 0, 0, 0)",
    "keyctl": "libc.syscall(KEYCTL, 0, 0, 0)",
    "init_module": "libc.syscall(INIT_MODULE, 0, 0, 0)",
    "finit_module": "libc.syscall(FINIT_MODULE, 0, 0, 0)",
    "delete_module": 'libc.syscall(DELETE_MODULE, b"ext4", 0)',
    "reboot": "libc.syscall(REBOOT, 0, 0, 0, 0)",
    "kexec_load": "libc.syscall(KEXEC_LOAD, 0, 0, 0, 0)",
    "AF_NETLINK": "socket.socket(16, socket.SOCK_RAW, 0)",
    "AF_PACKET": "socket.socket(17, socket.SOCK_RAW, 0)",
    "SOCK_RAW": "socket.socket(socket.AF_INET, socket.SOCK_RAW, 1)",
}


@needs_bwrap
@pytest.mark.parametrize("call", sorted(ESCAPES))
def test_an_escape_call_kills_the_process_and_is_named(call, tmp_path):
    """Each call only an escape attempt needs, made by a plugin that swallows the error: the process is killed
    (it never prints 'survived') and the sandbox names the call."""
    from nerfify_ns.runtime.seccomp import arch, supervised_available

    if not supervised_available():
        pytest.skip("this kernel has no seccomp user notification: the kill filter stops the call unnamed")
    numbers = {k.upper(): v for k, v in arch()[2].items()}
    code = (f"import ctypes, os, socket\nlibc = ctypes.CDLL(None, use_errno=True)\n{numbers!r}\n"
            + "".join(f"{k} = {v}\n" for k, v in numbers.items())
            + f"try:\n    {ESCAPES[call]}\nexcept Exception:\n    pass\nprint('survived')\n")
    r = run_sandboxed([sys.executable, "-c", code], tmp_path / "w", timeout=60)
    assert "survived" not in r.tail(), f"{call} went on: {r.tail()}"
    assert r.returncode == 137 and r.attempts, (r.returncode, r.attempts)
    named = r.attempts[0]["call"] + "(" + r.attempts[0]["detail"]
    assert call in named and r.attempts[0]["action"] == "killed", r.attempts
    assert any(call in s and "killed" in s for s in r.attempt_sentences())


@needs_bwrap
def test_the_kill_filter_alone_stops_an_escape_call(tmp_path, monkeypatch):
    """Without supervision (``NERFIFY_SECCOMP=kill``, as on a kernel without user notification) the same
    call kills the process with SIGSYS, and the result says a forbidden call killed it."""
    monkeypatch.setenv("NERFIFY_SECCOMP", "kill")
    code = "import ctypes\nctypes.CDLL(None).mount(b'none', b'/', None, 33, None)\nprint('survived')\n"
    r = run_sandboxed([sys.executable, "-c", code], tmp_path / "w", timeout=60)
    assert "seccomp-kill" in r.isolation and "survived" not in r.tail()
    assert r.returncode == 128 + 31 and any("SIGSYS" in s for s in r.attempt_sentences())


@needs_bwrap
def test_no_user_namespace_inside(tmp_path):
    assert seccomp_filter() is not None
    out, r = run_py("import subprocess, json; print(json.dumps(subprocess.run(['unshare', '-U', '-r', 'true'])"
                    ".returncode))", tmp_path / "w")
    assert out != 0 and "seccomp-no-userns" in r.isolation
    if "seccomp-supervised" in r.isolation:
        assert any(a["call"] == "unshare" for a in r.attempts), r.attempts


@needs_bwrap
def test_no_process_outlives_the_run(tmp_path):
    """setsid children that double-fork, and a command that never ends: none is left on the host."""
    marker = f"631.{uuid.uuid4().int % 10**6}"
    daemon = (f"import os, subprocess\nfor _ in range(5):\n    subprocess.Popen(['sh', '-c', 'sleep {marker} & "
              f"sleep {marker}'], start_new_session=True)\n")
    r = run_sandboxed([sys.executable, "-c", daemon + "print('started')"], tmp_path / "a", timeout=60)
    assert r.returncode == 0 and "started" in r.tail()
    assert marker_processes(marker) == []
    r = run_sandboxed([sys.executable, "-c", daemon + "while True: pass"], tmp_path / "b", timeout=3)
    assert r.timed_out and r.seconds < 30
    assert marker_processes(marker) == []


@needs_bwrap
@needs_cgroup
def test_memory_limit_binds_the_whole_tree(tmp_path):
    """Three children of 1 GiB each, the tree limited to 1.5 GiB: the kernel kills some, the peak stays below."""
    limit = 1536 << 20
    code = ("import subprocess, sys, json\nps = [subprocess.Popen([sys.executable, '-c', 'b = bytearray(1 << 30); "
            "import time; time.sleep(3)']) for _ in range(3)]\nprint(json.dumps([p.wait() for p in ps]))")
    out, r = run_py(code, tmp_path / "w", limits=Limits(memory=limit))
    assert r.limits["memory_scope"] == "tree" and "cgroup-memory" in r.isolation
    assert -9 in out and r.usage["oom_kills"] >= 1, (out, r.usage)
    assert r.usage["peak_memory"] <= limit
    assert any("memory limit" in hit for hit in r.limit_hits())


@needs_bwrap
@needs_cgroup
def test_process_limit_binds_the_whole_tree(tmp_path):
    marker = f"632.{uuid.uuid4().int % 10**6}"
    code = (f"import subprocess, json\nps = []\ntry:\n    for _ in range(100):\n        ps.append(subprocess.Popen("
            f"['sleep', '{marker}'], start_new_session=True))\nexcept OSError as e:\n    pass\nprint(len(ps))")
    out, r = run_py(code, tmp_path / "w", limits=Limits(pids=32))
    assert out < 32 and r.usage["pids_refused"] >= 1, (out, r.usage)
    assert any("limit of 32 processes" in hit for hit in r.limit_hits())
    assert marker_processes(marker) == []


@needs_bwrap
@needs_cgroup
def test_cgroup_removed_after_the_run(tmp_path):
    run_py("print(1)", tmp_path / "w")
    own = _own_cgroups()
    for controller in ("memory", "pids"):
        folder = Path(f"/sys/fs/cgroup/{controller}") / own.get(controller, "/").lstrip("/")
        if folder.is_dir():
            assert not list(folder.glob(f"nerfify-{os.getpid()}-*"))


@needs_bwrap
def test_rlimit_fallback_binds_the_unprivileged_user(tmp_path):
    """Without a cgroup: RLIMIT_NPROC binds (the command is not root), RLIMIT_AS per process."""
    marker = f"633.{uuid.uuid4().int % 10**6}"
    code = (f"import subprocess, json\nps = []\ntry:\n    for _ in range(100):\n        ps.append(subprocess.Popen("
            f"['sleep', '{marker}']))\nexcept OSError:\n    pass\ntry:\n    b = bytearray(3 << 30); big = 'allocated'\n"
            "except MemoryError:\n    big = 'MemoryError'\nprint(json.dumps([len(ps), big]))")
    out, r = run_py(code, tmp_path / "w", limits=Limits(pids=40, memory=1 << 30, cgroups=False))
    assert "rlimit-nproc" in r.isolation and "rlimit-as" in r.isolation
    assert out[0] < 40 and out[1] == "MemoryError", out
    assert marker_processes(marker) == []


@needs_unshare
def test_unshare_fallback_is_recorded_and_offline(tmp_path):
    out, r = run_py("import socket, json\ntry:\n    socket.create_connection(('1.1.1.1', 80), timeout=3); n = 'net'\n"
                    "except OSError as e:\n    n = e.errno\nprint(json.dumps(n))", tmp_path / "w", mode="unshare")
    assert r.mode == "unshare" and "root-with-capabilities" in r.isolation and "no-network" in r.isolation
    assert out != "net"


def test_no_isolation_still_times_out_and_limits(tmp_path):
    r = run_sandboxed([sys.executable, "-c", "while True: pass"], tmp_path / "loop", timeout=2, mode="none")
    assert r.timed_out and r.mode == "none"


@needs_bwrap
def test_environment_secrets_not_passed(tmp_path, monkeypatch):
    monkeypatch.setenv("SECRET_TOKEN_FOR_TEST", "hunter2")
    out, r = run_py("import os, json; print(json.dumps(sorted(os.environ)))", tmp_path / "w", env={"EXTRA": "1"})
    assert "SECRET_TOKEN_FOR_TEST" not in out and "EXTRA" in out and "HOME" in out


@needs_bwrap
def test_output_tail_bounded_and_escaped(tmp_path):
    code = "import sys\nfor _ in range(200000): sys.stdout.write('\\x1b[2J\\x1b]0;pwned\\x07' + 'x' * 40 + '\\n')"
    r = run_sandboxed([sys.executable, "-c", code], tmp_path / "w", timeout=60)
    tail = r.tail(30)
    assert "\x1b" not in tail and "\x07" not in tail and "\\x1b" in tail
    assert len(tail) < 30 * 200


@needs_bwrap
def test_unreadable_folder_is_refused(tmp_path):
    private = tmp_path / "private"
    private.mkdir(mode=0o700)
    with pytest.raises(SandboxError, match="not readable by other users"):
        run_sandboxed([sys.executable, "-c", "pass"], tmp_path / "w", timeout=30, readonly=[private])


def test_cgroup_v2_layout_on_a_stand_in_hierarchy(tmp_path, monkeypatch):
    """The cgroup v2 path (this machine has v1): on a stand-in hierarchy, the controllers enabled for the
    children, the run's cgroup made below ours with its limits, and what it used read back."""
    import shutil

    import nerfify_ns.runtime.sandbox as sb

    root = tmp_path / "cgroup"
    own = root / "user.slice" / "me"
    own.mkdir(parents=True)
    (own / "cgroup.controllers").write_text("cpu memory pids\n")
    (own / "cgroup.subtree_control").write_text("cpu\n")
    monkeypatch.setattr(sb, "_mountinfo", lambda: [("/", str(root), "cgroup2", "rw")])
    monkeypatch.setattr(sb, "_own_cgroups", lambda: {"": "/user.slice/me"})
    group = sb.TreeCgroup.create(Limits(memory=123 << 20, pids=7))
    assert group is not None and group.version == 2
    folder = group.dirs["memory"]
    assert group.dirs["pids"] == folder and folder.parent == own and folder.name.startswith(f"nerfify-{os.getpid()}-")
    assert (own / "cgroup.subtree_control").read_text() == "+memory +pids"
    assert (folder / "memory.max").read_text() == str(123 << 20) and (folder / "pids.max").read_text() == "7"
    (folder / "memory.events").write_text("low 0\nhigh 0\nmax 3\noom 1\noom_kill 2\n")
    (folder / "memory.peak").write_text("456\n")
    (folder / "pids.events").write_text("max 5\n")
    assert group.usage() == {"oom_kills": 2, "peak_memory": 456, "pids_refused": 5}
    shutil.rmtree(folder)
    (own / "cgroup.controllers").write_text("cpu\n")  # no memory controller here: not usable
    assert sb.TreeCgroup._v2("x", Limits()) is None


def test_interpreter_environment_is_visible(tmp_path, monkeypatch):
    """What the interpreter's site-packages reach is readable in the sandbox: editable installs of setuptools
    (a plugin installed with pip -e) and of hatchling, .pth folders, packages linked in from another venv."""
    import site

    import nerfify_ns.runtime.sandbox as sb

    sp = tmp_path / "site"
    sp.mkdir()
    targets = {name: tmp_path / name for name in ("setuptools_pkg", "hatch_pkg", "pth_dir", "other_venv")}
    for t in targets.values():
        t.mkdir()
    (targets["hatch_pkg"] / "__init__.py").write_text("")
    (targets["other_venv"] / "torchlike").mkdir()
    (sp / "__editable___p_0_1_finder.py").write_text(
        f"import sys\nMAPPING: dict[str, str] = {{'p': '{targets['setuptools_pkg']}'}}\nNAMESPACES = {{}}\n")
    (sp / "_editable_impl_h.py").write_text(f"F.map_module('h', '{targets['hatch_pkg'] / '__init__.py'}')")
    (sp / "x.pth").write_text(f"{targets['pth_dir']}\nimport os\n")
    (sp / "torchlike").symlink_to(targets["other_venv"] / "torchlike")
    monkeypatch.setattr(site, "getsitepackages", lambda: [str(sp)])
    assert set(targets.values()) <= set(sb._site_paths())



@needs_bwrap
def test_sandbox_dies_with_us_even_when_we_are_killed(tmp_path):
    """SIGKILL to the process that started the sandbox (no clean-up of ours runs): bubblewrap dies with its
    parent and the PID namespace with it; the empty cgroup left behind is removed by the next run."""
    import signal
    import subprocess

    marker = f"634.{uuid.uuid4().int % 10**6}"
    script = (f"import sys\nfrom pathlib import Path\nfrom nerfify_ns.runtime.sandbox import run_sandboxed\n"
              f"run_sandboxed(['sh', '-c', 'sleep {marker} & sleep {marker}; wait'], Path({str(tmp_path / 'w')!r}),"
              f" timeout=120)\n")
    parent = subprocess.Popen([sys.executable, "-c", script])

    def sleeping() -> list:  # the sandboxed command itself (the parent's own command line names the marker too)
        return [p for p in marker_processes(marker) if p[1].startswith(f"sleep {marker}")]

    deadline = time.monotonic() + 60
    while len(sleeping()) < 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert len(sleeping()) == 2, "the sandboxed command did not start"
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 10
    while marker_processes(marker) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert marker_processes(marker) == []
    if CGROUP is not None:
        run_py("print(1)", tmp_path / "next")  # sweeps cgroups of processes that no longer exist
        own = _own_cgroups()
        for controller in ("memory", "pids"):
            folder = Path(f"/sys/fs/cgroup/{controller}") / own.get(controller, "/").lstrip("/")
            assert not list(folder.glob(f"nerfify-{parent.pid}-*"))


@needs_bwrap
def test_packages_on_pythonpath_are_importable_inside(tmp_path, monkeypatch):
    """A package installed with ``pip install --target DIR`` and reached through ``PYTHONPATH`` (which the
    sandbox passes on) is readable inside too, even under ``/tmp``, which is the sandbox's own."""
    target = Path(f"/tmp/nerfify-target-{uuid.uuid4().hex[:8]}")
    (target / "targetpkg").mkdir(parents=True)
    try:
        (target / "targetpkg" / "__init__.py").write_text("VALUE = 41 + 1\n")
        os.chmod(target, 0o755)
        monkeypatch.setenv("PYTHONPATH", str(target))
        out, r = run_py("import json, targetpkg; print(json.dumps(targetpkg.VALUE))", tmp_path / "w")
        assert out == 42, r.tail()
    finally:
        import shutil

        shutil.rmtree(target)


@needs_bwrap
def test_gpu_device_nodes_are_bound_in_and_opening_them_is_no_attempt(tmp_path, monkeypatch):
    """With a GPU, its device nodes are in the sandbox's /dev and opening them read-write (as CUDA does) is
    neither refused nor recorded; no address-space limit is set (CUDA reserves far more than it uses). A node
    bwrap's minimal /dev lacks stands in for the GPU's; without one it is not there."""
    import nerfify_ns.runtime.sandbox as sb

    node = Path("/dev/fuse")
    if not node.exists():
        pytest.skip("needs /dev/fuse, a character device outside bwrap's minimal /dev, to stand in for a GPU's")
    code = ("import json, os\ntry:\n    fd = os.open('/dev/fuse', os.O_RDWR); os.close(fd); r = 'opened'\n"
            "except OSError as e:\n    r = e.strerror\nprint(json.dumps(r))")
    limits = Limits(cgroups=False)
    out, r = run_py(code, tmp_path / "without", limits=limits)
    assert out == "No such file or directory" and "gpu-devices" not in r.isolation and "rlimit-as" in r.isolation
    monkeypatch.setattr(sb, "gpu_devices", lambda: (node,))
    out, r = run_py(code, tmp_path / "with", limits=limits)
    assert out == "opened", r.tail()
    assert "gpu-devices" in r.isolation and "no-memory-limit" in r.isolation and "rlimit-as" not in r.isolation
    assert r.limits["memory"] is None
    assert not [a for a in r.attempts if "/dev/fuse" in str(a)], r.attempts


@needs_bwrap
def test_torchs_downloaded_weights_are_readable_inside(tmp_path, monkeypatch):
    """Weights torch's hub keeps (torchvision's AlexNet, which Nerfstudio's stock LPIPS loads where our runtime
    leaves it in place, with CUDA) are found inside through the same TORCH_HOME, read-only: offline, the sandboxed
    run could not fetch them."""
    cache = Path(f"/tmp/nerfify-cache-home-{uuid.uuid4().hex[:8]}")
    home = cache / "torch"  # torch's default under our XDG_CACHE_HOME, which the sandbox replaces with its own
    (home / "hub" / "checkpoints").mkdir(parents=True)
    try:
        os.chmod(cache, 0o755)
        (home / "hub" / "checkpoints" / "weights.pth").write_text("stand-in")
        monkeypatch.delenv("TORCH_HOME", raising=False)
        monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
        code = ("import json, os, torch\nd = torch.hub.get_dir()\nf = os.path.join(d, 'checkpoints', 'weights.pth')\n"
                "try:\n    open(f, 'a').close(); w = 'writable'\nexcept OSError:\n    w = 'read-only'\n"
                "print(json.dumps([d, open(f).read(), w]))")
        out, r = run_py(code, tmp_path / "w")
        assert out == [str(home / "hub"), "stand-in", "read-only"], r.tail()
    finally:
        import shutil

        shutil.rmtree(cache)
