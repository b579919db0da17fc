"""Scripted answers of the coder tests: what a model might write for a hole, right and wrong.

``bionerf_backbone()`` is a BioNeRF backbone written by hand from the paper (Aguiar et al., BioNeRF, Sec. 3,
Eqs. 1-9): positional and directional feature MLPs h_Delta and h_c, filters f_Delta = sigmoid(W h_Delta + b) and
f_c (Eqs. 2-3), modulation f_psi, f_mu and gamma = tanh(W [h_Delta, h_c] + b) (Eqs. 4-6), mu = f_mu * gamma
(Eq. 6), the memory Psi = tanh(W_Psi (mu + f_psi * Psi) + b_Psi) (Eq. 7, persistent state updated detached while
training) and the filtered embedding h'_Delta = [Psi * f_Delta, l] (Eq. 8). The wrong answers break it three
ways: a shape mismatch, a NaN for large inputs (a softmax written out by hand), an import of a missing module.
"""

from __future__ import annotations

import json

CLASS = "BackboneModelPart"
RIGHT = '''"""BioNeRF's backbone (Aguiar et al., Sec. 3, Eqs. 1-9), written for the coder test."""

import torch
from torch import nn


def _mlp(in_dim: int, width: int) -> nn.Module:
    return nn.Sequential(nn.Linear(in_dim, width), nn.ReLU(), nn.Linear(width, width), nn.ReLU())


class BackboneModelPart(nn.Module):
    def __init__(self, in_dim: int, out_dim=None, width: int = 64, **kwargs):
        super().__init__()
        self.in_dim, self.width = in_dim, width
        self.h_delta, self.h_c = _mlp(in_dim, width), _mlp(in_dim, width)          # Eq. 1
        self.f_delta, self.f_c = nn.Linear(width, width), nn.Linear(width, width)   # Eqs. 2-3
        self.f_psi, self.f_mu = nn.Linear(2 * width, width), nn.Linear(2 * width, width)  # Eqs. 4-5
        self.gamma = nn.Linear(2 * width, width)                                    # Eq. 6
        self.w_psi = nn.Linear(width, width)                                        # Eq. 7
        self.register_buffer("psi", torch.zeros(1, width))                          # the memory, persistent

    def get_out_dim(self) -> int:
        return 2 * self.width + self.in_dim

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        h_delta, h_c = self.h_delta(features), self.h_c(features)
        both = torch.cat([h_delta, h_c], dim=-1)
        f_delta, f_c = torch.sigmoid(self.f_delta(h_delta)), torch.sigmoid(self.f_c(h_c))
        f_psi, f_mu = torch.sigmoid(self.f_psi(both)), torch.sigmoid(self.f_mu(both))
        mu = f_mu * torch.tanh(self.gamma(both))
        psi = torch.tanh(self.w_psi(mu + f_psi * self.psi.to(features.dtype)))
        if self.training and psi.shape[0]:
            self.psi = psi.detach().reshape(-1, self.width).mean(dim=0, keepdim=True)  # over rays and samples
        return torch.cat([psi * f_delta, psi * f_c, features], dim=-1)              # Eqs. 8-9
'''
SHAPE_MISMATCH = RIGHT.replace("return 2 * self.width + self.in_dim", "return self.width + self.in_dim")
NAN_FOR_LARGE = RIGHT.replace(
    "        mu = f_mu * torch.tanh(self.gamma(both))",
    "        g = torch.exp(self.gamma(both))\n        mu = f_mu * g / g.sum(dim=-1, keepdim=True)")
MISSING_MODULE = RIGHT.replace("import torch\n", "import torch\nimport bionerf_memory  # noqa: F401\n", 1)

SENTENCES = ["we propose a memory mechanism to store the filtered positional and directional features",
             "Psi = tanh(W_Psi (mu + f_psi * Psi) + b_Psi)"]


def answer(code: str) -> str:
    return json.dumps({"code": code, "implements": [f"Eq. {k}" for k in range(1, 9)], "sentences": SENTENCES})


RGB_HEAD = '''import torch
from torch import nn


class RgbHeadModelPart(nn.Module):
    """A colour MLP with two hidden layers of 64 units and a sigmoid (GridLite, Sec. 3.1)."""

    def __init__(self, in_dim, **kwargs):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_dim, 64), nn.ReLU(), nn.Linear(64, 64), nn.ReLU(), nn.Linear(64, 3))

    def forward(self, features):
        return torch.sigmoid(self.net(features))
'''
RGB_HEAD_FOUR = RGB_HEAD.replace("nn.Linear(64, 3)", "nn.Linear(64, 4)")


def rgb_answer(code: str) -> str:
    return json.dumps({"code": code, "implements": ["Sec. 3.1"],
                       "sentences": ["a colour MLP with two hidden layers of 64 units predicts RGB with a sigmoid"]})


SLOT = "model.field.MLPField.rgb_head"


def rgb_head_hole(impl):
    """GridLite's colour head (Sec. 3.1) as the one hole left for the coder, whatever else the planner found: the
    test is about the checks, not about which part the paper's reading leaves open."""
    from nerfify_ns.synthesis.novel.implement import NOT_IMPLEMENTED, HoleResult

    assert isinstance(impl.plan.get(SLOT), dict), "GridLite's plan has an MLP field with a colour head"
    record = HoleResult("rgb_head", SLOT, "RGBHead", "3.1", NOT_IMPLEMENTED, "set aside for the coder test")
    impl.records = [record]
    impl.plan["holes"] = [{"production": "RGBHead", "slot": SLOT, "status": NOT_IMPLEMENTED,
                           "text": "a colour MLP with two hidden layers of 64 units predicts RGB with a sigmoid"}]
    return record
