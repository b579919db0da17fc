"""Reproducible ray batches from Nerfstudio's parallel datamanager.

Nerfstudio 1.1.5's ``ParallelDataManager`` (nerfacto, tensorf, ...) samples training rays in
``DataProcessor`` worker processes started with the ``spawn`` method. A spawned process begins with
a fresh, randomly seeded torch generator, so ``--machine.seed`` fixes the model's initial weights
but not the rays it trains on: two runs with the same seed differ from the first batch on (measured:
step-0 losses 0.1888 vs 0.1910 for nerfacto). :func:`seed_parallel_workers` makes every worker seed
torch, numpy and ``random`` from the trainer's seed (``torch.initial_seed()`` in the main process,
which ``ns-train`` sets from ``--machine.seed``) plus one plus its index, so a seed fixes the run.
The main process's random stream is not touched (no draw), so everything else stays as it was.
"""

from __future__ import annotations

import itertools
import random

_SEED_ATTR = "_nerfify_worker_seed"


def worker_seed(main_seed: int, index: int) -> int:
    """The seed of the ``index``-th worker of a run seeded with ``main_seed`` (within numpy's 32 bits)."""
    return (main_seed + 1 + index) % 2**32


def seed_everything(seed: int) -> None:
    import numpy as np
    import torch

    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def seed_parallel_workers() -> None:
    """Patch ``DataProcessor``: record a seed when it is created (main process), apply it when it runs."""
    import torch
    from nerfstudio.data.datamanagers import parallel_datamanager as pdm

    processor = pdm.DataProcessor
    if getattr(processor.run, "_nerfify_seeded", False):
        return
    original_init, original_run = processor.__init__, processor.run
    counter = itertools.count()

    def __init__(self, *args, **kwargs):
        original_init(self, *args, **kwargs)
        setattr(self, _SEED_ATTR, worker_seed(torch.initial_seed(), next(counter)))

    def run(self):
        seed = getattr(self, _SEED_ATTR, None)
        if seed is not None:
            seed_everything(seed)
        return original_run(self)

    run._nerfify_seeded = True  # type: ignore[attr-defined]
    processor.__init__, processor.run = __init__, run
