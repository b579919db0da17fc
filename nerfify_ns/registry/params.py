"""Typed terminal parameters: a dataclass per terminal, one field per parameter, as Nerfstudio's configs.

    @dataclass
    class Hash:
        num_levels: int = param(16, range=(1, 32))
        '''Number of resolution levels L.'''

``param_specs(Hash)`` reads the type from the annotation (``int``, ``float``, ``bool``, ``str``,
``Literal[...]`` for an enum, ``List[int]`` / ``List[float]`` / ``List[str]`` for lists, ``Dict[str, Any]``
for a mapping), the default, range and list length from ``param(...)``, and the documentation from
the docstring under the field (read from the class source, as tyro does).
"""

from __future__ import annotations

import ast
import copy
import dataclasses
import functools
import inspect
import keyword
import textwrap
import typing
from dataclasses import dataclass
from typing import Any

PARAM_TYPES = ("int", "float", "bool", "str", "enum", "int_list", "float_list", "str_list", "mapping")

_META = "nerfify"


@dataclass(frozen=True)
class ParamSpec:
    """A typed terminal parameter: type, inclusive range, allowed values, list length, default, doc."""

    name: str
    type: str
    default: Any = None
    range: tuple[float | None, float | None] | None = None
    values: tuple[Any, ...] = ()
    length: tuple[int, int] | None = None
    doc: str = ""

    def to_data(self) -> dict:
        """The parameter as the grammar export writes it."""
        data: dict[str, Any] = {"type": self.type}
        if self.values:
            data["values"] = list(self.values)
        if self.length is not None:
            data["length"] = list(self.length)
        if self.range is not None:
            data["range"] = list(self.range)
        data["default"] = self.default
        if self.doc:
            data["doc"] = self.doc
        return data


def param(default: Any, *, range: tuple[float | None, float | None] | None = None,
          length: tuple[int, int] | None = None, doc: str = "") -> Any:
    """A dataclass field holding a terminal parameter: its default, numeric range and list length (``doc``: where
    the class has no source to read the docstring under the field from, as for a class built from data)."""
    meta = {_META: {"range": range, "length": length, "doc": doc}}
    if isinstance(default, list | dict):
        value = default
        return dataclasses.field(default_factory=lambda: _copy(value), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _copy(value: Any) -> Any:
    return [*value] if isinstance(value, list) else dict(value)


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring written under each field of ``cls`` or of a base class it inherits the field from
    (cached: reading a class's source is slow and the source does not change in a process)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is not object:
            docs.update(_own_field_docs(klass))
    return docs


def _own_field_docs(cls: type) -> dict[str, str]:
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError, SyntaxError):
        return {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    docs: dict[str, str] = {}
    for node, after in zip(body, body[1:], strict=False):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) \
                and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) \
                and isinstance(after.value.value, str):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def _kind(annotation: Any) -> tuple[str, tuple[Any, ...]]:
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if annotation in (int, float, bool, str):
        return annotation.__name__, ()
    if origin is typing.Literal:
        return "enum", tuple(args)
    if origin in (list, tuple) and args:
        item = args[0]
        if item in (int, float, str):
            return f"{item.__name__}_list", ()
    if origin is dict or annotation is dict:
        return "mapping", ()
    raise TypeError(f"unsupported parameter annotation {annotation!r}")


def param_specs(cls: type) -> dict[str, ParamSpec]:
    """The ParamSpecs of a parameter dataclass, in field order (a fresh copy: callers may edit it)."""
    return {name: dataclasses.replace(spec, default=copy.deepcopy(spec.default))
            for name, spec in _param_specs(cls).items()}


def param_defaults(cls: type) -> dict[str, Any]:
    """The defaults of a parameter dataclass, in field order (a fresh copy: callers may edit it)."""
    return {name: copy.deepcopy(spec.default) if isinstance(spec.default, list | dict) else spec.default
            for name, spec in _param_specs(cls).items()}


@functools.cache
def _param_specs(cls: type) -> dict[str, ParamSpec]:
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    specs: dict[str, ParamSpec] = {}
    for f in dataclasses.fields(cls):
        kind, values = _kind(hints[f.name])
        meta = f.metadata.get(_META, {})
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        rng = meta.get("range")
        name = f.name.rstrip("_")  # `class_` is the parameter `class` (a Python keyword)
        specs[name] = ParamSpec(name=name, type=kind, default=default, values=values,
                                range=tuple(rng) if rng is not None else None,
                                length=tuple(meta["length"]) if meta.get("length") else None,
                                doc=docs.get(f.name) or meta.get("doc") or "")
    return specs


_ANNOTATIONS = {"int": int, "float": float, "bool": bool, "str": str, "int_list": list[int],
                "float_list": list[float], "str_list": list[str], "mapping": dict[str, Any]}


class ParamTypeError(ValueError):
    """A parameter written as data has a type that is not one of :data:`PARAM_TYPES`."""


def params_class_from_data(owner: str, raw: dict[str, dict]) -> type:
    """The parameter dataclass of terminal ``owner`` from its export (``ParamSpec.to_data`` per parameter)."""
    fields = []
    for name, spec in raw.items():
        kind = spec.get("type")
        if kind not in PARAM_TYPES:
            raise ParamTypeError(f"terminal {owner}: parameter {name} has unknown type {kind!r}")
        annotation = typing.Literal[tuple(spec.get("values", ()))] if kind == "enum" else _ANNOTATIONS[kind]
        rng, length = spec.get("range"), spec.get("length")
        fields.append((f"{name}_" if keyword.iskeyword(name) else name, annotation,
                       param(spec.get("default"), range=tuple(rng) if rng is not None else None,
                             length=tuple(length) if length else None, doc=spec.get("doc", ""))))
    return dataclasses.make_dataclass(f"{owner.title().replace('_', '').replace('-', '')}Params", fields)
