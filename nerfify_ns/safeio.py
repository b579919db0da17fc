"""Bounded reading of files we did not write ourselves, or that someone may have edited since: one home for it.

A leaf module (standard library, PyYAML; numpy only where an ``.npy`` header is read). Every reader checks what it
can *before* the expensive step: the file's size before reading it, the nesting depth and the number of nodes a
YAML document expands to (aliases counted as the nodes they stand for) while it is composed, the depth of JSON
while it is parsed, the width, height and size of an image from its header before any pixel is decoded, the
shape an ``.npy`` header claims against the bytes the file really holds. A file over a limit raises
:class:`ReadRefused` (a :class:`NerfifyError`: one line at the command line, exit 2), a file that does not parse
raises :class:`ReadRefused` too unless the caller asks for the parse error itself.

The limits are generous for every file nerfify-ns writes (plans, records, reports, suites, scripted answers are
kilobytes to a few megabytes) and small against the memory of a laptop; ``docs/hardening.md`` lists them and what
they do not promise.
"""

from __future__ import annotations

import json
import os
import stat
import struct
from pathlib import Path
from typing import Any, Union

import yaml
from yaml.events import AliasEvent

from nerfify_ns.errors import NerfifyError

MAX_TEXT = 16 << 20
"""Bytes of a text file (logs, markdown, code) read whole."""
MAX_JSON = 32 << 20
"""Bytes of a JSON file."""
MAX_YAML = 8 << 20
"""Bytes of a YAML file (PyYAML's pure-Python composer reads about 1 MB/s)."""
MAX_DEPTH = 64
"""Nesting depth of a JSON or YAML document (ours nest below 12)."""
MAX_NODES = 1_000_000
"""Nodes a YAML document may expand to, every alias counted as the nodes it stands for."""
MAX_IMAGE = 64 << 20
"""Bytes of an image file."""
MAX_PIXELS = 64 << 20
"""Pixels (width x height) an image header may declare."""

PathLike = Union[str, "os.PathLike[str]"]


class ReadRefused(NerfifyError):
    """A file is over a limit of this module, is not a regular file, or does not parse."""


class NotParsed(ReadRefused):
    """A file within the limits that does not parse (not JSON, not YAML, not UTF-8, not a PNG or JPEG): a damaged
    file rather than a hostile one; callers that show damaged files as such catch this one alone."""


def _show(path: PathLike) -> str:
    return str(path)


# ------------------------------------------------------------------------------------------ bytes and text


def read_bytes(path: PathLike, limit: int = MAX_TEXT, *, what: str | None = None,
               follow_links: bool = True) -> bytes:
    """The bytes of the regular file ``path`` when it holds at most ``limit`` of them; a file that grows while it
    is read is cut at ``limit + 1`` bytes and refused. ``follow_links=False`` refuses a symbolic link."""
    name = what or _show(path)
    flags = os.O_RDONLY | getattr(os, "O_CLOEXEC", 0) | (0 if follow_links else getattr(os, "O_NOFOLLOW", 0))
    flags |= getattr(os, "O_NONBLOCK", 0)  # a FIFO planted where a file belongs must not block the open
    try:
        fd = os.open(os.fspath(path), flags)
    except OSError as exc:
        if not follow_links and Path(path).is_symlink():
            raise ReadRefused(f"{name} is a symbolic link; it is not read") from None
        raise ReadRefused(f"{name}: cannot read it ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise ReadRefused(f"{name} is not a regular file")
        if info.st_size > limit:
            raise ReadRefused(f"{name} is {info.st_size} bytes, over the limit of {limit} bytes")
        chunks, total = [], 0
        while total <= limit:
            chunk = os.read(fd, min(1 << 20, limit + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > limit:
            raise ReadRefused(f"{name} grew over the limit of {limit} bytes while it was read")
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_text(path: PathLike, limit: int = MAX_TEXT, *, what: str | None = None,
              errors: str = "replace") -> str:
    """The text of ``path`` (UTF-8; undecodable bytes replaced unless ``errors='strict'``), at most ``limit`` bytes."""
    data = read_bytes(path, limit, what=what)
    try:
        return data.decode("utf-8", errors=errors)
    except UnicodeDecodeError as exc:
        raise NotParsed(f"{what or _show(path)} is not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def read_tail(path: PathLike, limit: int = 64 << 10) -> str:
    """The last ``limit`` bytes of the text file ``path`` (a log someone else wrote: however long it grew)."""
    with open(os.fspath(path), "rb") as f:
        f.seek(0, os.SEEK_END)
        size = f.tell()
        f.seek(max(0, size - limit))
        return f.read(limit).decode("utf-8", errors="replace")


# ------------------------------------------------------------------------------------------ JSON


def _depth_ok(value: Any, limit: int) -> bool:
    """Whether ``value`` nests at most ``limit`` deep (iterative: no recursion on hostile data)."""
    stack = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, dict):
            if depth > limit:
                return False
            stack.extend((v, depth + 1) for v in item.values())
        elif isinstance(item, list):
            if depth > limit:
                return False
            stack.extend((v, depth + 1) for v in item)
    return True


def parse_json(text: str | bytes, *, what: str = "the JSON", max_depth: int = MAX_DEPTH) -> Any:
    """``text`` as JSON, nested at most ``max_depth`` deep; :class:`ReadRefused` when it is not JSON or is
    deeper (the parser's own recursion limit stops a 10^5-deep document early; it is caught, not shown)."""
    try:
        value = json.loads(text)
    except RecursionError:
        raise ReadRefused(f"{what} nests deeper than {max_depth} levels; it is not read") from None
    except ValueError as exc:
        raise NotParsed(f"{what} is not valid JSON ({str(exc)[:160]})") from None
    if not _depth_ok(value, max_depth):
        raise ReadRefused(f"{what} nests deeper than {max_depth} levels; it is not read")
    return value


def load_json(path: PathLike, limit: int = MAX_JSON, *, what: str | None = None,
              max_depth: int = MAX_DEPTH) -> Any:
    """The JSON in ``path``, read within ``limit`` bytes and ``max_depth`` levels."""
    name = what or _show(path)
    return parse_json(read_bytes(path, limit, what=name), what=name, max_depth=max_depth)


# ------------------------------------------------------------------------------------------ YAML


class _YamlLimit(yaml.YAMLError):
    pass


def _bounded_loader(max_depth: int, max_nodes: int) -> type:
    """A SafeLoader that counts, while it composes, the depth and the nodes the document expands to."""

    class BoundedLoader(yaml.SafeLoader):
        def __init__(self, stream) -> None:
            super().__init__(stream)
            self._depth = 0
            self._nodes = 0
            self._weight: dict = {}

        def compose_node(self, parent, index):  # type: ignore[override]
            self._depth += 1
            try:
                if self._depth > max_depth:
                    raise _YamlLimit(f"nests deeper than {max_depth} levels")
                alias = self.check_event(AliasEvent)
                before = self._nodes
                node = super().compose_node(parent, index)
                if alias:
                    self._nodes += self._weight.get(id(node), 1)
                else:
                    self._nodes += 1
                    self._weight[id(node)] = self._nodes - before
                if self._nodes > max_nodes:
                    raise _YamlLimit(f"expands to more than {max_nodes} nodes (aliases counted as what they "
                                     "stand for)")
                return node
            finally:
                self._depth -= 1

    return BoundedLoader


def parse_yaml(text: str, *, what: str = "the YAML", max_depth: int = MAX_DEPTH, max_nodes: int = MAX_NODES) -> Any:
    """``text`` as YAML (safe tags only), refused when it nests deeper than ``max_depth`` or expands to more than
    ``max_nodes`` nodes: an alias bomb stops while it is composed, before anything is built."""
    loader = _bounded_loader(max_depth, max_nodes)(text)
    try:
        return loader.get_single_data()
    except _YamlLimit as exc:
        raise ReadRefused(f"{what} {exc}; it is not read") from None
    except RecursionError:
        raise ReadRefused(f"{what} nests deeper than {max_depth} levels; it is not read") from None
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise NotParsed(f"{what} is not valid YAML ({first[:160]})") from None
    finally:
        loader.dispose()


def load_yaml(path: PathLike, limit: int = MAX_YAML, *, what: str | None = None, max_depth: int = MAX_DEPTH,
              max_nodes: int = MAX_NODES) -> Any:
    """The YAML in ``path``, read within ``limit`` bytes, ``max_depth`` levels and ``max_nodes`` nodes."""
    name = what or _show(path)
    return parse_yaml(read_text(path, limit, what=name, errors="strict"), what=name, max_depth=max_depth,
                      max_nodes=max_nodes)


# ------------------------------------------------------------------------------------------ images


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def image_header(data: bytes) -> tuple[str, int, int] | None:
    """(mime type, width, height) of a PNG or JPEG from its first bytes; None for anything else (or a JPEG whose
    size is not found in its first 64 KB)."""
    if data[:8] == PNG_MAGIC and data[12:16] == b"IHDR" and len(data) >= 24:
        width, height = struct.unpack(">II", data[16:24])
        return "image/png", width, height
    if data[:2] == b"\xff\xd8":
        i = 2
        while i + 9 < min(len(data), 1 << 16):
            if data[i] != 0xFF:
                return None
            marker = data[i + 1]
            length = struct.unpack(">H", data[i + 2:i + 4])[0]
            if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
                height, width = struct.unpack(">HH", data[i + 5:i + 9])
                return "image/jpeg", width, height
            i += 2 + length
    return None


def read_image_bytes(path: PathLike, limit: int = MAX_IMAGE, *, max_pixels: int = MAX_PIXELS,
                     what: str | None = None) -> tuple[str, bytes]:
    """(mime type, bytes) of a PNG or JPEG file at most ``limit`` bytes whose header declares at most
    ``max_pixels`` pixels; nothing is decoded."""
    name = what or _show(path)
    data = read_bytes(path, limit, what=name)
    header = image_header(data)
    if header is None:
        raise NotParsed(f"{name} is not a PNG or JPEG image")
    mime, width, height = header
    if width * height > max_pixels:
        raise ReadRefused(f"{name} declares {width} x {height} pixels, over the limit of {max_pixels}")
    return mime, data


# ------------------------------------------------------------------------------------------ paths


def inside(root: PathLike, relative: Any, *, what: str = "path") -> Path:
    """``root / relative`` when it is a relative path that stays inside ``root`` once every link is resolved
    (no absolute path, no ``..`` out, no symbolic link pointing out); :class:`ReadRefused` otherwise."""
    text = str(relative)
    if not text or "\x00" in text:
        raise ReadRefused(f"{what} {text!r} is not a file name")
    if os.path.isabs(text):
        raise ReadRefused(f"{what} {text!r} is an absolute path; only files inside the run folder are read")
    base = Path(root).resolve()
    target = (base / text).resolve()
    if target != base and base not in target.parents:
        raise ReadRefused(f"{what} {text!r} resolves outside {base}; only files inside it are read")
    return target


# ------------------------------------------------------------------------------------------ numpy files


def npy_header(path: PathLike, limit: int, *, what: str | None = None) -> tuple[tuple, Any, bool]:
    """(shape, dtype, fortran_order) of the ``.npy`` file ``path``, checked before any array is built: a plain
    numeric dtype (no objects, no pickles), a file of at most ``limit`` bytes, and exactly the bytes its header's
    shape needs (a header claiming 2^40 rows in a small file is refused here, not by a failed allocation)."""
    import numpy as np
    from numpy.lib import format as npy

    name = what or _show(path)
    try:
        size = os.stat(os.fspath(path)).st_size
    except OSError as exc:
        raise ReadRefused(f"{name}: cannot read it ({exc.strerror or exc})") from None
    if size > limit:
        raise ReadRefused(f"{name} is {size} bytes, over the limit of {limit} bytes")
    try:
        with open(os.fspath(path), "rb") as f:
            version = npy.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = npy.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = npy.read_array_header_2_0(f)
            else:
                raise ValueError(f"unknown .npy version {version}")
            offset = f.tell()
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        raise ReadRefused(f"{name} is not a numpy array file ({str(exc)[:160]})") from None
    if dtype.hasobject or not np.issubdtype(dtype, np.number):
        raise ReadRefused(f"{name} holds {dtype} values; numbers are expected")
    count = 1
    for n in shape:
        count *= int(n)
    needed = count * dtype.itemsize
    if offset + needed != size:
        raise ReadRefused(f"{name}: its header claims shape {tuple(shape)} ({needed} bytes of data) but the file "
                          f"holds {size - offset}")
    return tuple(shape), dtype, fortran
