"""Assemble the source of a lowered module: the fixed prelude (helpers), the symbol map, the class.

Everything here is fixed text, generated identifiers, ints and float reprs; the paper's notation appears
only through ``render.safe_comment`` in comments.
"""

from __future__ import annotations

from .show import safe_comment

PRELUDE = '''import math

import torch
from torch import nn


def _exclusive_cumsum(x, dim):
    """The sum over the samples before each sample along dim (0 for the first)."""
    n = x.shape[dim]
    parts = [torch.zeros_like(x.narrow(dim, 0, 1)), torch.cumsum(x, dim).narrow(dim, 0, n - 1)]
    return torch.cat(parts, dim)


def _exclusive_cumprod(x, dim):
    """The product over the samples before each sample along dim (1 for the first)."""
    n = x.shape[dim]
    return torch.cumprod(torch.cat([torch.ones_like(x.narrow(dim, 0, 1)), x.narrow(dim, 0, n - 1)], dim), dim)


def _before_mask(n, inclusive, like):
    """mask[i, j]: sample j comes before sample i (or is i, when inclusive)."""
    return torch.ones(n, n, dtype=torch.bool, device=like.device).tril(0 if inclusive else -1)


def _sample_ones(n, like):
    """n ones along the sample axis: a value that does not depend on the samples, repeated for each."""
    return torch.ones(n, dtype=like.dtype, device=like.device)


def _cat_features(*xs):
    """Concatenate along the last (feature) dimension, broadcasting the others; numbers become features."""
    ref = next(x for x in xs if torch.is_tensor(x))
    xs = [x if torch.is_tensor(x) else torch.full(ref.shape[:-1] + (1,), x, dtype=ref.dtype, device=ref.device)
          for x in xs]
    shape = torch.broadcast_shapes(*[x.shape[:-1] for x in xs])
    return torch.cat([x.expand(*shape, x.shape[-1]) for x in xs], dim=-1)
'''


def _dims_text(dims) -> str:
    return "[" + ", ".join(safe_comment(str(d), 12) for d in dims) + "]"


def assemble(class_name: str, input_rows: list, output_rows: list, param_rows: dict, body: list[str],
             returns: list[str], numbers: list[str]) -> str:
    """The module's source: prelude, symbol map comments, the class with __init__, reset_parameters, forward."""
    numbers_text = ", ".join(f"({safe_comment(n, 12)})" for n in numbers if n) or "(unnumbered)"
    lines = [
        f'"""{class_name}: compiled by nerfify-ns from a paper\'s equations; generated code, do not edit."""',
        "",
        PRELUDE.rstrip("\n"),
        "",
        "",
        f"# equations {numbers_text}",
        "# symbol map (identifier <- the paper's symbol [layout]):",
    ]
    for key, ident, dims in input_rows:
        lines.append(f"#   {ident} <- {safe_comment(key, 60)} {_dims_text(dims)}  (input)")
    for _key, (attr, spec) in param_rows.items():
        kind = "parameter" if spec.learned else "fixed"
        lines.append(f"#   self.{attr} <- {safe_comment(key, 60)} {_dims_text(spec.shape)}  ({kind})")
    for key, ident in output_rows:
        lines.append(f"#   {ident} <- {safe_comment(key, 60)}  (output)")
    lines += [
        f"class {class_name}(nn.Module):",
        '    """Equations lowered to torch; forward takes the inputs and returns the outputs in the order of the '
        'symbol map."""',
        "",
        "    def __init__(self):",
        "        super().__init__()",
    ]
    for _key, (attr, spec) in param_rows.items():
        shape = ", ".join(str(int(s)) for s in spec.shape) or "()"  # () for one learned number
        if spec.learned:
            lines.append(f"        self.{attr} = nn.Parameter(torch.empty({shape}))")
        else:
            lines.append(f"        self.register_buffer({attr!r}, torch.empty({shape}))")
    lines += ["        self.reset_parameters()", "", "    def reset_parameters(self):"]
    init_lines: list[str] = []
    for _key, (attr, spec) in param_rows.items():
        target = f"self.{attr}"
        low, high = spec.clamp or (None, None)
        if low is not None and high is not None and spec.init == "default":
            init_lines.append(f"nn.init.uniform_({target}, {float(low)!r}, {float(high)!r})  # the paper's range")
            continue
        if spec.init == "normal":
            init_lines.append(f"nn.init.normal_({target}, std={float(spec.std)!r})")
        elif spec.init == "ones":
            init_lines.append(f"nn.init.ones_({target})")
        elif spec.init == "zeros" or len(spec.shape) < 2:
            init_lines.append(f"nn.init.zeros_({target})")
        else:
            init_lines.append(f"nn.init.kaiming_uniform_({target}, a=math.sqrt(5))")
    for _key, (attr, spec) in param_rows.items():
        if spec.clamp and spec.clamp != (None, None):
            init_lines.append(f"self.{attr}.clamp_({_bound(spec.clamp[0])}, {_bound(spec.clamp[1])})")
    if init_lines:
        lines += ["        with torch.no_grad():"] + [f"            {line}" for line in init_lines]
    else:
        lines.append("        return")
    args = ", ".join(["self"] + [ident for _, ident, _ in input_rows])
    lines += ["", f"    def forward({args}):"]
    clamped = [(attr, spec.clamp) for attr, spec in param_rows.values() if spec.clamp and spec.clamp != (None, None)]
    if clamped:  # the paper's constraint on learned values, applied at every training step (a projection)
        lines += ["        if self.training:"]
        lines += [f"            self.{attr}.data.clamp_({_bound(lo)}, {_bound(hi)})" for attr, (lo, hi) in clamped]
    lines += [f"        {line}" if line else "" for line in body]
    lines.append(f"        return {', '.join(returns)}" if returns else "        return None")
    source = "\n".join(lines) + "\n"
    if "math." not in source.split("def _exclusive_cumsum", 1)[1]:
        source = source.replace("import math\n\n", "", 1)  # no unused import
    return source


def _bound(value) -> str:
    """A clamp bound as code: a float literal, or None for an open side."""
    return "None" if value is None else repr(float(value))
