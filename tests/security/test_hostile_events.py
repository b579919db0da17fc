"""Event files are written by the run (a plugin's code, sandboxed) and parsed in our own process: a tensor header
claiming 30000 x 30000 elements in a 61-byte file, a record claiming 2^40 bytes, a truncated or garbled record
and a link out are read within bounds (no array built for a non-scalar, no allocation from a claimed length), and
the real scalars around them are still read."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from tensorboard.compat.proto import event_pb2, summary_pb2, tensor_pb2, tensor_shape_pb2, types_pb2
from tensorboard.compat.tensorflow_stub.pywrap_tensorflow import masked_crc32c

from nerfify_ns.runtime import events as ev


def record(data: bytes, length: int = None) -> bytes:
    header = struct.pack("<Q", len(data) if length is None else length)
    return header + struct.pack("<I", masked_crc32c(header)) + data + struct.pack("<I", masked_crc32c(data))


def scalar(tag: str, step: int, value: float) -> bytes:
    summary = summary_pb2.Summary(value=[summary_pb2.Summary.Value(tag=tag, simple_value=value)])
    return record(event_pb2.Event(step=step, summary=summary).SerializeToString())


def tensor_bomb(side: int = 30_000) -> bytes:
    shape = tensor_shape_pb2.TensorShapeProto(dim=[tensor_shape_pb2.TensorShapeProto.Dim(size=side)] * 2)
    tensor = tensor_pb2.TensorProto(dtype=types_pb2.DT_FLOAT, tensor_shape=shape, float_val=[1.0])  # repeated to fill
    summary = summary_pb2.Summary(value=[summary_pb2.Summary.Value(tag=ev.LOSS_TAG, tensor=tensor)])
    return record(event_pb2.Event(step=7, summary=summary).SerializeToString())


def read_in_child(folder: Path) -> tuple:
    """read_scalars(folder) in a fresh interpreter: its printed result, seconds and peak RSS (MB)."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from nerfify_ns.runtime.events import read_scalars; "
                             "print(read_scalars(sys.argv[1]))", str(folder)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    out, err = proc.stdout.read(), proc.stderr.read()
    assert os.waitstatus_to_exitcode(status) == 0, err
    return out.strip(), time.perf_counter() - start, usage.ru_maxrss / 1024


def test_a_61_byte_tensor_bomb_is_not_expanded(tmp_path):
    bomb = tensor_bomb()
    assert len(bomb) <= 64  # the whole file: a header claiming 3.6 GB of floats
    (tmp_path / "events.out.tfevents.1.bomb").write_bytes(bomb)
    (tmp_path / "events.out.tfevents.2.real").write_bytes(scalar(ev.LOSS_TAG, 1, 0.5) + scalar(ev.LOSS_TAG, 2, 0.25))
    baseline = tmp_path.parent / f"{tmp_path.name}-baseline"
    baseline.mkdir()
    (baseline / "events.out.tfevents.2.real").write_bytes((tmp_path / "events.out.tfevents.2.real").read_bytes())
    _, _, base_rss = read_in_child(baseline)  # importing the reader (and what it imports) alone
    out, seconds, rss = read_in_child(tmp_path)
    assert out == "{'Train Loss': {1: 0.5, 2: 0.25}}"  # the bomb's step 7 is no scalar
    assert rss - base_rss < 100 and seconds < 30, (rss, base_rss)  # expanded, it would take 3.6 GB


def test_claimed_lengths_truncation_garbage_and_links(tmp_path):
    good = scalar(ev.LOSS_TAG, 1, 1.0)
    (tmp_path / "events.out.tfevents.1.huge").write_bytes(good + record(b"x" * 10, length=1 << 40))
    (tmp_path / "events.out.tfevents.2.garbled").write_bytes(scalar(ev.RAYS_TAG, 1, 10.0) + record(b"\xff" * 40))
    (tmp_path / "events.out.tfevents.3.cut").write_bytes(scalar(ev.ITER_TIME_TAG, 1, 0.1) + good[:-3])
    outside = tmp_path.parent / f"{tmp_path.name}-outside"
    outside.mkdir()
    (outside / "x").write_bytes(scalar(ev.LOSS_TAG, 99, 9.0))
    (tmp_path / "events.out.tfevents.4.link").symlink_to(outside / "x")
    reader = ev.EventReader(tmp_path)
    scalars = reader.poll()
    assert scalars == {ev.LOSS_TAG: {1: 1.0}, ev.RAYS_TAG: {1: 10.0}, ev.ITER_TIME_TAG: {1: pytest.approx(0.1)}}
    with open(tmp_path / "events.out.tfevents.3.cut", "ab") as f:  # the cut record completes: read next poll
        f.write(good[-3:])
    assert reader.poll()[ev.LOSS_TAG] == {1: 1.0}  # the completed record was the loss at step 1 again
    assert reader.last_step() == 1


def test_a_huge_log_is_read_by_its_tail_only(tmp_path):
    """A child (training, a sandboxed probe) may print without end: its log is read from the end, 256 KB at most."""
    from nerfify_ns.runtime.process import ProcessResult

    log = tmp_path / "train.log"
    with open(log, "wb") as f:
        f.truncate(8 << 30)  # 8 GiB (sparse): read whole, it would exhaust our memory
        f.seek(0, os.SEEK_END)
        f.write(b"step 1\nstep 2\nTraceback: the last line\n")
    start = time.perf_counter()
    tail = ProcessResult(returncode=1, seconds=1.0, timed_out=False, log_path=log).tail(2)
    assert tail == "step 2\nTraceback: the last line" and time.perf_counter() - start < 2


def test_a_record_over_the_record_limit_is_skipped_not_the_file(tmp_path):
    """An image summary (or any record over the limit) is skipped unread; the scalars after it are still read."""
    big = record(b"\x00" * (ev.MAX_RECORD + 1))
    (tmp_path / "events.out.tfevents.1.img").write_bytes(
        scalar(ev.LOSS_TAG, 1, 1.0) + big + scalar(ev.LOSS_TAG, 2, 0.5))
    assert ev.read_scalars(tmp_path) == {ev.LOSS_TAG: {1: 1.0, 2: 0.5}}
