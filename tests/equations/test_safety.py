"""A paper is untrusted input that becomes code: nothing of its text reaches the emitted source except
through the IR (generated identifiers, float literals, comments made safe)."""

from __future__ import annotations

import ast
import io
import re
import tokenize

import numpy as np
import pytest
import torch

from nerfify_ns.equations import (
    Apply,
    BinOp,
    Equation,
    LoweringError,
    Number,
    ParamSpec,
    ParseFailure,
    Symbol,
    lower_module,
    parse_equation,
)
from nerfify_ns.equations.naming import RESERVED

EVIL = [
    "__import__('os').system('rm -rf /')",
    'a"""\nimport os\nos.system("id")\n"""',
    "x'; exec('print(1)'); '",
    "\n\r\x00\x1b[31m#",
    "\u03c3\u202e\u200b\u540d\u524d",
    "A" * 10_000,
    "self.__class__.__bases__[0].__subclasses__()",
    "torch.load",
    "__builtins__",
]
MARKERS = ["__import__", "system", "rm -rf", '"""', "exec", "__class__", "__subclasses__", "__builtins__",
           "torch.load", "\x00", "\u202e"]

TORCH_ATTRIBUTES = {
    "exp", "log", "sin", "cos", "tan", "tanh", "sigmoid", "relu", "functional", "softplus", "abs", "sqrt", "ceil",
    "floor", "sum", "prod", "mean", "cumsum", "cumprod", "cat", "zeros_like", "ones_like", "narrow", "shape", "ones",
    "bool", "device", "tril", "is_tensor", "full", "dtype", "broadcast_shapes", "expand", "linalg", "vector_norm",
    "amax", "minimum", "maximum", "clamp", "where", "detach", "permute", "linear", "Module", "Parameter", "empty",
    "register_buffer", "init", "normal_", "ones_", "zeros_", "kaiming_uniform_", "no_grad", "as_tensor", "__init__",
    "log1p", "nn", "reset_parameters",
}


def _code_without_comments(source: str) -> str:
    tokens = [t for t in tokenize.generate_tokens(io.StringIO(source).readline) if t.type != tokenize.COMMENT]
    return tokenize.untokenize(tokens)


def assert_safe(lowered) -> None:
    source = lowered.source
    tree = ast.parse(source)
    ours = set(lowered.names) | {lowered.class_name} | RESERVED
    attrs = {attr for attr, _ in lowered.params.values()}
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef) and ast.get_docstring(node) is not None:
            docstrings.add(id(node.body[0].value))
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            assert node.id in ours, f"identifier {node.id!r} is not ours"
        elif isinstance(node, ast.arg):
            assert node.arg in ours, f"argument {node.arg!r} is not ours"
        elif isinstance(node, ast.FunctionDef | ast.ClassDef):
            assert node.name in ours
        elif isinstance(node, ast.Attribute):
            assert node.attr in TORCH_ATTRIBUTES | attrs, f"attribute {node.attr!r}"
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            assert id(node) in docstrings or node.value in attrs, f"string {node.value!r} reached the code"
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names = {a.name for a in node.names}
            assert names <= {"math", "torch", "nn"} and getattr(node, "module", None) in (None, "torch")
        elif isinstance(node, ast.Lambda | ast.Global | ast.Nonlocal | ast.JoinedStr):
            raise AssertionError(f"{type(node).__name__} in generated code")
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            assert tok.string.isascii() and tok.string.isprintable() and len(tok.string) <= 220, tok.string
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            for marker in MARKERS:
                assert marker not in node.value or marker == '"""', f"{marker!r} reached a string"
    for ident in lowered.names:
        assert re.fullmatch(r"[a-z]+_[a-z0-9_]{1,30}", ident), ident
    code = _code_without_comments(source)
    assert "import os" not in code and "__import__" not in code and "exec(" not in code
    assert source.isascii()


@pytest.mark.parametrize("evil", EVIL, ids=[f"evil{k}" for k in range(len(EVIL))])
def test_hostile_symbol_names_and_numbers_never_reach_the_code(evil):
    x = Symbol(evil, subscripts=(evil[:50],), superscript=evil[:20], decorations=("hat",))
    weight = Symbol("W" + evil)
    out = Symbol(evil + "out")
    rhs = Apply("tanh", (BinOp("+", BinOp("*", weight, x), Number(0.5, evil)),))
    eq = Equation(out, rhs, number=evil, source=evil)
    lowered = lower_module([eq], {x.key: ("R", 3)}, [out.key], {weight.key: (4, 3)}, "Hostile")
    assert_safe(lowered)
    namespace: dict = {}
    exec(compile(lowered.source, "<hostile>", "exec"), namespace)  # the generated code runs
    result = namespace["Hostile"]()(torch.rand(2, 3))
    assert result.shape == (2, 4)
    assert lowered.names[lowered.outputs[0][1]] == out.key  # the mapping keeps the paper's symbol


HOSTILE_LATEX = [
    r"y = \operatorname{__import__('os').system}(x)",
    r"y = \operatorname{__import__('os').system} x",
    r"y = \text{\"\"\"; import os}",
    r"y = \mathrm{os}.system(x)",
    "y = x \\\\\n import os",
    r"y = x \tag{1'); import os; ('}",
    r"\mathrm{exec} = \mathrm{eval} + \mathrm{open}",
    r"\mathrm{self} = \mathrm{torch} \cdot \mathrm{nn} + \mathrm{super}",
    "y = x_{" + "a" * 500 + "}",
    r"y = \mathrm{" + "B" * 40 + "}",
    "y = \u00e9\u00e8 + x",
]


@pytest.mark.parametrize("latex", HOSTILE_LATEX, ids=[f"latex{k}" for k in range(len(HOSTILE_LATEX))])
def test_hostile_equations_fail_or_lower_to_safe_code(latex):
    eq = parse_equation(latex)
    if isinstance(eq, ParseFailure):
        assert eq.reason  # a typed reason, never a guess
        return
    symbols = {n.key for n in ast_free_symbols(eq)}
    lowered = lower_module([eq], {key: ("R", 2) for key in symbols}, [eq.defines], {}, "FromPaper")
    assert_safe(lowered)


def ast_free_symbols(eq: Equation):
    from nerfify_ns.equations.ir import walk

    return [n for n in walk(eq.rhs) if isinstance(n, Symbol)]


def test_reserved_words_of_the_paper_become_our_identifiers():
    eq = parse_equation(r"\mathrm{self} = \mathrm{torch} \cdot \mathrm{nn} + \mathrm{super}")
    lowered = lower_module([eq], {"torch": ("R",), "nn": ("R",), "super": ("R",)}, ["self"])
    assert {ident for _, ident, _ in lowered.inputs} == {"v_torch", "v_nn", "v_super"}
    assert lowered.outputs == [("self", "v_self")]
    assert_safe(lowered)


def test_what_cannot_be_written_safely_is_refused():
    eq = parse_equation(r"y = x")
    with pytest.raises(LoweringError):
        lower_module([eq], {"x": ("R",)}, ["y"], {}, "Bad(nn.Module): pass\nclass X")
    nan = Equation(Symbol("y"), BinOp("*", Symbol("x"), Number(float("nan"))))
    with pytest.raises(LoweringError):
        lower_module([nan], {"x": ("R",)}, ["y"])
    with pytest.raises(LoweringError):
        lower_module([eq], {"x": ("R",)}, ["y"], {"W": ParamSpec((2, 2), init="normal", std=float("inf"))})


def test_long_names_are_truncated_and_kept_apart():
    a, b = "alpha" * 40 + "1", "alpha" * 40 + "2"
    eq = Equation(Symbol("y"), BinOp("+", Symbol(a), Symbol(b)))
    lowered = lower_module([eq], {a: ("R",), b: ("R",)}, ["y"])
    idents = [ident for _, ident, _ in lowered.inputs]
    assert len(set(idents)) == 2 and all(len(i) <= 30 for i in idents)
    namespace: dict = {}
    exec(compile(lowered.source, "<long>", "exec"), namespace)
    out = namespace["CompiledEquations"]()(torch.ones(2, dtype=torch.float64), 2 * torch.ones(2, dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [3.0, 3.0])
