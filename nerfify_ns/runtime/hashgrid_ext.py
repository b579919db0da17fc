"""The fused C++ CPU kernel of the hash encoding (``csrc/hashgrid_cpu.cpp``): build, load, autograd.

The kernel is compiled at setup time only::

    python -m nerfify_ns.runtime.hashgrid_ext build      # prints the built .so; non-zero exit on failure

into ``$NERFIFY_CACHE/ext/<torch version>/`` (default ``~/.cache/nerfify/ext/<torch version>/``).
:func:`load` only imports an already-built library and never compiles: it returns ``None`` when the
library is missing, was built from a different source or with different flags (a stamp file records
both), or fails to import; :mod:`nerfify_ns.runtime.hashgrid` then falls back to its torch path.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.machinery
import importlib.util
import os
import platform
import sys
import warnings
from pathlib import Path
from types import ModuleType

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

from nerfify_ns.runtime.paths import nerfify_cache_dir

EXT_NAME = "nerfify_hashgrid_cpu"
SOURCE = Path(__file__).resolve().parent / "csrc" / "hashgrid_cpu.cpp"
STAMP_SUFFIX = ".stamp"
BUILD_HINT = "python -m nerfify_ns.runtime.hashgrid_ext build"


def _cflags() -> list[str]:
    """Portable optimisation flags (the cache may be shared between machines of one architecture).

    ``-ffp-contract=off`` keeps ``p * s - floor(p * s)`` rounded exactly like the torch path.
    """
    flags = ["-O3", "-ffp-contract=off", "-fopenmp"]
    if platform.machine().lower() in ("x86_64", "amd64"):
        flags.insert(1, "-march=x86-64-v2")
    return flags


LDFLAGS = ("-fopenmp",)  # a tuple: cpp_extension.load appends to the lists it is given
LIB_EXT = ".pyd" if os.name == "nt" else ".so"  # as torch.utils.cpp_extension names it


def build_dir() -> Path:
    """Where the library is built and looked for: ``$NERFIFY_CACHE/ext/<torch version>``."""
    return nerfify_cache_dir() / "ext" / torch.__version__


def library_path() -> Path:
    """The file ``torch.utils.cpp_extension.load`` writes: ``<build_dir>/<name>.so``."""
    return build_dir() / f"{EXT_NAME}{LIB_EXT}"


def _fingerprint() -> str:
    """What the built library must match: the kernel source, the flags, torch and Python."""
    digest = hashlib.sha256(SOURCE.read_bytes())
    digest.update(repr((_cflags(), list(LDFLAGS), torch.__version__, sys.implementation.cache_tag)).encode())
    return digest.hexdigest()


_loaded: dict[str, ModuleType | None] = {}  # library path -> module (None: not loadable)
_warned: set = set()


def _warn_once(key: str, message: str) -> None:
    if key not in _warned:
        _warned.add(key)
        warnings.warn(message, RuntimeWarning, stacklevel=3)


def build(verbose: bool = False) -> Path:
    """Compile the kernel into :func:`build_dir` (about a minute) and return the library's path."""
    from torch.utils import cpp_extension

    if not SOURCE.is_file():
        raise FileNotFoundError(f"kernel source missing: {SOURCE}")
    out_dir = build_dir()
    out_dir.mkdir(parents=True, exist_ok=True)
    # cpp_extension renames a second build of one name in one process to <name>_v1; start afresh so
    # the library keeps the fixed file and module name that load() imports.
    versioner = getattr(cpp_extension, "JIT_EXTENSION_VERSIONER", None)
    if versioner is not None and isinstance(getattr(versioner, "entries", None), dict):
        versioner.entries.pop(EXT_NAME, None)
    stamp = out_dir / f"{EXT_NAME}{STAMP_SUFFIX}"
    stamp.unlink(missing_ok=True)
    fingerprint = _fingerprint()  # before the build, which may touch the arguments it is given
    module = cpp_extension.load(name=EXT_NAME, sources=[str(SOURCE)], build_directory=str(out_dir),
                                extra_cflags=_cflags(), extra_ldflags=list(LDFLAGS), verbose=verbose)
    path = Path(module.__file__).resolve()
    if path != library_path().resolve():
        raise RuntimeError(f"built {path}, expected {library_path()}")
    stamp.write_text(fingerprint + "\n")
    _loaded.clear()
    return path


def load() -> ModuleType | None:
    """The built kernel module, or ``None`` if it is not built, stale, or fails to import. Never compiles."""
    path = library_path()
    key = str(path)
    if key in _loaded:
        return _loaded[key]
    module: ModuleType | None = None
    stamp = path.parent / f"{EXT_NAME}{STAMP_SUFFIX}"
    if path.is_file():
        try:
            fresh = stamp.is_file() and stamp.read_text().strip() == _fingerprint()
        except OSError:
            fresh = False
        if not fresh:
            _warn_once(key, f"hash-grid kernel at {path} is stale or unstamped; using the torch path "
                            f"(rebuild with '{BUILD_HINT}')")
        else:
            try:
                loader = importlib.machinery.ExtensionFileLoader(EXT_NAME, str(path))
                spec = importlib.util.spec_from_file_location(EXT_NAME, str(path), loader=loader)
                assert spec is not None
                module = importlib.util.module_from_spec(spec)
                loader.exec_module(module)
            except Exception as err:  # noqa: BLE001 - any import failure means "use the torch path"
                module = None
                _warn_once(key, f"hash-grid kernel at {path} failed to load ({err}); using the torch path")
    _loaded[key] = module
    return module


def require() -> ModuleType:
    """:func:`load`, raising a RuntimeError that says how to build when the kernel is unavailable."""
    module = load()
    if module is None:
        raise RuntimeError(f"the C++ hash-grid kernel is not available at {library_path()}; build it with "
                           f"'{BUILD_HINT}' (same NERFIFY_CACHE and torch {torch.__version__})")
    return module


class HashGridCppFunction(torch.autograd.Function):
    """Differentiable hash-grid lookup by the fused C++ kernel (CPU, float32/float64).

    ``apply(positions [N, 3], table [L * T, F], scalings [L], T) -> [N, L * F]``; same semantics and
    layout as :class:`nerfify_ns.runtime.hashgrid.HashGridFunction`. Backward recomputes corner rows
    and weights from the saved inputs (nothing of size ``[L, N, 8]`` is kept).
    """

    @staticmethod
    def forward(ctx, positions: Tensor, table: Tensor, scalings: Tensor,  # type: ignore[override]
                table_size: int):
        module = require()
        positions = positions.detach().contiguous()
        table_d = table.detach()
        scalings = scalings.detach().contiguous()
        ctx.table_size = table_size
        ctx.save_for_backward(positions, table_d, scalings)
        return module.forward(positions, table_d, scalings, table_size, bool(ctx.needs_input_grad[0]))

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        positions, table, scalings = ctx.saved_tensors
        need_pos, need_table = bool(ctx.needs_input_grad[0]), bool(ctx.needs_input_grad[1])
        grad_table, grad_pos = require().backward(grad_out.contiguous(), positions, table, scalings,
                                                  ctx.table_size, need_table, need_pos)
        return (grad_pos if need_pos else None), (grad_table if need_table else None), None, None


class HashGridReusedFunction(torch.autograd.Function):
    """The C++ hash-grid lookup of ``positions`` whose values were computed already: ``computed[rows]``,
    rows of an earlier no-gradient encoding of a superset of these positions with the same table (checked
    by the caller, :func:`nerfify_ns.runtime.hashgrid.hash_encode`). Backward is
    :class:`HashGridCppFunction`'s: the table (and position) gradients recomputed from the positions."""

    @staticmethod
    def forward(ctx, positions: Tensor, table: Tensor, scalings: Tensor,  # type: ignore[override]
                table_size: int, computed: Tensor, rows: Tensor):
        ctx.table_size = table_size
        ctx.save_for_backward(positions.detach().contiguous(), table.detach(), scalings.detach().contiguous())
        return computed.index_select(0, rows)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        return (*HashGridCppFunction.backward(ctx, grad_out), None, None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nerfify_ns.runtime.hashgrid_ext",
                                     description="Build or inspect the C++ hash-grid kernel.")
    sub = parser.add_subparsers(dest="command", required=True)
    p_build = sub.add_parser("build", help="compile the kernel into the cache and print the library path")
    p_build.add_argument("--verbose", action="store_true", help="show the compiler commands")
    sub.add_parser("status", help="print the library path if it is built and loads, else exit 1")
    args = parser.parse_args(argv)
    if args.command == "build":
        try:
            path = build(verbose=args.verbose)
        except Exception as err:  # noqa: BLE001 - report any build failure as a non-zero exit
            print(f"hash-grid kernel build failed: {err}", file=sys.stderr)
            return 1
        if load() is None:
            print(f"hash-grid kernel built at {path} but does not load", file=sys.stderr)
            return 1
        print(path)
        return 0
    module = load()
    if module is None:
        print(f"not available at {library_path()} (build with '{BUILD_HINT}')", file=sys.stderr)
        return 1
    print(library_path())
    return 0


if __name__ == "__main__":
    sys.exit(main())
