"""Shared oracle for the hash-grid tests: Nerfstudio's stock torch fallback and how to compare with it."""

import torch
from nerfstudio.field_components.encodings import HashEncoding

STOCK = HashEncoding.__dict__["pytorch_fwd"]  # captured before any runtime patch can replace it


def make_encoding(levels=16, log2_size=19, features=2, max_res=2048, dtype=torch.float32, seed=0):
    torch.manual_seed(seed)
    enc = HashEncoding(num_levels=levels, log2_hashmap_size=log2_size, features_per_level=features,
                       max_res=max_res, implementation="torch")
    enc.hash_table.data.uniform_(-1, 1)  # larger than the 1e-3 init so differences are visible
    return enc.to(dtype)


def off_grid(x: torch.Tensor, enc: HashEncoding) -> torch.Tensor:
    """Rows whose scaled coordinates are integers at no level (where the stock derivative is one-sided)."""
    scaled = x[:, None, :] * enc.scalings[None, :, None].to(x.dtype)  # in x's precision, as both paths do
    return ~(scaled == torch.round(scaled)).any(-1).any(-1)


def run(fn, enc, x, grad_out):
    """Output, table gradient and position gradient of ``fn(enc, x)`` against ``grad_out``."""
    xx = x.clone().requires_grad_(True)
    enc.hash_table.grad = None
    out = fn(enc, xx)
    g_table, g_pos = torch.autograd.grad(out, [enc.hash_table, xx], grad_out)
    return out.detach(), g_table, g_pos
