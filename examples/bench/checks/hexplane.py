"""Checks of HexPlane (Cao and Johnson 2023) items: reference functions written from the paper."""

import torch


def _refs():
    """The shared reference functions (checks/_refs.py; check files are loaded by path)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("nerfify_bench_refs", Path(__file__).with_name("_refs.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def photometric_loss(target):
    """Eq. 7: the mean squared error between rendered and observed colours."""
    assert target.path.endswith(".l2") or "l2" in (target.value or {}), f"colour loss {target.value}, not L2"
    _refs().mse(torch.nn.MSELoss())


def plane_tv(target):
    """Sec. 3.3: a total variation loss on the planes (squared differences of neighbouring cells)."""
    assert float(target.value.get("weight", 0)) > 0, "the TV loss has no weight"
    _refs().plane_tv()
