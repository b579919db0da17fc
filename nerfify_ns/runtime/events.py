"""The one reader of a run's tensorboard events: every scalar per step, read incrementally and within bounds.

Verdicts and figures (iterations reached, losses, rays per second, iteration times) come from the
events Nerfstudio's own writer logged, never from text a process printed. :class:`EventReader` keeps
its place in each event file, so polling a running training (progress) reads only what is new.

The event files are written by the run (a plugin's code, sandboxed) and parsed here, in our own process, outside
every limit the sandbox sets; so nothing in them is trusted. The records (TFRecord framing: an 8-byte length, its
checksum, the serialized ``Event``, its checksum) are read by this module, not by tensorboard's loader: a length
is checked against the bytes the file really holds before anything is read, so a record claiming 2^40 bytes is
never allocated. A summary value's tensor is a scalar only when its header's shape holds exactly one element; its
shape is checked before any array is built (a 61-byte record claiming a 30000 x 30000 tensor is skipped, not
expanded by ``make_ndarray``). Files over :data:`MAX_EVENT_FILE`, links, and values past :data:`MAX_VALUES` are not
read.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

Scalars = dict[str, dict[int, float]]
"""tag -> step -> value."""

MAX_EVENT_FILE = 256 << 20
"""Event files larger than this, and links, are not read: the run (a plugin's, sandboxed) wrote them, and they are
parsed in our own process."""
MAX_RECORD = 4 << 20
"""Bytes of one event record parsed (scalars take a few dozen; larger ones, images, are skipped unread)."""
MAX_VALUES = 1_000_000
"""Scalar values kept per reader (a run logging more is cut there; a CPU run logs a few thousand)."""

LOSS_TAG = "Train Loss"
RAYS_TAG = "Train Rays / Sec"
ITER_TIME_TAG = "Train Iter (time)"

_NUMERIC_FIELDS = ("float_val", "double_val", "int_val", "int64_val", "uint32_val", "uint64_val", "half_val",
                   "bool_val")


def _elements(tensor) -> int | None:
    """The element count a tensor's header claims (None for an unknown rank or a negative size)."""
    if tensor.tensor_shape.unknown_rank:
        return None
    count = 1
    for dim in tensor.tensor_shape.dim:
        if dim.size < 0:
            return None
        count *= dim.size
        if count > 1:
            return count
    return count


def _value(value) -> float | None:
    """The scalar in one summary value: ``simple_value`` (torch's writer) or a one-element numeric tensor. The
    tensor's header is checked first: anything but one element is no scalar, and no array is built for it."""
    if value.HasField("simple_value"):
        return float(value.simple_value)
    if value.HasField("tensor"):
        tensor = value.tensor
        if _elements(tensor) != 1:
            return None  # a text summary (the run's config), a histogram, or a tensor bomb: no scalar
        if len(tensor.tensor_content) > 16 or any(len(getattr(tensor, f)) > 1 for f in _NUMERIC_FIELDS):
            return None
        from tensorboard.util import tensor_util

        try:
            array = tensor_util.make_ndarray(tensor)
        except (ValueError, TypeError, KeyError):
            return None
        numeric = array.dtype.kind in "fiub"
        return float(array.reshape(-1)[0]) if numeric and array.size == 1 else None
    return None


class _RecordFile:
    """The records of one event file from where the last read stopped; a record not written completely yet is
    left for the next poll."""

    def __init__(self, path: Path) -> None:
        self.path, self.offset, self.broken = path, 0, False

    def records(self) -> list[bytes]:
        if self.broken:
            return []
        out: list[bytes] = []
        try:
            fd = os.open(str(self.path), os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            return out
        try:
            size = min(os.fstat(fd).st_size, MAX_EVENT_FILE)
            while self.offset + 12 <= size:
                head = os.pread(fd, 12, self.offset)
                if len(head) < 12:
                    break
                (length,) = struct.unpack("<Q", head[:8])
                end = self.offset + 12 + length + 4
                if end > size:
                    break  # not written completely yet (or claims more than the file holds): nothing allocated
                if length > MAX_RECORD:
                    self.offset = end  # an image or another large summary: skipped unread, never a scalar
                    continue
                data = os.pread(fd, length, self.offset + 12)
                if len(data) < length:
                    break
                out.append(data)
                self.offset = end
        finally:
            os.close(fd)
        return out


class EventReader:
    """Every scalar of the event files in ``run_dir``; :meth:`poll` reads what was written since the last call."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self.scalars: Scalars = {}
        self._files: dict[Path, _RecordFile] = {}
        self._count = 0

    def poll(self) -> Scalars:
        """Read new events (files that appeared included) and return all scalars so far."""
        from google.protobuf.message import DecodeError
        from tensorboard.compat.proto import event_pb2

        for path in sorted(self.run_dir.glob("events.out.tfevents.*")):
            if path.is_symlink() or not path.is_file() or path.stat().st_size > MAX_EVENT_FILE:
                continue
            reader = self._files.get(path)
            if reader is None:
                reader = self._files[path] = _RecordFile(path)
            for data in reader.records():
                try:
                    event = event_pb2.Event.FromString(data)
                except (DecodeError, ValueError, RuntimeError):
                    reader.broken = True
                    break
                for value in event.summary.value:
                    if self._count >= MAX_VALUES:
                        return self.scalars
                    number = _value(value)
                    if number is not None:
                        self.scalars.setdefault(value.tag, {})[event.step] = number
                        self._count += 1
        return self.scalars

    def last_step(self, tag: str = LOSS_TAG) -> int:
        """The highest step ``tag`` was logged at (-1 before the first). Training steps are those of the loss;
        Nerfstudio logs its total time one step later."""
        return max(self.scalars.get(tag) or {}, default=-1)


def read_scalars(run_dir: Path) -> Scalars:
    """Every scalar of the run in ``run_dir`` ({} when it logged none)."""
    return EventReader(run_dir).poll() if Path(run_dir).is_dir() else {}


def losses(scalars: Scalars) -> dict[int, float]:
    """The total training loss per logged step."""
    return dict(scalars.get(LOSS_TAG, {}))


def rays_per_sec(scalars: Scalars) -> list[float]:
    """Nerfstudio's per-step training throughput, in step order."""
    rays = scalars.get(RAYS_TAG, {})
    return [rays[s] for s in sorted(rays)]
