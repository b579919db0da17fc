"""The one reader of a run's tensorboard events: every scalar per step, read incrementally.

Verdicts and figures (iterations reached, losses, rays per second, iteration times) come from the
events Nerfstudio's own writer logged, never from text a process printed. :class:`EventReader` keeps
its place in each event file, so polling a running training (progress) reads only what is new.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Optional

Scalars = Dict[str, Dict[int, float]]
"""tag -> step -> value."""

MAX_EVENT_FILE = 256 << 20
"""Event files larger than this, and links, are not read: the run (a plugin's, sandboxed) wrote them, and they are
parsed in our own process."""

LOSS_TAG = "Train Loss"
RAYS_TAG = "Train Rays / Sec"
ITER_TIME_TAG = "Train Iter (time)"


def _value(value) -> Optional[float]:
    """The scalar in one summary value: ``simple_value`` (torch's writer) or a one-element tensor."""
    if value.HasField("simple_value"):
        return float(value.simple_value)
    if value.HasField("tensor"):
        from tensorboard.util import tensor_util

        array = tensor_util.make_ndarray(value.tensor)
        numeric = array.dtype.kind in "fiub"  # a text summary (the run's config) is no scalar
        return float(array.reshape(-1)[0]) if numeric and array.size == 1 else None
    return None


class EventReader:
    """Every scalar of the event files in ``run_dir``; :meth:`poll` reads what was written since the last call."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = Path(run_dir)
        self.scalars: Scalars = {}
        self._loaders: dict = {}

    def poll(self) -> Scalars:
        """Read new events (files that appeared included) and return all scalars so far."""
        from tensorboard.backend.event_processing.event_file_loader import LegacyEventFileLoader

        for path in sorted(self.run_dir.glob("events.out.tfevents.*")):
            if path.is_symlink() or not path.is_file() or path.stat().st_size > MAX_EVENT_FILE:
                continue
            loader = self._loaders.get(path)
            if loader is None:
                loader = self._loaders[path] = LegacyEventFileLoader(str(path))
            for event in loader.Load():
                for value in event.summary.value:
                    number = _value(value)
                    if number is not None:
                        self.scalars.setdefault(value.tag, {})[event.step] = number
        return self.scalars

    def last_step(self, tag: str = LOSS_TAG) -> int:
        """The highest step ``tag`` was logged at (-1 before the first). Training steps are those of the loss;
        Nerfstudio logs its total time one step later."""
        return max(self.scalars.get(tag) or {}, default=-1)


def read_scalars(run_dir: Path) -> Scalars:
    """Every scalar of the run in ``run_dir`` ({} when it logged none)."""
    return EventReader(run_dir).poll() if Path(run_dir).is_dir() else {}


def losses(scalars: Scalars) -> Dict[int, float]:
    """The total training loss per logged step."""
    return dict(scalars.get(LOSS_TAG, {}))


def rays_per_sec(scalars: Scalars) -> List[float]:
    """Nerfstudio's per-step training throughput, in step order."""
    rays = scalars.get(RAYS_TAG, {})
    return [rays[s] for s in sorted(rays)]
