"""Differential testing: random (seeded) equations over per-sample, per-ray and scalar symbols, with nested
sums and products over earlier samples, concatenations, norms, cases; each is read, lowered and checked
against the interpreter (rtol 1e-6) and gradchecked."""

from __future__ import annotations

import random

import pytest

from nerfify_ns.equations import check_lowering, parse_equation, show

SPEC = {"a": ("R", "S"), "b": ("R", "S"), "c": ("R",), "lambda": ()}
DOMAINS = {"a": (-1.0, 1.0), "b": (-1.0, 1.0)}


def _expr(rng: random.Random, depth: int, idx: list[str]) -> str:
    leaves = ["c", "0.5", r"\lambda"] + [f"a_{v}" for v in idx] + [f"b_{v}" for v in idx]
    if depth <= 0 or rng.random() < 0.2:
        return rng.choice(leaves)

    def sub() -> str:
        return _expr(rng, depth - 1, idx)

    k = rng.randrange(11)
    if k == 0:
        return f"{sub()} + {sub()}"
    if k == 1:
        return rf"{sub()} - {sub()}"
    if k == 2:
        return rf"{sub()} \cdot {sub()}"
    if k == 3:
        return rf"\frac{{{sub()}}}{{2 + ({sub()})^2}}"
    if k == 4:
        return rf"\exp(-({sub()})^2)"
    if k == 5:
        return rf"\tanh({sub()})"
    if k == 6:
        return rf"\sigma({sub()} + 1)"
    if k == 7 and len(idx) < 3:
        j = "jkl"[len(idx) - 1]
        limit = rng.choice([f"{j}<{idx[-1]}", rf"{j} \le {idx[-1]}", f"{j}=1}}^{{{idx[-1]}-1"])
        inner = _expr(rng, depth - 1, idx + [j])
        if rng.random() < 0.5:
            return rf"\sum_{{{limit}}} {inner}"
        body = rf"\exp(-({inner})^2)" if rng.random() < 0.5 else rf"(1 + 0.1 ({inner})^2)"
        return rf"\prod_{{{limit}}} {body}"
    if k == 8:
        return rf"\|[{sub()}, {sub()}]\|"
    if k == 9:
        return rf"\max({sub()}, {sub()})"
    return rf"\begin{{cases}} {sub()} & a_{idx[-1]} > {sub()} \\ {sub()} & \text{{otherwise}} \end{{cases}}"


def _equations(seed: int, count: int) -> list[str]:
    rng = random.Random(seed)
    out = []
    for _ in range(count):
        body = _expr(rng, 4, ["i"])
        out.append(rf"y = \sum_{{i=1}}^{{N}} {body}" if rng.random() < 0.5 else rf"y_i = {body}")
    return out


@pytest.mark.parametrize("latex", _equations(seed=7, count=30), ids=[f"random{k}" for k in range(30)])
def test_random_equations_lower_to_what_the_interpreter_computes(latex):
    eq = parse_equation(latex)
    assert eq, f"{latex}: {eq}"
    report = check_lowering([eq], SPEC, {}, ["y"], n_rays=2, n_samples=5, domains=DOMAINS)
    assert report.ok, f"{latex}\n{show(eq)}\n{report}\n{report.source}"
