"""Checks of HexPlane (Cao and Johnson 2023) items: reference functions written from the paper."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
import torch


def photometric_loss(target):
    """Eq. 7: the mean squared error between rendered and observed colours."""
    assert target.path.endswith(".l2") or "l2" in (target.value or {}), f"colour loss {target.value}, not L2"
    _refs.mse(torch.nn.MSELoss())


def plane_tv(target):
    """Sec. 3.3: a total variation loss on the planes (squared differences of neighbouring cells)."""
    assert float(target.value.get("weight", 0)) > 0, "the TV loss has no weight"
    _refs.plane_tv()
