"""RawNeRF's relative L2 photometric loss (Mildenhall et al., "NeRF in the Dark: High Dynamic Range View Synthesis
from Noisy Raw Images", CVPR 2022, arXiv 2111.13679): L = mean(((C_hat - C) / (sg(C_hat) + eps))^2), the squared
error weighted by the stop-gradient of the rendered colour, so dark linear (raw, HDR) values count as much as bright
ones. SeaThru-NeRF trains its linear-domain reconstruction with it.

The plugin builds it from Nerfstudio's ``MSELoss`` (``torch.nn.MSELoss``) with a forward pre-hook that divides both
colours by ``sg(pred) + eps``: the base models call ``rgb_loss(target, pred)``, and the mean squared error of the
scaled colours is the relative loss."""

from __future__ import annotations

from dataclasses import dataclass

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import VALUE_CASES
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Harness, TerminalDef


@dataclass
class RelativeL2:
    eps: float = param(0.001, range=(1.0e-8, 1.0))
    """The epsilon of sg(C_hat) + eps (RawNeRF: 1e-3)."""


CTOR = ("(lambda loss, eps: (loss.register_forward_pre_hook(lambda _, a: (a[0] / (a[1].detach() + eps), "
        "a[1] / (a[1].detach() + eps))), loss)[1])(nn.MSELoss(), {{ p.eps }})")
"""``nn.MSELoss`` whose inputs ``(target, pred)`` are divided by ``sg(pred) + eps`` before it runs."""

TERMINALS = [
    TerminalDef("relative_l2", "RGBLoss", RelativeL2,
                "Relative squared error ((C_hat - C) / (sg(C_hat) + eps))^2 (RawNeRF; linear, HDR colours).",
                "torch.nn.MSELoss", card="relative_l2",
                contract=Contract({"target": T("[R, 3]", range=(0.0, 1.0), doc="observed colours"),
                                   "pred": T("[R, 3]", range=(0.0, 1.0), grad=True, doc="rendered colours")},
                                  {"loss": T("[]", range=(0.0, None), doc="a non-negative scalar")}),
                code=Code(("from torch import nn",), ctor=CTOR),
                harness=Harness(cases=VALUE_CASES)),
]
