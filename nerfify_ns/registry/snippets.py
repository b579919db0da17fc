"""Rendering terminal code: the one Jinja2 environment for snippets, and evaluation of the same code in
the probe (so the ladder checks the code a plugin gets, not a second copy of it)."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import jinja2

from nerfify_ns.registry.terminal import Code


def py(value: Any) -> str:
    """A Python literal for a plan value (lists become tuples, as Nerfstudio's configs use)."""
    if isinstance(value, list | tuple):
        items = ", ".join(py(v) for v in value)
        return f"({items},)" if len(value) == 1 else f"({items})"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{py(k)}: {py(v)}" for k, v in value.items()) + "}"
    return repr(value)


SNIPPETS = jinja2.Environment(undefined=jinja2.StrictUndefined, keep_trailing_newline=False)
SNIPPETS.filters["tuple_literal"] = py


def render(text: str, params: Mapping[str, Any], package: str = "", **extra: Any) -> str:
    """A snippet (a Jinja2 expression over the parameters ``p``) rendered for a plugin."""
    return SNIPPETS.from_string(text).render(p=dict(params), package=package, **extra)


_RELATIVE_COMPONENTS = re.compile(r"^from \.components(\.\w+)? import")


def _namespace(imports: Iterable[str]) -> dict[str, Any]:
    """Execute import lines (a plugin's ``.components`` are ours, ``nerfify_ns.components``)."""
    namespace: dict[str, Any] = {}
    exec("from torch import nn\nimport torch", namespace)  # noqa: S102 - our own registry's lines
    for line in imports:
        line = _RELATIVE_COMPONENTS.sub(lambda m: f"from nerfify_ns.components{m.group(1) or ''} import", line)
        exec(line, namespace)  # noqa: S102
    return namespace


def build_from_code(code: Code, params: Mapping[str, Any]) -> Any:
    """The component a terminal's ``ctor`` builds with ``params``, evaluated as a plugin would."""
    if not code.ctor:
        raise ValueError("the terminal renders no constructor")
    return eval(render(code.ctor, params), _namespace(code.imports))  # noqa: S307 - our own registry's code


def compile_expression(code: Code, variable: str) -> Callable[[Any], Any]:
    """A function of one tensor evaluating the terminal's ``expr`` with ``{{ x }}`` bound to it."""
    source = render(code.expr or "", {}, x=variable)
    compiled = compile(source, "<terminal expression>", "eval")
    namespace = _namespace(code.imports)
    return lambda value: eval(compiled, {**namespace, variable: value})  # noqa: S307
