"""The plan: one type and one path API, used by every stage that reads or changes a plan.

A plan is a derivation of the grammar (``scene``, ``base``, ``trainer``, ``datamanager``, ``model``,
``optimizers``) plus annotations (``method``, ``description``, ``paper``, ``evidence``, ``pruned``,
``holes``, ``notes``). It is the mapping a plan YAML file holds, so ``Plan`` is a ``dict``: YAML,
JSON, templates and ``validate`` read it as they read any mapping. Every path operation goes through
its methods:

    plan = Plan.load("method_configs/nerfacto.yaml")
    plan.get("model.sampler.proposal.nerf_samples")          # None when absent
    plan.set("model.losses.distortion.weight", 0.01)         # creates missing mappings
    plan.delete("model.camera_optimizer")                    # returns the removed value
    plan.expand("optimizers.*.optimizer")                    # wildcard -> concrete paths
    plan.leaves()                                            # every leaf path and value
"""

from __future__ import annotations

import ast
import copy
import functools
import importlib.util
import json
import keyword
import os
import re
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns import runfolder
from nerfify_ns.errors import NerfifyError

ANNOTATION_KEYS = ("description", "paper", "evidence", "pruned", "holes", "notes", "repairs", "schedule", "family",
                   "contributions")
"""Top-level keys that annotate a plan (not part of the derivation)."""

_MISSING = object()


class PlanPathError(NerfifyError):
    """A path that does not exist where it must, or runs through something that is not a mapping."""


class PlanFileError(NerfifyError):
    """A plan file that cannot be read as a YAML mapping."""


def split_path(path: str) -> list[str]:
    """``"model.sampler.proposal"`` -> ``["model", "sampler", "proposal"]`` (empty parts dropped)."""
    return [part for part in str(path).split(".") if part]


@dataclass
class Hole:
    """A part of the paper no technique card covers: not implemented until something fills it; the base's
    part stands in (``stands_in``) and the report says so."""

    production: str
    slot: str
    contract: dict
    text: str
    equations: list[dict]
    status: str = "not implemented"
    stands_in: str = ""
    section: str = ""
    where: str = ""
    contribution: str = ""
    """The part of the paper it comes from (the ledger's part id and heading)."""
    claim: str = ""
    """The paper's sentence that claims it (empty when the paper claims it in no sentence)."""
    why: str = ""
    """Why it is new (no card's equation matches, a claim no card covers) and why it lands at its production."""
    hyperparameters: list[dict] = field(default_factory=list)
    """The paper's hyperparameters stated in the part's section ({name, value, sentence})."""
    sections: list[str] = field(default_factory=list)
    """The further sections of a contribution developed over sibling subsections (its sentences are the part's)."""

    def to_dict(self) -> dict:
        return asdict(self)


class Plan(dict):
    """A plan mapping with the one path API (see the module docstring)."""

    # ------------------------------------------------------------------ construction and files
    @classmethod
    def of(cls, value: Plan | dict) -> Plan:
        """``value`` itself when it already is a Plan, else a deep copy of the mapping as a Plan."""
        if isinstance(value, Plan):
            return value
        if not isinstance(value, dict):
            raise PlanFileError(f"a plan is a mapping, not a {type(value).__name__}")
        return cls(copy.deepcopy(value))

    @classmethod
    def load(cls, path: str | Path) -> Plan:
        """Read a plan from YAML (or JSON); anything else raises PlanFileError naming the file."""
        from nerfify_ns import safeio

        try:  # bounded: size, depth, and the nodes its aliases expand to
            data = safeio.load_yaml(path, what="the file", max_nodes=200_000)
        except safeio.ReadRefused as exc:
            raise PlanFileError(f"cannot read plan {path}: {str(exc).splitlines()[0]}; "
                                "a plan is a YAML mapping (see method_configs/)") from None
        if not isinstance(data, dict):
            raise PlanFileError(f"{path} is not a plan (a YAML mapping; see method_configs/ for examples)")
        return cls(data)

    def copy(self) -> Plan:  # type: ignore[override]
        """A deep copy (plans nest mappings; a shallow copy would share them)."""
        return Plan(copy.deepcopy(dict(self)))

    def to_dict(self) -> dict:
        """A plain, deep-copied mapping (for JSON, YAML or a subprocess)."""
        return _plain(self)

    def dump(self) -> str:
        """The plan as YAML text, keys in their order."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, width=110, allow_unicode=True)

    # ------------------------------------------------------------------ paths
    def get(self, path: str, default: Any = None) -> Any:  # type: ignore[override]
        """The value at the dot ``path``, ``default`` when any part of it is absent."""
        node: Any = self
        for key in split_path(path):
            if not isinstance(node, dict) or key not in node:
                return default
            node = dict.__getitem__(node, key) if isinstance(node, Plan) else node[key]
        return node

    def has(self, path: str) -> bool:
        """Whether ``path`` exists (a ``*`` matches any key)."""
        if "*" in path:
            return any(self.get(p, _MISSING) is not _MISSING for p in self.expand(path))
        return self.get(path, _MISSING) is not _MISSING

    def set(self, path: str, value: Any, *, create: bool = True) -> Any:
        """Set ``path`` to ``value``; returns the value before (None if absent). Missing mappings on the way
        are created unless ``create`` is False (then PlanPathError)."""
        parent, key = self._parent(path, create=create)
        before = parent.get(key) if isinstance(parent, dict) else None
        parent[key] = value
        return before

    def delete(self, path: str, *, missing_ok: bool = True) -> Any:
        """Remove ``path``; returns the removed value (None when it was absent and ``missing_ok``)."""
        try:
            parent, key = self._parent(path, create=False)
        except PlanPathError:
            if missing_ok:
                return None
            raise
        if key not in parent:
            if missing_ok:
                return None
            raise PlanPathError(f"{path}: not in the plan")
        return parent.pop(key)

    def parent(self, path: str) -> tuple[dict | None, str]:
        """(the mapping holding the last key of ``path`` or None, that key)."""
        try:
            return self._parent(path, create=False)
        except PlanPathError:
            return None, split_path(path)[-1] if split_path(path) else ""

    def expand(self, pattern: str) -> list[str]:
        """Concrete paths matching ``pattern``: ``*`` matches every key of a mapping; a last part that
        is absent is kept (so ``set`` can add it)."""
        results: list[tuple[list[str], Any]] = [([], self)]
        parts = split_path(pattern)
        for i, key in enumerate(parts):
            found = []
            for prefix, node in results:
                if key == "*":
                    if isinstance(node, dict):
                        found.extend((prefix + [k], v) for k, v in node.items())
                elif i == len(parts) - 1 or (isinstance(node, dict) and key in node):
                    found.append((prefix + [key], node.get(key) if isinstance(node, dict) else None))
            results = found
        return [".".join(p) for p, _ in results]

    def leaves(self, root: str = "") -> Iterator[tuple[str, Any]]:
        """Every (path, value) under ``root`` whose value is not a non-empty mapping."""
        node = self.get(root) if root else self
        yield from _leaves(node, root)

    def _parent(self, path: str, *, create: bool) -> tuple[dict, str]:
        parts = split_path(path)
        if not parts:
            raise PlanPathError("an empty plan path")
        node: Any = self
        for i, key in enumerate(parts[:-1]):
            if not isinstance(node, dict):
                raise PlanPathError(f"{path}: {'.'.join(parts[:i]) or '<plan>'} is not a mapping")
            if key not in node:
                if not create:
                    raise PlanPathError(f"{path}: {key!r} is not in the plan")
                node[key] = {}
            node = node[key]
        if not isinstance(node, dict):
            raise PlanPathError(f"{path}: {'.'.join(parts[:-1])} is not a mapping")
        return node, parts[-1]

    # ------------------------------------------------------------------ annotations
    @property
    def method(self) -> str:
        return str(dict.get(self, "method", ""))

    @property
    def base(self) -> str:
        return str(dict.get(self, "base", ""))

    @property
    def evidence(self) -> dict[str, str]:
        """Plan path -> where in the paper (or the base, a card, a citation) the value comes from."""
        return self.setdefault("evidence", {})

    @property
    def holes(self) -> list[dict]:
        return self.setdefault("holes", [])

    @property
    def pruned(self) -> list[dict]:
        return self.setdefault("pruned", [])

    @property
    def notes(self) -> list[str]:
        return self.setdefault("notes", [])

    def evidence_for(self, path: str) -> str:
        """The evidence of ``path``: its own entry, else that of the nearest enclosing path that has one."""
        table = dict.get(self, "evidence") or {}
        parts = split_path(path)
        for i in range(len(parts), 0, -1):
            hit = table.get(".".join(parts[:i]))
            if hit:
                return str(hit)
        return ""

    def derivation(self) -> dict:
        """The derivation part alone (no annotations)."""
        return {k: copy.deepcopy(v) for k, v in self.items() if k not in ANNOTATION_KEYS}


def _leaves(node: Any, prefix: str) -> Iterator[tuple[str, Any]]:
    if isinstance(node, dict) and node:
        for key, value in node.items():
            yield from _leaves(value, f"{prefix}.{key}" if prefix else str(key))
    else:
        yield prefix, node


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return copy.deepcopy(value)


# ---------------------------------------------------------------------- the method's name
# A plan's method name becomes a Nerfstudio method (``ns-train NAME``), a distribution (``nerfify-NAME``) and an
# import package (NAME with '-' -> '_'). ``validate`` checks it with :func:`method_name_problems`, so every way
# into the pipeline (a plan file, a reference plan, a paper) gets the same check.

DISTRIBUTION_PREFIX = "nerfify-"
"""A generated plugin's distribution is ``nerfify-<method>`` (``templates/pyproject.toml.j2``)."""
METHOD_GROUP = "nerfstudio.method_configs"


def package_name(method: str) -> str:
    """The import package of a plugin for ``method`` ('kplanes-static' -> 'kplanes_static')."""
    package = re.sub(r"[^a-z0-9]+", "_", str(method).lower()).strip("_")
    return package if package[:1].isalpha() else f"m_{package}"


def _normalise(distribution: str) -> str:
    return re.sub(r"[-_.]+", "-", distribution).lower()


def _source_of(module: str) -> Path | None:
    """The source file of an installed module, found without importing it."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    return Path(spec.origin) if spec is not None and spec.origin and os.path.isfile(spec.origin) else None


def _assigned_keys(tree: ast.AST, target: str) -> list[str]:
    """String keys of ``target[...] = ...`` assignments and of a ``target = {...}`` dict literal."""
    keys = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                if (isinstance(t, ast.Subscript) and isinstance(t.value, ast.Name) and t.value.id == target
                        and isinstance(t.slice, ast.Constant) and isinstance(t.slice.value, str)):
                    keys.append(t.slice.value)
                if isinstance(t, ast.Name) and t.id == target and isinstance(node.value, ast.Dict):
                    keys += [k.value for k in node.value.keys if isinstance(k, ast.Constant)
                             and isinstance(k.value, str)]
    return keys


@functools.lru_cache(maxsize=1)
def nerfstudio_builtin_methods() -> frozenset[str]:
    """The method names Nerfstudio itself defines (its ``method_configs`` and the external methods it offers to
    install), read from its source without importing it (no torch for a dry run); plus those of
    $NERFSTUDIO_METHOD_CONFIGS."""
    names = set()
    configs = _source_of("nerfstudio.configs.method_configs")
    if configs is not None:
        tree = ast.parse(configs.read_text(encoding="utf-8"))
        names.update(_assigned_keys(tree, "method_configs") + _assigned_keys(tree, "descriptions"))
    external = _source_of("nerfstudio.configs.external_methods")
    if external is not None:
        for node in ast.walk(ast.parse(external.read_text(encoding="utf-8"))):
            if isinstance(node, ast.keyword) and node.arg == "configurations" and isinstance(node.value, ast.List):
                names.update(e.elts[0].value for e in node.value.elts if isinstance(e, ast.Tuple) and e.elts
                             and isinstance(e.elts[0], ast.Constant) and isinstance(e.elts[0].value, str))
    for definition in os.environ.get("NERFSTUDIO_METHOD_CONFIGS", "").split(","):
        if "=" in definition:
            names.add(definition.split("=", 1)[0].strip())
    return frozenset(names)


@functools.lru_cache(maxsize=1)
def installed_plugins() -> tuple[tuple[str, str, str], ...]:
    """(method, entry point value, distribution) of every installed Nerfstudio plugin."""
    from importlib.metadata import entry_points

    found = []
    for ep in entry_points(group=METHOD_GROUP):
        dist = getattr(getattr(ep, "dist", None), "name", None) or ""
        found.append((ep.name, ep.value, dist))
    return tuple(found)


def _nerfify_plugin_package(origin: Path, package: str) -> bool:
    """Whether ``origin`` (a module's file) is package ``package`` of a plugin folder nerfify generated."""
    folder = origin.parent if origin.name == "__init__.py" else None
    if folder is None or folder.name != package:
        return False
    try:
        return json.loads((folder.parent / runfolder.PLUGIN_META).read_text()).get("package") == package
    except (OSError, ValueError, AttributeError):
        return False


@functools.lru_cache(maxsize=1)
def _packages_distributions() -> dict[str, list[str]]:
    from importlib.metadata import packages_distributions

    return packages_distributions()


def _module_owner(package: str) -> str | None:
    """What an importable top-level module ``package`` is, when it is not an earlier build of our plugin of
    that name (None: nothing, or that earlier build)."""
    if package in sys.builtin_module_names or package in getattr(sys, "stdlib_module_names", ()):
        return "a module of Python's standard library"
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    if spec.origin and _nerfify_plugin_package(Path(spec.origin), package):
        return None
    for location in spec.submodule_search_locations or ():
        if _nerfify_plugin_package(Path(location) / "__init__.py", package):
            return None
    dists = _packages_distributions().get(package, [])
    method = package.replace("_", "-")
    if any(_normalise(d) == _normalise(DISTRIBUTION_PREFIX + method) for d in dists):
        return None
    where = f" (from {', '.join(sorted(dists))})" if dists else f" ({spec.origin})" if spec.origin else ""
    return f"an installed module{where}"


def method_name_problems(method: str) -> list[tuple[str, str]]:
    """(rule, message) for each reason ``method`` cannot name a plugin: its distribution ``nerfify-<method>`` is
    not a valid project name, its import package is a Python keyword (rule ``method_name``), or it shadows
    a Nerfstudio built-in method, another installed plugin or an importable module (rule ``method_shadows``).
    An earlier build of the same plugin (``nerfify-<method>`` installed, or its generated folder on the path)
    is not a clash. ``method`` is assumed to match the grammar's pattern (lower case, digits, '-')."""
    problems = []
    if method.endswith("-"):
        problems.append(("method_name", f"{method!r} ends with '-': the distribution "
                         f"'{DISTRIBUTION_PREFIX}{method}' would not be a valid project name"))
    package = package_name(method)
    if keyword.iskeyword(package) or not package.isidentifier():
        problems.append(("method_name", f"{method!r} gives the import package {package!r}, a Python keyword; "
                         "choose another name"))
    if problems:
        return problems
    if method in nerfstudio_builtin_methods():
        return [("method_shadows", f"{method!r} shadows Nerfstudio's built-in method of that name "
                 f"(`ns-train {method}`); choose another name, e.g. '{method}-ref'")]
    for name, value, dist in installed_plugins():
        if name == method and _normalise(dist) != _normalise(DISTRIBUTION_PREFIX + method):
            return [("method_shadows", f"{method!r} shadows the installed Nerfstudio plugin {name!r} ({value}, "
                     f"from {dist or 'an unknown distribution'}); choose another name")]
    owner = _module_owner(package)
    if owner:
        return [("method_shadows", f"{method!r} gives the import package {package!r}, which would shadow "
                 f"{owner}; choose another name")]
    return []


def free_method_name(method: str, suffix: str = "paper") -> str:
    """``method`` when it can name a plugin, else ``method-<suffix>`` (a paper titled 'TensoRF' or 'Import')."""
    if not method_name_problems(method):
        return method
    return f"{method[:62 - len(suffix)].rstrip('-')}-{suffix}"


yaml.add_representer(Plan, yaml.representer.SafeRepresenter.represent_dict, Dumper=yaml.SafeDumper)
yaml.add_representer(Plan, yaml.representer.Representer.represent_dict, Dumper=yaml.Dumper)
