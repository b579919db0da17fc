"""The sandbox: how code we do not trust (a plugin's, and anything that imports it) runs.

One call, :func:`run_sandboxed`, runs a command with its working directory ``workdir`` (the only place it
may write), the folders it needs to read (``readonly``: the plugin, the scene) and limits on its whole
process tree. The isolation is the strongest this machine allows, chosen per run and recorded in the
result (``mode`` and the ``isolation`` tags, which the ladder writes into ``verify.json``):

``bwrap`` (root, with Debian's ``bubblewrap`` and util-linux's ``setpriv``)
    bubblewrap, run by root, builds new mount, PID, network, IPC, UTS and cgroup namespaces
    (``--unshare-pid --unshare-net --unshare-ipc --unshare-uts --unshare-cgroup-try``, ``--die-with-parent``,
    ``--new-session``). The root is a read-only tmpfs holding only read-only binds of ``/usr`` (and the
    ``/bin``, ``/lib*`` links), an allow-list of ``/etc`` files (no ``shadow``, ``gshadow``, keys or
    ``sudoers``), the Python installation, the virtual environment, the nerfify-ns checkout, the built
    kernel cache, what the interpreter's site-packages reach (editable installs, linked packages) and
    ``readonly``; ``workdir`` is the one writable bind (owned by the sandbox's user while it runs). ``/proc`` is the
    sandbox's own (its PID namespace), ``/dev`` a minimal one (null, zero, random, tty...) that cannot be written,
    with the GPU's device nodes bound in where there is one (:func:`gpu_devices`), ``/tmp`` and ``/dev/shm``
    private size-limited tmpfs, ``HOME`` a folder inside ``workdir``. Nothing of
    ``/root``, ``/home``, ``/run``, ``/var`` or ``/sys`` (but ``/sys/devices/system/cpu``) is there. bwrap
    keeps only CAP_SETUID, CAP_SETGID and CAP_SETPCAP for ``setpriv``, which then becomes uid/gid 65534
    (``nobody``: an unprivileged user on the host, not only inside a user namespace), clears supplementary
    groups, the bounding, inheritable and ambient capability sets, and sets ``no_new_privs`` before it
    executes the command. The command therefore has no capability in any namespace: it cannot mount,
    ``setns``, write a sysctl, or read a root-only file, and the process-count rlimit binds it. A seccomp
    filter (:func:`seccomp_filter`) refuses it a user namespace of its own, where it would regain capabilities
    over new namespaces. (Why not bwrap's own ``--unshare-user --uid 65534``: run by root, that maps the
    sandbox's user to the host's root, so the process-count rlimit does not bind it and root-owned files
    treat it as their owner.)
``unshare`` (root, without bubblewrap): the weaker fallback
    ``unshare -n -m``: no network, the root file system remounted read-only but ``workdir``, a fresh
    ``/dev/shm``. The command runs as root with every capability (it can remount, setns, read
    ``/etc/shadow``); only the limits below and the network namespace hold.
``none`` (not root, or neither tool): the limits below only.

Limits on the whole tree: a cgroup of its own per run (cgroup v2 where the memory and pids controllers
are available there, else the v1 ``memory`` and ``pids`` hierarchies) with a memory limit (swap included)
and a task limit; the command's first process joins it before it executes (``preexec``), so every
descendant is in it. After the run every task still in the cgroup is killed and the cgroup removed. Where
no cgroup can be written: ``RLIMIT_AS`` per process (not with a GPU bound in: CUDA reserves address space
far beyond what it uses, so the run then has no memory limit, recorded as ``no-memory-limit``) and
``RLIMIT_NPROC`` (binding only a non-root user, which in ``bwrap`` mode the command is). Always:
``RLIMIT_NOFILE``, ``RLIMIT_FSIZE``, no core dumps, stdin from ``/dev/null``, and the wall-time limit of
:func:`nerfify_ns.runtime.process.run_process` (the whole process group killed); in ``bwrap`` mode the PID
namespace makes every descendant die with the run.

What the command prints goes to a log file; :meth:`SandboxResult.tail` reads a bounded end of it with
control characters escaped (:mod:`nerfify_ns.safetext`).
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import os
import re
import resource
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from nerfify_ns.runtime.paths import ENV_CACHE, nerfify_cache_dir
from nerfify_ns.runtime.process import Poll, ProcessResult, pid_alive, run_process
from nerfify_ns.runtime.seccomp import Installer, Supervisor, kill_filter, notify_filter, notify_supported
from nerfify_ns.safetext import clean

GiB = 1 << 30
SANDBOX_UID = 65534
"""The unprivileged user (``nobody``) the command runs as in ``bwrap`` mode."""
SANDBOX_GID = 65534
MODES = ("bwrap", "unshare", "none")
"""Isolation modes, strongest first."""

ETC_FILES = (
    "passwd", "group", "nsswitch.conf", "host.conf", "hosts", "ld.so.cache", "ld.so.conf", "ld.so.conf.d",
    "localtime", "timezone", "alternatives", "os-release", "debian_version", "mime.types", "protocols",
    "services", "fonts", "ssl/certs", "ca-certificates.conf", "gai.conf", "inputrc", "matplotlibrc",
)
"""The only ``/etc`` entries visible in the sandbox (no ``shadow``, ``gshadow``, ``sudoers``, ssh or TLS keys)."""

ENV_KEEP = re.compile(
    r"^(PATH|LANG|LANGUAGE|LC_[A-Z]+|TZ|PYTHONHASHSEED|PYTHONPATH|OMP_[A-Z_]+|MKL_[A-Z_]+|OPENBLAS_[A-Z_]+"
    r"|TORCH_[A-Z_]+|CUDA_VISIBLE_DEVICES|NERFIFY_[A-Z_]+)$"
)
"""The variables of our environment the sandboxed command sees (plus what the caller passes); others, where
secrets live, are not passed on."""


class SandboxError(RuntimeError):
    """The sandbox cannot be set up as asked (a folder its user cannot read, an unknown mode)."""


def _physical_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 16 * GiB


DEFAULT_MEMORY = min(12 * GiB, _physical_memory() * 3 // 4)
"""Memory of the whole process tree (or of each process, in the rlimit fallback)."""


@dataclass(frozen=True)
class Limits:
    """What one sandboxed run may use."""

    memory: int = DEFAULT_MEMORY
    """Bytes of memory (resident, page cache, tmpfs) of the whole process tree; per process (address space)
    where no memory cgroup can be written."""
    pids: int = 1024
    """Processes and threads of the whole tree; of the sandbox's user (``RLIMIT_NPROC``) without a pids cgroup."""
    files: int = 4096
    """Open files per process (``RLIMIT_NOFILE``)."""
    file_size: int = 16 * GiB
    """Largest file one process may write (``RLIMIT_FSIZE``); total disk use is not limited."""
    tmp: int = 2 * GiB
    """Size of each private tmpfs (``/tmp`` and ``/dev/shm``, counted in ``memory`` too)."""
    cgroups: bool = True
    """Use a cgroup where one can be written (False: the rlimit fallback, for tests)."""


# ----------------------------------------------------------------------------------------------- cgroups
def _mountinfo() -> list[tuple[str, str, str, str]]:
    """(root, mount point, fs type, super options) of every mount."""
    out = []
    try:
        text = Path("/proc/self/mountinfo").read_text()
    except OSError:
        return out
    for line in text.splitlines():
        left, _, right = line.partition(" - ")
        parts, rest = left.split(), right.split()
        if len(parts) >= 5 and len(rest) >= 3:
            out.append((parts[3], parts[4], rest[0], rest[2]))
    return out


def _own_cgroups() -> dict[str, str]:
    """Controller (or ``""`` for v2) -> our cgroup path, from ``/proc/self/cgroup``."""
    found: dict[str, str] = {}
    try:
        text = Path("/proc/self/cgroup").read_text()
    except OSError:
        return found
    for line in text.splitlines():
        parts = line.split(":", 2)
        if len(parts) == 3:
            for controller in parts[1].split(",") if parts[1] else [""]:
                found[controller] = parts[2]
    return found


def _under(mount_root: str, mount_point: str, path: str) -> Path | None:
    """The folder of cgroup ``path`` in a hierarchy mounted at ``mount_point`` from ``mount_root``."""
    root = mount_root.rstrip("/")
    if root and not (path == root or path.startswith(root + "/")):
        return None
    return Path(mount_point) / path[len(root):].lstrip("/")


def _write(path: Path, value: str) -> None:
    with open(path, "w") as f:
        f.write(value)


def _read_int(path: Path, key: str | None = None) -> int | None:
    """An integer file, or the value of ``key`` in a flat-keyed one; None when absent."""
    try:
        text = path.read_text()
    except OSError:
        return None
    if key is None:
        try:
            return int(text.split()[0])
        except (ValueError, IndexError):
            return None
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] == key:
            try:
                return int(parts[1])
            except ValueError:
                return None
    return None


class TreeCgroup:
    """The cgroup of one run: memory and task limits on the whole process tree, its tasks killed and the
    cgroup removed at the end. ``dirs`` maps ``memory``/``pids`` to the folder holding that controller
    (one folder for both under cgroup v2)."""

    PREFIX = "nerfify-"

    def __init__(self, version: int, dirs: dict[str, Path]) -> None:
        self.version = version
        self.dirs = dirs

    @property
    def folders(self) -> list[Path]:
        return list(dict.fromkeys(self.dirs.values()))

    @classmethod
    def create(cls, limits: Limits) -> TreeCgroup | None:
        """A new cgroup below ours with the memory and pids limits set; None where none can be written."""
        name = f"{cls.PREFIX}{os.getpid()}-{uuid.uuid4().hex[:8]}"
        return cls._v2(name, limits) or cls._v1(name, limits)

    @classmethod
    def _v2(cls, name: str, limits: Limits) -> TreeCgroup | None:
        own = _own_cgroups().get("")
        mount = next(((r, m) for r, m, fs, _ in _mountinfo() if fs == "cgroup2"), None)
        if own is None or mount is None:
            return None
        parent = _under(mount[0], mount[1], own)
        if parent is None or not (parent / "cgroup.controllers").is_file():
            return None
        try:
            available = (parent / "cgroup.controllers").read_text().split()
            if not {"memory", "pids"} <= set(available):
                return None
            enabled = (parent / "cgroup.subtree_control").read_text().split()
            if not {"memory", "pids"} <= set(enabled):
                _write(parent / "cgroup.subtree_control", "+memory +pids")
            cls._sweep(parent, 2)
            folder = parent / name
            folder.mkdir()
        except OSError:
            return None
        group = cls(2, {"memory": folder, "pids": folder})
        try:
            _write(folder / "memory.max", str(limits.memory))
            if (folder / "memory.swap.max").exists():
                _write(folder / "memory.swap.max", "0")
            _write(folder / "pids.max", str(limits.pids))
        except OSError:
            group.remove()
            return None
        return group

    @classmethod
    def _v1(cls, name: str, limits: Limits) -> TreeCgroup | None:
        own = _own_cgroups()
        dirs: dict[str, Path] = {}
        for controller in ("memory", "pids"):
            mount = next(((r, m) for r, m, fs, opts in _mountinfo()
                          if fs == "cgroup" and controller in opts.split(",")), None)
            if mount is None or controller not in own:
                continue
            parent = _under(mount[0], mount[1], own[controller])
            if parent is None:
                continue
            cls._sweep(parent, 1)
            try:
                (parent / name).mkdir()
            except OSError:
                continue
            dirs[controller] = parent / name
        if not dirs:
            return None
        group = cls(1, dirs)
        try:
            if "memory" in dirs:
                _write(dirs["memory"] / "memory.limit_in_bytes", str(limits.memory))
                if (dirs["memory"] / "memory.memsw.limit_in_bytes").exists():
                    _write(dirs["memory"] / "memory.memsw.limit_in_bytes", str(limits.memory))
            if "pids" in dirs:
                _write(dirs["pids"] / "pids.max", str(limits.pids))
        except OSError:
            group.remove()
            return None
        return group

    @classmethod
    def _sweep(cls, parent: Path, version: int) -> None:
        """Remove the cgroups that runs of processes that no longer exist left behind (killed with SIGKILL): tasks
        still in one (a tree still exiting, or one that outlived its owner) are killed first, as at a run's end."""
        try:
            entries = list(parent.iterdir())
        except OSError:
            return
        for entry in entries:
            m = re.fullmatch(rf"{cls.PREFIX}(\d+)-[0-9a-f]+", entry.name)
            if m and not pid_alive(int(m.group(1))):
                orphan = cls(version, {"memory": entry, "pids": entry})
                orphan.kill(grace=3.0, settle=0.0)
                orphan.remove()

    def enter(self) -> None:
        """Move the calling process into the cgroup (called in the child before it executes the command)."""
        pid = str(os.getpid())
        for folder in self.folders:
            _write(folder / "cgroup.procs", pid)

    def tasks(self) -> list[int]:
        pids = set()
        for folder in self.folders:
            try:
                pids.update(int(p) for p in (folder / "cgroup.procs").read_text().split())
            except (OSError, ValueError):
                pass
        return sorted(pids)

    def kill(self, grace: float = 5.0, settle: float = 2.0) -> int:
        """SIGKILL every task left in the cgroup until none is; how many were still running after ``settle``
        seconds (tasks already killed with their process group, or exiting, leave the cgroup within it: a
        process freeing a large address space takes a while, and counting it would be a false alarm)."""
        first = self.tasks()
        deadline = time.monotonic() + settle
        while first and time.monotonic() < deadline:
            time.sleep(0.02)
            first = self.tasks()
        if not first:
            return 0
        if self.version == 2 and (self.dirs["memory"] / "cgroup.kill").exists():
            try:
                _write(self.dirs["memory"] / "cgroup.kill", "1")
            except OSError:
                pass
        deadline = time.monotonic() + grace
        while time.monotonic() < deadline:
            left = self.tasks()
            if not left:
                break
            for pid in left:
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
            time.sleep(0.02)
        return len(first)

    def usage(self) -> dict[str, int]:
        """What the tree used and which limits it hit: ``oom_kills``, ``peak_memory`` (bytes), ``pids_refused``
        (forks refused at the task limit)."""
        out: dict[str, int] = {}
        mem, pids = self.dirs.get("memory"), self.dirs.get("pids")
        if mem is not None:
            if self.version == 2:
                values = {"oom_kills": _read_int(mem / "memory.events", "oom_kill"),
                          "peak_memory": _read_int(mem / "memory.peak")}
            else:
                values = {"oom_kills": _read_int(mem / "memory.oom_control", "oom_kill"),
                          "peak_memory": _read_int(mem / "memory.max_usage_in_bytes")}
                if values["oom_kills"] is None:  # kernels before 4.13: limit hits, not kills
                    values["oom_kills"] = _read_int(mem / "memory.failcnt")
            out.update({k: v for k, v in values.items() if v is not None})
        if pids is not None:
            refused = _read_int(pids / "pids.events", "max")
            if refused is not None:
                out["pids_refused"] = refused
        return out

    def remove(self) -> None:
        for folder in self.folders:
            for _ in range(100):
                try:
                    folder.rmdir()
                    break
                except FileNotFoundError:
                    break
                except OSError:
                    time.sleep(0.02)


# ----------------------------------------------------------------------------------------------- modes
def _is_root() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0


def setpriv_args() -> list[str]:
    """util-linux ``setpriv`` becoming the sandbox's unprivileged user with no capability and no_new_privs."""
    return [shutil.which("setpriv") or "setpriv", f"--reuid={SANDBOX_UID}", f"--regid={SANDBOX_GID}",
            "--clear-groups", "--inh-caps=-all", "--bounding-set=-all", "--no-new-privs", "--"]


@functools.cache
def available_modes() -> tuple[str, ...]:
    """The isolation modes this machine allows, strongest first (``none`` always)."""
    modes = []
    if _is_root() and shutil.which("bwrap") and shutil.which("setpriv") and _bwrap_works():
        modes.append("bwrap")
    if _is_root() and shutil.which("unshare"):
        modes.append("unshare")
    return tuple(modes + ["none"])


def best_mode() -> str:
    return available_modes()[0]


def isolation_available() -> bool:
    """True when a process can get its own namespaces here (``bwrap``, or the ``unshare`` fallback)."""
    return best_mode() != "none"


def _bwrap_works() -> bool:
    """Whether bubblewrap can build the sandbox here (a container may forbid namespaces)."""
    try:
        cmd = [*_bwrap_args(Path("/"), [], [], Limits(), probe=True), "/bin/true"]
        return subprocess.run(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, timeout=30).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


def _site_paths() -> list[Path]:
    """Folders our interpreter's site-packages reach: what ``.pth`` files add (editable installs, a plugin
    installed with -e) and the folders of packages linked in from elsewhere."""
    import site

    found: list[Path] = []
    dirs = [Path(p) for p in site.getsitepackages() if Path(p).is_dir()]
    for d in dirs:
        for entry in d.iterdir():  # packages linked in from another environment: that environment's folder
            if entry.is_symlink():
                try:
                    found.append(entry.resolve(strict=True).parent)
                except (OSError, RuntimeError):
                    pass
        for pth in d.glob("*.pth"):
            try:
                lines = pth.read_text(errors="replace").splitlines()
            except OSError:
                continue
            for line in lines:
                line = line.strip()
                if line.startswith("/") and Path(line).is_dir():
                    found.append(Path(line))
        for finder in d.glob("_editable_impl_*.py"):  # hatchling's editables: map_module('name', 'path')
            try:
                text = finder.read_text(errors="replace")
            except OSError:
                continue
            for path in re.findall(r"map_module\(\s*'[^']*'\s*,\s*'([^']+)'\s*\)", text):
                p = Path(path)
                found.append(p.parent if p.name == "__init__.py" else p)
        for finder in d.glob("__editable__*_finder.py"):  # setuptools' editable installs: MAPPING = {name: path}
            try:
                match = re.search(r"^MAPPING\s*(?::[^=\n]*)?=\s*(\{.*?\})\s*$", finder.read_text(errors="replace"),
                                  re.MULTILINE)
                mapping = ast.literal_eval(match.group(1)) if match else {}
            except (OSError, ValueError, SyntaxError):
                continue
            if isinstance(mapping, dict):
                found += [Path(v) for v in mapping.values() if isinstance(v, str) and v.startswith("/")]
    return found


def code_paths() -> tuple[Path, ...]:
    """What the sandboxed Python needs to read: the virtual environment, the Python installation it points
    into (the venv's ``python`` may be a link into ``/root/.pyenv``), nerfify-ns itself (a checkout when
    installed editable) and folders of ``.pth`` files and editable installs (read at each run: tests install and
    remove plugins while a process runs)."""
    import nerfify_ns

    paths = [Path(sys.prefix), Path(sys.base_prefix), Path(os.path.realpath(sys.executable)).parent.parent,
             Path(nerfify_ns.__file__).resolve().parent.parent, *_site_paths(), *_python_path()]
    return _existing(paths)


def _python_path() -> list[Path]:
    """The absolute folders of ``PYTHONPATH`` (which the sandbox passes on): packages installed there with
    ``pip install --target`` must be readable inside too."""
    return [Path(p) for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p.startswith("/")]


def gpu_devices() -> tuple[Path, ...]:
    """The GPU's device nodes (NVIDIA's ``/dev/nvidia*``: the cards, ``nvidiactl``, ``nvidia-uvm``, and the
    ``nvidia-caps`` folder), bound into the sandbox's otherwise minimal ``/dev`` so that a training run there
    reaches the GPU the way it would outside. None on a machine without one."""
    return tuple(sorted(Path("/dev").glob("nvidia*")))


def cache_paths() -> tuple[Path, ...]:
    """The built kernel and the LPIPS weights in our cache, and the weights torch's hub keeps (read-only in the
    sandbox; ``$NERFIFY_CACHE`` may change between runs, so not cached)."""
    cache = nerfify_cache_dir()
    return _existing([cache / "ext", cache / "lpips", torch_home() / "hub" / "checkpoints"])


def torch_home() -> Path:
    """Torch's own folder for downloaded weights (``torch.hub``'s rule: ``$TORCH_HOME``, else
    ``$XDG_CACHE_HOME/torch``, else ``~/.cache/torch``). The sandbox names it explicitly (its ``HOME`` and
    ``XDG_CACHE_HOME`` are its own): with CUDA our runtime leaves Nerfstudio's stock LPIPS in place, which loads
    torchvision's AlexNet from there and, offline, cannot fetch it."""
    if os.environ.get("TORCH_HOME"):
        return Path(os.environ["TORCH_HOME"]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "torch"


def _existing(paths: Iterable[Path]) -> tuple[Path, ...]:
    """The resolved folders of ``paths`` that exist, once each, never ``/``."""
    out: list[Path] = []
    for p in paths:
        try:
            p = p.resolve()
        except OSError:
            continue
        if p.is_dir() and p != Path("/") and p not in out:
            out.append(p)
    return tuple(out)


def _depth(p: Path) -> int:
    return len(p.parts)


def _bwrap_args(workdir: Path, readonly: Sequence[Path], extra_code: Sequence[Path], limits: Limits,
                probe: bool = False, supervise: bool = False) -> list[str]:
    """The bwrap command line up to and including ``setpriv ... --`` (``supervise``: the seccomp filter is
    installed before bwrap runs, by :func:`run_sandboxed`, not passed to it)."""
    args = [shutil.which("bwrap") or "bwrap", "--unshare-pid", "--unshare-net", "--unshare-ipc", "--unshare-uts",
            "--unshare-cgroup-try", "--hostname", host_name(), "--die-with-parent", "--new-session",
            "--cap-drop", "ALL", "--cap-add", "CAP_SETUID", "--cap-add", "CAP_SETGID", "--cap-add", "CAP_SETPCAP",
            "--ro-bind", "/usr", "/usr"]
    for name in ("bin", "sbin", "lib", "lib32", "lib64", "libx32"):
        p = Path("/") / name
        if p.is_symlink():
            args += ["--symlink", os.readlink(p), str(p)]
        elif p.is_dir():
            args += ["--ro-bind", str(p), str(p)]
    args += ["--proc", "/proc", "--dev", "/dev",
             "--perms", "1777", "--size", str(limits.tmp), "--tmpfs", "/dev/shm",
             "--perms", "1777", "--size", str(limits.tmp), "--tmpfs", "/tmp"]
    if not probe:
        for node in gpu_devices():
            args += ["--dev-bind-try", str(node), str(node)]
    binds = [(Path("/etc") / name, "--ro-bind") for name in ETC_FILES if (Path("/etc") / name).exists()]
    if Path("/sys/devices/system/cpu").is_dir():
        binds.append((Path("/sys/devices/system/cpu"), "--ro-bind"))
    if not probe:
        binds += [(p, "--ro-bind-try") for p in (*code_paths(), *cache_paths(), *extra_code)]  # may vanish
        binds += [(p, "--ro-bind") for p in readonly]
        binds.append((workdir, "--bind"))
    # parents first, a writable bind after a read-only one of the same depth; bwrap would make missing
    # parent folders mode 0700 (unreadable to the sandbox's user), so they are made here, 0755
    seen, made, bound = set(), {Path("/tmp"), Path("/dev"), Path("/proc")}, {Path("/usr")}
    for path, flag in sorted(binds, key=lambda b: (_depth(b[0]), b[1] == "--bind")):
        if (path, flag == "--bind") in seen:
            continue
        seen.add((path, flag == "--bind"))
        for parent in reversed(path.parents[:-1]):
            if parent not in made and not any(b == parent or b in parent.parents for b in bound):
                args += ["--perms", "0755", "--dir", str(parent)]
                made.add(parent)
        args += [flag, str(path), str(path)]
        bound.add(path)
    if not probe:
        args += ["--chdir", str(workdir)]
    wrapper: list[str] = []
    bpf = None if supervise else _seccomp_file()
    if bpf is not None:  # bwrap reads the filter from a file descriptor: the shell opens it as fd 3
        wrapper = ["/bin/sh", "-c", 'exec "$@" 3<"$0"', bpf]
        args += ["--seccomp", "3"]
    args += ["--remount-ro", "/", "--"]
    return wrapper + args + setpriv_args()


# ----------------------------------------------------------------------------------------------- seccomp
def seccomp_filter() -> bytes | None:
    """The classic-BPF program for ``bwrap --seccomp`` where calls cannot be supervised
    (:func:`nerfify_ns.runtime.seccomp.kill_filter`): escape calls kill the process (SIGSYS), new user
    namespaces and other ABIs are refused; None on a machine it does not know."""
    return kill_filter()


def supervised() -> bool:
    """Whether the sandbox's escape calls, connects and writes are decided and recorded by a supervisor thread
    of ours (seccomp user notification) rather than only killed by ``bwrap --seccomp``."""
    return os.environ.get("NERFIFY_SECCOMP", "supervise") != "kill" and notify_supported()


@functools.cache
def _seccomp_file() -> str | None:
    """The filter written once per process to a private file of ours (never into a sandbox's folder)."""
    import atexit
    import tempfile

    program = seccomp_filter()
    if program is None:
        return None
    folder = tempfile.mkdtemp(prefix="nerfify-seccomp-")
    path = os.path.join(folder, "filter.bpf")
    with open(path, "wb") as f:
        f.write(program)
    atexit.register(shutil.rmtree, folder, True)
    return path


# Runs inside the new mount namespace of the unshare fallback before the command: everything read-only but $1.
_UNSHARE_INNER = (
    'set -e; W="$1"; shift; mount --make-rprivate /; mount --bind "$W" "$W"; '
    "mount -o remount,bind,ro /; mount -t tmpfs -o size=2g tmpfs /dev/shm; "
    'mount -o remount,bind,rw "$W"; cd "$W"; exec "$@"'
)


def unshare_prefix(workdir: Path) -> list[str]:
    """The weaker fallback's prefix: no network, a read-only root but ``workdir``; still root, with capabilities."""
    return [shutil.which("unshare") or "unshare", "-n", "-m", "sh", "-c", _UNSHARE_INNER, "sh", str(workdir)]


# ----------------------------------------------------------------------------------------------- running
@dataclass
class SandboxResult(ProcessResult):
    """How the sandboxed command ended, which isolation it had, the limits and what the tree used."""

    isolation: list[str] = field(default_factory=list)
    """Tags of what held: the mode, then e.g. ``no-network``, ``read-only-fs``, ``cgroup-memory``..."""
    mode: str = "none"
    limits: dict[str, object] = field(default_factory=dict)
    usage: dict[str, int] = field(default_factory=dict)
    """``oom_kills``, ``peak_memory``, ``pids_refused`` (from the cgroup) and ``left_running`` (tasks still in
    the cgroup when the command had ended, killed then)."""
    attempts: list[dict[str, object]] = field(default_factory=list)
    """What the sandboxed code tried that the seccomp supervisor stopped (call, detail, action, pid), recorded
    in our process; empty without supervision."""

    def attempt_sentences(self) -> list[str]:
        """One sentence per escape attempt (the call named), or for a process the kill filter stopped."""
        from nerfify_ns.runtime.seccomp import Attempt

        found = [Attempt(**a).sentence() for a in self.attempts]
        if not self.attempts and self.mode == "bwrap" and self.returncode == 128 + signal.SIGSYS:
            found.append("plugin code made a system call the sandbox forbids (only an escape attempt needs it): "
                         "the seccomp filter killed the process (SIGSYS)")
        return found

    def tail(self, lines: int = 30, max_bytes: int = 64 << 10) -> str:
        """The last ``lines`` lines of the log, read from at most its last ``max_bytes`` bytes, with control
        characters escaped (the log is written by untrusted code)."""
        try:
            with open(self.log_path, "rb") as f:
                f.seek(0, os.SEEK_END)
                size = f.tell()
                f.seek(max(0, size - max_bytes))
                data = f.read(max_bytes)
        except OSError:
            return ""
        text = data.decode("utf-8", errors="replace")
        return clean("\n".join(text.splitlines()[-lines:]), limit=max(4000, lines * 200), keep="tail")

    def limit_hits(self, left_running: bool = True) -> list[str]:
        """Sentences naming the limits the process tree ran into (empty when none); with ``left_running``, also
        the processes still running when the command had ended (for a command that should leave none)."""
        found = []
        if self.usage.get("oom_kills"):
            found.append(f"the process tree reached its memory limit ({_size(self.limits.get('memory'))}); the "
                         f"kernel killed {self.usage['oom_kills']} process(es)")
        if self.usage.get("pids_refused"):
            found.append(f"the process tree reached its limit of {self.limits.get('pids')} processes and threads; "
                         f"{self.usage['pids_refused']} fork(s) refused")
        if left_running and self.usage.get("left_running"):
            found.append(f"{self.usage['left_running']} process(es) were still running when the command ended "
                         "(killed)")
        return found


def _size(n: object) -> str:
    if not isinstance(n, int):
        return "?"
    return f"{n / GiB:.3g} GiB" if n >= GiB else f"{n / (1 << 20):.3g} MiB"


def _user_name() -> str:
    """Our user's name (from the password database when the environment does not say)."""
    try:
        import pwd

        return pwd.getpwuid(os.getuid()).pw_name
    except (ImportError, KeyError, OSError):
        return "user"


def host_name() -> str:
    """Our host's name, which the sandbox's own UTS namespace repeats: plugin code cannot tell the sandbox from
    the user's machine by its host name."""
    name = os.uname().nodename
    return name if re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9.-]{0,62}", name or "") else "localhost"


def sandbox_env(workdir: Path, extra: Mapping[str, str] | None = None, mode: str = "none") -> dict[str, str]:
    """The command's environment: the allowed part of ours (:data:`ENV_KEEP`), temporary files, caches and
    ``HOME`` inside ``workdir``, bytecode off, our cache named explicitly, then ``extra``. Nothing in it says
    "sandbox": the user and log name are ours (the uid is not), and no variable names the isolation (the probe
    finds its own PID namespace by itself)."""
    tmp = workdir / ".tmp"
    home = tmp / "home"
    home.mkdir(parents=True, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if ENV_KEEP.match(k)}
    env.setdefault("PATH", "/usr/local/bin:/usr/bin:/bin")
    env["PATH"] = f"{Path(sys.executable).parent}:{env['PATH']}"
    env.update({
        "HOME": str(home),
        "TMPDIR": str(tmp),
        "MPLCONFIGDIR": str(tmp / "mpl"),
        "XDG_CACHE_HOME": str(tmp / "cache"),
        "PYTHONDONTWRITEBYTECODE": "1",
        "PYTHONWARNINGS": "ignore",
        ENV_CACHE: str(nerfify_cache_dir()),
        "TORCH_HOME": str(torch_home()),
    })
    for key in ("USER", "LOGNAME"):  # what getpass.getuser() reads first: our name, not the sandbox's user
        env[key] = os.environ.get(key) or _user_name()
    env.pop("NERFIFY_SANDBOX", None)
    env.update(extra or {})
    return env


_PR_SET_PDEATHSIG = 1


def _death_signal():
    """libc's ``prctl`` bound in the parent (the child of a fork must not load libraries), or None off Linux."""
    try:
        import ctypes

        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def _preexec(group: TreeCgroup | None, rlimits: Sequence[tuple[int, int]],
             installer: Installer | None = None):
    """Run in the child before it executes the sandbox: SIGKILL when we die (bubblewrap's --die-with-parent is set
    only once it runs; a parent killed in between would leave the sandbox orphaned), stdin from /dev/null, join
    the cgroup, set rlimits."""
    parent, prctl = os.getpid(), _death_signal()

    def apply() -> None:
        if prctl is not None:
            prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
            if os.getppid() != parent:  # killed before the death signal was armed
                os._exit(137)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
        if group is not None:
            group.enter()
        for which, value in rlimits:
            resource.setrlimit(which, (value, value))
        if installer is not None:  # last: from here on every escape call of the tree goes to our supervisor
            installer.install()

    return apply


def _chown_tree(root: Path, uid: int, gid: int) -> None:
    """``lchown`` ``root`` and everything below it (links are not followed)."""
    try:
        os.lchown(root, uid, gid)
    except OSError:
        return
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            try:
                os.lchown(os.path.join(folder, name), uid, gid)
            except OSError:
                pass


def _check_readable(path: Path) -> None:
    """The sandbox's user reads ``path`` as 'other': its folder must be readable and searchable by others."""
    st = path.stat()
    need = 0o005 if path.is_dir() else 0o004
    if st.st_mode & need != need:
        raise SandboxError(f"{path} is not readable by other users (mode {st.st_mode & 0o777:o}): the sandbox "
                           f"runs the plugin as an unprivileged user (uid {SANDBOX_UID}), which cannot read it; "
                           f"chmod o+rX it")


def run_sandboxed(
    cmd: Sequence[str],
    workdir: Path,
    *,
    timeout: float,
    log_name: str = "run.log",
    memory: int | None = None,
    env: Mapping[str, str] | None = None,
    isolate: bool = True,
    poll: Poll | None = None,
    readonly: Iterable[Path] = (),
    limits: Limits | None = None,
    mode: str | None = None,
    pass_fds: Sequence[int] = (),
) -> SandboxResult:
    """Run ``cmd`` in the sandbox with its working directory ``workdir`` (created; the only writable place),
    ``readonly`` folders visible, output to ``workdir/log_name``, under ``limits`` (``memory`` overrides
    theirs) and the ``timeout``; ``poll`` is called about every second while it runs. ``mode`` forces an
    isolation mode (default the strongest available; ``isolate=False`` is ``none``). ``pass_fds`` stay open in
    the command (a pipe our process reads what it reports from)."""
    limits = limits or Limits()
    if memory:
        limits = dataclasses.replace(limits, memory=memory)
    mode = mode or (best_mode() if isolate else "none")
    if mode not in available_modes():
        raise SandboxError(f"isolation mode {mode!r} is not available here (available: {', '.join(available_modes())})")
    workdir = Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    readonly = [Path(p).resolve() for p in readonly]
    for p in readonly:
        if not p.exists():
            raise SandboxError(f"{p} does not exist")
        if mode == "bwrap":
            _check_readable(p)
    full_env = sandbox_env(workdir, env, mode)
    group = TreeCgroup.create(limits) if limits.cgroups else None
    memory_cgroup = group is not None and "memory" in group.dirs
    pids_cgroup = group is not None and "pids" in group.dirs
    rlimits = [(resource.RLIMIT_NOFILE, limits.files), (resource.RLIMIT_CORE, 0),
               (resource.RLIMIT_FSIZE, limits.file_size)]
    gpus = gpu_devices() if mode != "none" else ()
    # CUDA reserves address space far beyond the memory it uses: an address-space limit stops it starting
    address_limit = not memory_cgroup and not gpus
    if address_limit:
        rlimits.append((resource.RLIMIT_AS, limits.memory))
    if not pids_cgroup and mode == "bwrap":
        rlimits.append((resource.RLIMIT_NPROC, limits.pids))
    isolation = [mode]
    supervisor: Supervisor | None = None
    if mode == "bwrap":
        supervise = supervised()
        prefix = _bwrap_args(workdir, readonly, [], limits, supervise=supervise)
        isolation += [f"uid-{SANDBOX_UID}", "no-capabilities", "no-new-privs", "no-network", "read-only-fs",
                      "pid-namespace", "ipc-namespace", "private-tmp"]
        if supervise:
            supervisor = Supervisor(str(workdir), installer=Installer(notify_filter()),
                                    devices=[str(node) for node in gpus])
            isolation += ["seccomp-no-userns", "seccomp-supervised"]
        elif _seccomp_file() is not None:
            isolation += ["seccomp-no-userns", "seccomp-kill"]
    elif mode == "unshare":
        prefix = unshare_prefix(workdir)
        isolation += ["root-with-capabilities", "no-network", "read-only-fs"]
    else:
        prefix = []
    isolation += ["cgroup-memory" if memory_cgroup else "rlimit-as" if address_limit else "no-memory-limit"]
    if gpus:
        isolation += ["gpu-devices"]
    isolation += ["cgroup-pids" if pids_cgroup else "rlimit-nproc" if mode == "bwrap" else "no-pids-limit"]
    isolation += ["rlimit-nofile", "timeout"]
    applied = {"memory": limits.memory if memory_cgroup or address_limit else None,
               "memory_scope": "tree" if memory_cgroup else "process" if address_limit else None,
               "pids": limits.pids if (pids_cgroup or mode == "bwrap") else None,
               "pids_scope": "tree" if pids_cgroup else "user" if mode == "bwrap" else None,
               "files": limits.files, "timeout_s": timeout,
               "cgroup": f"v{group.version}" if group is not None else None}
    usage: dict[str, int] = {}
    owner, folder_mode = (os.getuid(), os.getgid()), workdir.stat().st_mode & 0o7777
    if mode == "bwrap":  # the sandbox's user owns its folder while it runs; bwrap (root, no capability) enters it
        _chown_tree(workdir, SANDBOX_UID, SANDBOX_GID)
        os.chmod(workdir, folder_mode | 0o711)
    attempts: list[dict[str, object]] = []
    try:
        if supervisor is not None:
            supervisor.start()
        result = run_process([*prefix, *cmd], workdir / log_name, cwd=workdir, timeout=timeout, env=full_env,
                             preexec_fn=_preexec(group, rlimits, supervisor and supervisor.installer), poll=poll,
                             pass_fds=pass_fds)
    finally:
        if supervisor is not None:
            attempts = [a.to_dict() for a in supervisor.stop()]
        if group is not None:
            left = group.kill()
            usage.update(group.usage())
            if left:
                usage["left_running"] = left
            group.remove()
        if mode == "bwrap":
            _chown_tree(workdir, *owner)
            os.chmod(workdir, folder_mode)
    base = {f.name: getattr(result, f.name) for f in dataclasses.fields(ProcessResult)}
    return SandboxResult(**base, isolation=isolation, mode=mode, limits=applied, usage=usage, attempts=attempts)


def python_cmd(module: str, *args: str) -> list[str]:
    """``python -m module args`` with our interpreter."""
    return [sys.executable, "-m", module, *args]
