"""Seccomp for the sandbox: which system calls plugin code may make, and a record of what it tried.

Two programs, both classic BPF assembled here with :mod:`struct` (no dependency):

* :func:`notify_filter` (the default where the kernel has ``SECCOMP_RET_USER_NOTIF``, Linux 5.5+): installed by
  the child we fork before it executes bubblewrap, with ``SECCOMP_FILTER_FLAG_NEW_LISTENER``. Every call in
  :data:`ESCAPE_CALLS` (and ``clone`` with a namespace flag, ``socket`` for netlink, packet or raw sockets,
  ``connect``, and opens that can write) stops the calling thread and is decided by a :class:`Supervisor`
  thread of OUR process, which the sandboxed code cannot reach: calls of root (bubblewrap building the
  sandbox) continue; the same calls of the sandbox's unprivileged user are escape attempts, recorded with
  their name and the process is killed with SIGKILL. A ``connect`` to anything but a unix socket fails with
  ``ENETUNREACH`` and is recorded with its address; an open for writing outside the run folder (and
  ``/tmp``, ``/dev/shm``, ``/dev/null``) into a folder that exists in the sandbox goes on to the kernel, which
  refuses it (read-only file system, permissions), and is recorded with its path (a library writing its
  cache into a folder the sandbox does not have, ``/var/cache``, is not recorded). The record lives in our process:
  what the plugin prints or writes cannot change it.
* :func:`kill_filter` (the fallback, passed to ``bwrap --seccomp``): the same calls kill the process with
  ``SECCOMP_RET_KILL_PROCESS`` (SIGSYS, which bubblewrap reports as exit 159): the rung fails saying that a
  forbidden call killed it, without its name.

Both refuse system calls of another ABI (32-bit, x32) and ``clone3`` (``ENOSYS``: its flags live in memory a
filter cannot read; the C library falls back to ``clone``, whose flags it can).
"""

from __future__ import annotations

import ctypes
import errno
import os
import platform
import signal
import socket
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass

ESCAPE_CALLS = ("mount", "umount2", "pivot_root", "setns", "unshare", "ptrace", "bpf", "keyctl", "add_key",
                "request_key", "init_module", "finit_module", "delete_module", "reboot", "kexec_load",
                "kexec_file_load", "open_tree", "move_mount", "fsopen", "fsconfig", "fsmount", "fspick",
                "mount_setattr", "process_vm_writev")
"""Calls a NeRF plugin never needs: only an escape attempt makes them (the process is killed, the call named)."""

# machine -> (AUDIT_ARCH, x32 bit or 0, syscall numbers)
_ARCH: dict[str, tuple[int, int, dict[str, int]]] = {
    "x86_64": (0xC000003E, 0x40000000, {
        "mount": 165, "umount2": 166, "pivot_root": 155, "setns": 308, "unshare": 272, "ptrace": 101, "bpf": 321,
        "keyctl": 250, "add_key": 248, "request_key": 249, "init_module": 175, "finit_module": 313,
        "delete_module": 176, "reboot": 169, "kexec_load": 246, "kexec_file_load": 320, "open_tree": 428,
        "move_mount": 429, "fsopen": 430, "fsconfig": 431, "fsmount": 432, "fspick": 433, "mount_setattr": 442,
        "process_vm_writev": 311, "socket": 41, "connect": 42, "clone": 56, "clone3": 435, "open": 2,
        "openat": 257, "creat": 85, "openat2": 437, "seccomp": 317}),
    "aarch64": (0xC00000B7, 0, {
        "mount": 40, "umount2": 39, "pivot_root": 41, "setns": 268, "unshare": 97, "ptrace": 117, "bpf": 280,
        "keyctl": 219, "add_key": 217, "request_key": 218, "init_module": 105, "finit_module": 273,
        "delete_module": 106, "reboot": 142, "kexec_load": 104, "kexec_file_load": 294, "open_tree": 428,
        "move_mount": 429, "fsopen": 430, "fsconfig": 431, "fsmount": 432, "fspick": 433, "mount_setattr": 442,
        "process_vm_writev": 271, "socket": 198, "connect": 203, "clone": 220, "clone3": 435, "openat": 56,
        "openat2": 437, "seccomp": 277}),
}
_CLONE_NAMESPACES = 0x10000000 | 0x00020000 | 0x20000000 | 0x40000000 | 0x08000000 | 0x04000000 | 0x02000000 | 0x80
"""CLONE_NEWUSER, NEWNS, NEWPID, NEWNET, NEWIPC, NEWUTS, NEWCGROUP, NEWTIME."""
_WRITE_FLAGS = 0o1 | 0o2 | 0o100 | 0o1000 | 0o2000
"""O_WRONLY, O_RDWR, O_CREAT, O_TRUNC, O_APPEND."""
AF_NETLINK, AF_PACKET, SOCK_RAW = 16, 17, 3
_DOMAINS = {2: "AF_INET", 10: "AF_INET6", AF_NETLINK: "AF_NETLINK", AF_PACKET: "AF_PACKET"}

RET_KILL_PROCESS = 0x80000000
RET_ERRNO = 0x00050000
RET_USER_NOTIF = 0x7FC00000
RET_ALLOW = 0x7FFF0000
_LD, _JEQ, _JGE, _JSET, _AND, _RET = 0x20, 0x15, 0x35, 0x45, 0x54, 0x06

WRITABLE = ("/tmp", "/dev/shm", "/dev/null", "/proc/self", "/proc/thread-self")
"""Where plugin code may open files for writing besides its run folder (private tmpfs, the null device)."""


def arch() -> tuple[int, int, dict[str, int]] | None:
    return _ARCH.get(platform.machine())


def _assemble(prog: Sequence[tuple]) -> bytes:
    """(op, jt, jf, k) instructions, jump targets given as labels (``("name",)`` marks a label)."""
    labels, code = {}, []
    for op in prog:
        if len(op) == 1:
            labels[op[0]] = len(code)
        else:
            code.append(op)
    out = b""
    for i, (op, jt, jf, k) in enumerate(code):
        jt = labels[jt] - i - 1 if isinstance(jt, str) else jt
        jf = labels[jf] - i - 1 if isinstance(jf, str) else jf
        assert 0 <= jt < 256 and 0 <= jf < 256
        out += struct.pack("<HBBI", op, jt, jf, k)
    return out


def _program(action: int, watch: bool) -> bytes | None:
    """The filter: escape calls (and namespace clones, netlink/packet/raw sockets) get ``action``; with
    ``watch`` (the supervised filter) connects and write-opens are also sent to the supervisor."""
    spec = arch()
    if spec is None:
        return None
    audit, x32, nr = spec
    eperm, enosys = RET_ERRNO | errno.EPERM, RET_ERRNO | errno.ENOSYS
    prog: list[tuple] = [(_LD, 0, 0, 4), (_JEQ, 1, 0, audit), (_RET, 0, 0, eperm), (_LD, 0, 0, 0)]
    if x32:
        prog.append((_JGE, "eperm", 0, x32))
    prog += [(_JEQ, "act", 0, nr[name]) for name in ESCAPE_CALLS]
    prog += [(_JEQ, "socket", 0, nr["socket"]), (_JEQ, "clone", 0, nr["clone"]), (_JEQ, "enosys", 0, nr["clone3"])]
    if watch:
        prog += [(_JEQ, "notify", 0, nr["connect"]), (_JEQ, "flags2", 0, nr["openat"]),
                 (_JEQ, "notify", 0, nr["openat2"])]
        if "open" in nr:
            prog += [(_JEQ, "flags1", 0, nr["open"]), (_JEQ, "notify", 0, nr["creat"])]
    prog += [(_RET, 0, 0, RET_ALLOW),
             ("socket",), (_LD, 0, 0, 16), (_JEQ, "act", 0, AF_NETLINK), (_JEQ, "act", 0, AF_PACKET),
             (_LD, 0, 0, 24), (_AND, 0, 0, 0xF), (_JEQ, "act", 0, SOCK_RAW), (_RET, 0, 0, RET_ALLOW),
             ("clone",), (_LD, 0, 0, 16), (_JSET, "act", 0, _CLONE_NAMESPACES), (_RET, 0, 0, RET_ALLOW)]
    if watch:
        prog += [("flags2",), (_LD, 0, 0, 32), (_JSET, "notify", 0, _WRITE_FLAGS), (_RET, 0, 0, RET_ALLOW),
                 ("flags1",), (_LD, 0, 0, 24), (_JSET, "notify", 0, _WRITE_FLAGS), (_RET, 0, 0, RET_ALLOW),
                 ("notify",), (_RET, 0, 0, RET_USER_NOTIF)]
    prog += [("act",), (_RET, 0, 0, action), ("eperm",), (_RET, 0, 0, eperm), ("enosys",), (_RET, 0, 0, enosys)]
    return _assemble(prog)


def kill_filter() -> bytes | None:
    """The fallback program for ``bwrap --seccomp``: escape calls kill the process (SIGSYS)."""
    return _program(RET_KILL_PROCESS, watch=False)


def notify_filter() -> bytes | None:
    """The supervised program: escape calls, connects and write-opens go to the :class:`Supervisor`."""
    return _program(RET_USER_NOTIF, watch=True)


# ----------------------------------------------------------------------------------------------- installing
_SECCOMP_SET_MODE_FILTER, _FLAG_NEW_LISTENER = 1, 8
_NOTIF_RECV, _NOTIF_SEND, _NOTIF_ID_VALID = 0xC0502100, 0xC0182101, 0x40082102
_FLAG_CONTINUE = 1


class _Fprog(ctypes.Structure):
    _fields_ = [("len", ctypes.c_ushort), ("filter", ctypes.c_void_p)]


class Installer:
    """Everything the forked child needs, prepared in the parent (a child of a threaded process should
    allocate little): the program, libc's ``syscall`` and the socket the listener is sent back on."""

    def __init__(self, program: bytes) -> None:
        self.buffer = ctypes.create_string_buffer(program, len(program))
        self.fprog = _Fprog(len(program) // 8, ctypes.cast(self.buffer, ctypes.c_void_p))
        self.syscall = ctypes.CDLL(None, use_errno=True).syscall
        self.nr = arch()[2]["seccomp"]
        self.parent, self.child = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)

    def install(self) -> None:
        """In the child: install the filter and send its listener to the parent (raises when it cannot)."""
        fd = self.syscall(self.nr, _SECCOMP_SET_MODE_FILTER, _FLAG_NEW_LISTENER, ctypes.byref(self.fprog))
        if fd < 0:
            raise OSError(ctypes.get_errno(), "seccomp user notification")
        socket.send_fds(self.child, [b"L"], [fd])
        os.close(fd)

    def listener(self, timeout: float = 30.0) -> int | None:
        """In the parent: the listener the child sent (None when it sent none, or :meth:`close` was called)."""
        self.parent.settimeout(timeout)
        try:
            _, fds, _, _ = socket.recv_fds(self.parent, 1, 1)
        except OSError:
            return None
        return fds[0] if fds else None

    def close(self) -> None:
        for s in (self.parent, self.child):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()


_SUPPORTED: bool | None = None


def supervised_available() -> bool:
    """Whether the sandbox supervises calls here (kernel support, not switched off by ``NERFIFY_SECCOMP=kill``)."""
    return os.environ.get("NERFIFY_SECCOMP", "supervise") != "kill" and notify_supported()


def notify_supported() -> bool:
    """Whether this kernel lets us supervise the sandbox's calls (checked once, in a throwaway child)."""
    global _SUPPORTED
    if _SUPPORTED is None:
        import subprocess

        program = notify_filter()
        _SUPPORTED = False
        if program is not None:
            inst = Installer(program)
            try:
                proc = subprocess.Popen(["/bin/true"], preexec_fn=inst.install, stdin=subprocess.DEVNULL,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                fd = inst.listener(timeout=10)
                _SUPPORTED = proc.wait(timeout=30) == 0 and fd is not None
                if fd is not None:
                    os.close(fd)
            except (OSError, subprocess.SubprocessError):
                _SUPPORTED = False
            finally:
                inst.close()
    return _SUPPORTED


# ----------------------------------------------------------------------------------------------- supervising
@dataclass
class Attempt:
    """One thing the sandboxed code tried: the call, what it named, and what happened."""

    call: str
    detail: str
    action: str  # "killed" (SIGKILL) or "refused"
    pid: int

    def to_dict(self) -> dict:
        return {"call": self.call, "detail": self.detail, "action": self.action, "pid": self.pid}

    def sentence(self) -> str:
        what = f"{self.call}({self.detail})" if self.detail else f"{self.call}()"
        if self.action == "killed":
            return (f"plugin code called {what}, which only an escape attempt needs: the sandbox killed the "
                    f"process (SIGKILL)")
        return f"plugin code tried {what}: refused by the sandbox"


def _uid(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("Uid:"):
                    return int(line.split()[2])  # effective uid
    except (OSError, ValueError, IndexError):
        return None
    return None


class Supervisor:
    """A thread of our process answering the sandbox's supervised calls and recording the attempts."""

    MAX_ATTEMPTS = 200

    def __init__(self, workdir: str, listener: int | None = None,
                 installer: Installer | None = None, devices: Sequence[str] = ()) -> None:
        self.fd = listener
        self.installer = installer
        self.workdir = os.path.normpath(workdir)
        self.devices = tuple(os.path.normpath(d) for d in devices)  # device nodes bound in to be used (a GPU)
        self.attempts: list[Attempt] = []
        self.dropped = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="seccomp-supervisor", daemon=True)
        spec = arch()
        self.names = {v: k for k, v in (spec[2] if spec else {}).items()}

    def start(self) -> Supervisor:
        self._thread.start()
        return self

    def stop(self) -> list[Attempt]:
        self._stop.set()
        if self.installer is not None:
            self.installer.close()  # wakes a thread still waiting for the listener (the child never sent it)
        if self._thread.is_alive() or self._thread.ident is not None:
            self._thread.join(timeout=40)
        if self.fd is not None:
            try:
                os.close(self.fd)
            except OSError:
                pass
        return self.attempts

    def _loop(self) -> None:
        import select

        if self.fd is None and self.installer is not None:
            self.fd = self.installer.listener()
        if self.fd is None:
            return
        poller = select.poll()
        poller.register(self.fd, select.POLLIN)
        while not self._stop.is_set():
            events = poller.poll(100)
            if not events:
                continue
            if any(ev & (select.POLLHUP | select.POLLERR) and not ev & select.POLLIN for _, ev in events):
                return  # every task under the filter has exited
            buf = bytearray(80)
            try:
                import fcntl

                fcntl.ioctl(self.fd, _NOTIF_RECV, buf, True)
            except OSError:
                continue  # the task died before we read it
            try:
                self._answer(buf)
            except Exception:  # noqa: BLE001 - never leave the sandboxed task waiting
                self._respond(struct.unpack_from("<Q", buf)[0], 0, errno.EPERM, 0)

    def _respond(self, nid: int, val: int, error: int, flags: int) -> None:
        import fcntl

        try:
            fcntl.ioctl(self.fd, _NOTIF_SEND, bytearray(struct.pack("<QqiI", nid, val, -error if error else 0,
                                                                    flags)))
        except OSError:
            pass

    def _record(self, attempt: Attempt) -> None:
        if len(self.attempts) < self.MAX_ATTEMPTS:
            self.attempts.append(attempt)
        else:
            self.dropped += 1

    def _answer(self, buf: bytearray) -> None:
        nid, pid, _flags, nr, _arch, _ip = struct.unpack_from("<QIIiIQ", buf)
        args = struct.unpack_from("<6Q", buf, 32)
        name = self.names.get(nr, f"syscall {nr}")
        if _uid(pid) == 0:  # bubblewrap (root) building the sandbox
            self._respond(nid, 0, 0, _FLAG_CONTINUE)
            return
        if name == "connect":
            family, detail = self._sockaddr(pid, args[1], args[2])
            if family == socket.AF_UNIX:
                self._respond(nid, 0, 0, _FLAG_CONTINUE)
                return
            self._record(Attempt("connect", detail, "refused", pid))
            self._respond(nid, 0, errno.ENETUNREACH, 0)
            return
        if name in ("open", "openat", "creat", "openat2"):
            path = self._open_path(pid, name, args)
            if path is not None and not self._writable(path) and self._visible(pid, path):
                self._record(Attempt(name, f"{path!r}, for writing", "refused", pid))
            self._respond(nid, 0, 0, _FLAG_CONTINUE)  # the read-only file system refuses what is outside
            return
        detail = self._detail(name, args)
        self._record(Attempt(name, detail, "killed", pid))
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
        self._respond(nid, 0, errno.EPERM, 0)

    @staticmethod
    def _detail(name: str, args: tuple) -> str:
        if name == "socket":
            domain, kind = args[0] & 0xFFFFFFFF, args[1] & 0xF
            return f"{_DOMAINS.get(domain, domain)}, {'SOCK_RAW' if kind == SOCK_RAW else kind}"
        if name in ("clone", "unshare"):
            return f"flags {args[0] & 0xFFFFFFFF:#x}"
        return ""

    def _read(self, pid: int, address: int, size: int) -> bytes:
        try:
            with open(f"/proc/{pid}/mem", "rb", buffering=0) as f:
                f.seek(address)
                return f.read(size)
        except (OSError, ValueError, OverflowError):
            return b""

    def _sockaddr(self, pid: int, address: int, length: int) -> tuple[int, str]:
        data = self._read(pid, address, min(int(length), 128))
        if len(data) < 2:
            return -1, "?"
        family = struct.unpack_from("<H", data)[0]
        if family == socket.AF_INET and len(data) >= 8:
            port = struct.unpack_from(">H", data, 2)[0]
            return family, f"{socket.inet_ntop(socket.AF_INET, data[4:8])}:{port}"
        if family == socket.AF_INET6 and len(data) >= 24:
            port = struct.unpack_from(">H", data, 2)[0]
            return family, f"[{socket.inet_ntop(socket.AF_INET6, data[8:24])}]:{port}"
        return family, f"address family {family}"

    def _open_path(self, pid: int, name: str, args: tuple) -> str | None:
        address = args[1] if name in ("openat", "openat2") else args[0]
        raw = self._read(pid, address, 4096)
        raw = raw.split(b"\0", 1)[0]
        if not raw:
            return None
        path = raw.decode("utf-8", errors="replace")
        if not path.startswith("/"):
            dirfd = ctypes.c_int32(args[0] & 0xFFFFFFFF).value if name in ("openat", "openat2") else -100
            where = f"/proc/{pid}/cwd" if dirfd == -100 else f"/proc/{pid}/fd/{dirfd}"
            try:
                path = os.path.join(os.readlink(where), path)
            except OSError:
                return None
        return os.path.normpath(path)

    @staticmethod
    def _visible(pid: int, path: str) -> bool:
        """Whether the folder of ``path`` exists in the sandbox (seen through the process's own root): a write
        into a folder the sandbox does not have (a library's cache under ``/var``) fails and is no attempt on
        anything; one into ``/dev``, ``/etc``, ``/usr`` or a bound folder is."""
        return os.path.lexists(f"/proc/{pid}/root{os.path.dirname(path)}")

    def _writable(self, path: str) -> bool:
        return any(path == p or path.startswith(p + "/") for p in (self.workdir, *WRITABLE, *self.devices))
