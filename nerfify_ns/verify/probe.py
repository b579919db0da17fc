"""The probe: the part of the ladder that executes plugin code, run only as a sandboxed subprocess.

    python -m nerfify_ns.verify.probe PLUGIN_DIR EVENTS_JSONL --rungs static,contract,stability [--suite all]
        [--records FD --seed N]

It runs plugin code and judges none of it: with ``--records`` it sends, down a pipe our process holds,
``{"kind": "event", "rung", "event": "start"|"end"|"diagnosis"}`` and one record per check to make (a
component on a case, the assembled field, a model step, the parameter groups) carrying the raw values as
arrays; the checker (:mod:`nerfify_ns.verify.checker`, in our process, which never imports plugin code)
computes the verdicts. ``--seed`` (drawn by the ladder from ``os.urandom``) moves every example input, so a
component cannot know them in advance. The same events are also written, one JSON object per line, to
EVENTS_JSONL for reading by people (never for a verdict). A rung that started and never ended was killed
(timeout, memory).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import json
import os
import sys
import traceback
import warnings
from pathlib import Path

import numpy as np

from nerfify_ns import runfolder


def module_name(rel: str) -> str:
    parts = rel[:-3].split("/")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def plugin_classes(modules: dict[str, object]):
    for rel, module in modules.items():
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if cls.__module__ == module.__name__:
                yield rel, cls


def _target_line(cls) -> int | None:
    try:
        lines, start = inspect.getsourcelines(cls)
    except (OSError, TypeError):
        return None
    return next((start + i for i, text in enumerate(lines) if text.strip().startswith("_target")), None)


def _import(path: str):
    module, _, attr = path.rpartition(".")
    return getattr(importlib.import_module(module), attr)


def used_terminals(plan: dict) -> dict[str, str]:
    from nerfify_ns.grammar import load_grammar, validate

    return dict(validate(plan, load_grammar()).used)


def model_step(model, case: str = "nominal"):
    from nerfify_ns.verify.assembled import train_step

    return train_step(model, case)


def _owner(terminal: str) -> tuple:
    """(implementation, owner) of a terminal: ours (nerfify_ns), the plugin's (custom) or Nerfstudio's."""
    from nerfify_ns.registry import default_registry

    if terminal == "custom":
        return "the plugin's own component", "plugin"
    implementation = default_registry()[terminal].implementation
    return implementation, "ours" if implementation.startswith("nerfify_ns.") else "nerfstudio"


ADVISORY_CASES = ("empty_batch", "half")
"""Model cases recorded but not gating: Nerfstudio's own samplers and losses fail on them (see the report)."""


class Probe:
    """One probe run: the plugin (root folder, package, plan), the events file, the rungs that failed and the
    models built so far (building a Nerfstudio model costs seconds, so one per scene scale is shared)."""

    def __init__(self, events, root: Path = Path("."), package: str = "", plan=None, pipe=None) -> None:
        self.events = events
        self.pipe = pipe  # the checker's record pipe (None: the component suite alone, judged here)
        self.root = root
        self.package = package
        self.plan = plan  # the plugin's plan (a nerfify_ns.plan.Plan), None for a hand-written plugin
        self.failed: set = set()
        self.models: dict[float, object] = {}
        self.last_rung: str | None = None

    def emit(self, **event) -> None:
        self.events.write(json.dumps(event, default=str) + "\n")
        self.events.flush()
        if self.pipe is not None:
            self.pipe.send({"kind": "event", **event})

    def send(self, header: dict, arrays=None) -> None:
        """One record for the checker."""
        self.pipe.send(header, arrays)

    def plugin_frame(self, tb) -> tuple:
        """(file, line) of the innermost traceback frame inside the plugin folder, else (None, None)."""
        found = (None, None)
        for frame in traceback.extract_tb(tb):
            try:
                rel = Path(frame.filename).resolve().relative_to(self.root)
            except ValueError:
                continue
            found = (str(rel), frame.lineno)
        return found

    def diagnose(
        self,
        rung: str,
        rule: str,
        message: str,
        file=None,
        line=None,
        exc: BaseException | None = None,
        **extra,
    ) -> None:
        self.failed.add(rung)
        text = ""
        if exc is not None:
            text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__)[-6:])[-2000:]
            if file is None:
                file, line = self.plugin_frame(exc.__traceback__)
        self.emit(
            event="diagnosis",
            rung=rung,
            rule=rule,
            message=message,
            file=file,
            line=line,
            traceback=text,
            **extra,
        )

    def class_line(self, cls) -> tuple:
        try:
            file = Path(inspect.getsourcefile(cls)).resolve().relative_to(self.root)
            return str(file), inspect.getsourcelines(cls)[1]
        except (TypeError, OSError, ValueError):
            return None, None

    # ----------------------------------------------------------------------------- static
    def check_imports(self, files: list[str]) -> dict[str, object]:
        """Resolve every import statement of every file; import the plugin's own modules."""
        modules = {}
        for rel in files:
            try:
                tree = ast.parse((self.root / rel).read_text())
            except SyntaxError:
                continue
            name = module_name(rel)
            package = name if rel.endswith("__init__.py") else name.rpartition(".")[0]
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    targets = [(a.name, None) for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    base = (
                        importlib.util.resolve_name("." * node.level + (node.module or ""), package)
                        if node.level
                        else node.module
                    )
                    targets = [(base, a.name) for a in node.names]
                else:
                    continue
                for mod, attr in targets:
                    try:
                        imported = importlib.import_module(mod)
                        if attr and attr != "*" and not hasattr(imported, attr):
                            importlib.import_module(f"{mod}.{attr}")
                    except Exception as exc:  # any failure of untrusted code is a finding
                        what = f"{mod}.{attr}" if attr else mod
                        self.diagnose(
                            "static",
                            "import",
                            f"import of {what} fails: {type(exc).__name__}: {exc}",
                            rel,
                            node.lineno,
                            exc if not isinstance(exc, ImportError) else None,
                        )
            try:
                modules[rel] = importlib.import_module(name)
            except Exception as exc:
                self.diagnose(
                    "static",
                    "import",
                    f"module {name} cannot be imported: {type(exc).__name__}: {exc}",
                    exc=exc,
                )
        return modules

    def check_classes(self, modules, base: dict | None) -> None:
        from nerfstudio.fields.base_field import Field
        from nerfstudio.models.base_model import Model, ModelConfig

        for _, cls in plugin_classes(modules):
            file, line = self.class_line(cls)
            name = cls.__name__
            if name.endswith("ModelConfig") and not issubclass(cls, ModelConfig):
                self.diagnose(
                    "static", "base-class", f"{name} must subclass nerfstudio ModelConfig", file, line
                )
            elif (
                not name.endswith("Config")
                and (name.endswith("Model") or "populate_modules" in vars(cls))
                and not issubclass(cls, Model)
            ):
                self.diagnose("static", "base-class", f"{name} must subclass nerfstudio's Model", file, line)
            elif (name.endswith("Field") or "get_density" in vars(cls)) and not issubclass(cls, Field):
                self.diagnose(
                    "static",
                    "base-class",
                    f"{name} must subclass nerfstudio's Field " "(nerfstudio.fields.base_field.Field)",
                    file,
                    line,
                )
            if isinstance(cls, type) and issubclass(cls, ModelConfig) and cls is not ModelConfig:
                self.check_target(cls, file, line, base)

    def check_target(self, cfg_cls, file, line, base: dict | None) -> None:
        from nerfstudio.models.base_model import Model

        try:
            target = cfg_cls()._target
        except Exception as exc:
            self.diagnose(
                "static", "config-target", f"{cfg_cls.__name__}() cannot be built: {exc}", file, line, exc
            )
            return
        tline = _target_line(cfg_cls) or line
        if not (isinstance(target, type) and issubclass(target, Model)):
            self.diagnose(
                "static",
                "config-target",
                f"{cfg_cls.__name__}._target is {target!r}, not a Model class",
                file,
                tline,
            )
            return
        annotated = target.__dict__.get("__annotations__", {}).get("config")
        annotated = getattr(annotated, "__name__", annotated)
        expected = cfg_cls.__name__[: -len("Config")]
        if (
            annotated is not None
            and annotated != cfg_cls.__name__
            or annotated is None
            and target.__name__ != expected
        ):
            self.diagnose(
                "static",
                "config-target",
                f"{cfg_cls.__name__}._target builds {target.__module__}."
                f"{target.__name__}, not the model this config belongs to ({expected})",
                file,
                tline,
            )
        elif base and not issubclass(target, _import(f"{base['module']}.{base['model_class']}")):
            self.diagnose(
                "static",
                "base-class",
                f"{target.__name__} must derive from the plan's base " f"{base['model_class']}",
                *self.class_line(target),
            )

    def load_spec(self, config: str, entry_line):
        from nerfstudio.plugins.types import MethodSpecification

        module_name_, _, var = config.partition(":")
        try:
            spec = getattr(importlib.import_module(module_name_), var)
        except Exception as exc:
            self.diagnose(
                "static",
                "entry-point",
                f"entry point {config} does not resolve: {type(exc).__name__}: {exc}",
                "pyproject.toml",
                entry_line,
                exc if not isinstance(exc, ImportError | AttributeError) else None,
            )
            return None
        if not isinstance(spec, MethodSpecification):
            self.diagnose(
                "static",
                "entry-point",
                f"entry point {config} is a {type(spec).__name__}, not a " "MethodSpecification",
                "pyproject.toml",
                entry_line,
            )
            return None
        return spec

    def optimizers_line(self, config_module: str) -> tuple:
        rel = config_module.replace(".", "/") + ".py"
        try:
            tree = ast.parse((self.root / rel).read_text())
        except (OSError, SyntaxError):
            return rel, None
        line = next(
            (n.lineno for n in ast.walk(tree) if isinstance(n, ast.keyword) and n.arg == "optimizers"), None
        )
        return rel, line

    def shared_model(self, spec, scale: float = 1.0):
        """One model per scene scale for the whole probe (building a Nerfstudio model costs seconds)."""
        from nerfify_ns.verify.assembled import build_model

        if scale not in self.models:
            self.models[scale] = build_model(spec, scale)
        model = self.models[scale]
        model.zero_grad(set_to_none=True)
        return model

    def check_param_groups(self, spec, config_module: str):
        try:
            model = self.shared_model(spec)
        except Exception as exc:
            self.diagnose(
                "static",
                "model-build",
                f"the model cannot be built from its config: {type(exc).__name__}: {exc}",
                exc=exc,
            )
            return None
        groups = {k: v for k, v in model.get_param_groups().items()}
        keys = set(spec.config.optimizers)
        file, line = self.optimizers_line(config_module)
        if self.pipe is not None:  # judged by the checker
            self.send({"kind": "param_groups", "rung": "static", "groups": {k: len(list(v)) for k, v in groups.items()},
                       "optimizers": sorted(keys), "file": file, "line": line})
            return model
        missing, extra = sorted(set(groups) - keys), sorted(keys - set(groups))
        empty = sorted(k for k, v in groups.items() if not list(v))
        if missing or extra:
            self.diagnose(
                "static",
                "param-groups",
                f"model parameter groups {sorted(groups)} != optimizer keys "
                f"{sorted(keys)} (missing optimizers: {missing}; optimizers without a group: {extra})",
                file,
                line,
                missing=missing,
                extra=extra,
            )
        if empty:
            self.diagnose(
                "static", "param-groups", f"parameter groups without parameters: {empty}", file, line
            )
        return model

    # ----------------------------------------------------------------------------- contract / stability
    def component_of(self, path: str, terminal: str):
        """(name, contract-checking function of a case) of the component at ``path``; None when the terminal
        lives inside a Nerfstudio model (checked through the assembled model) or has no contract."""
        from nerfify_ns.grammar import load_grammar
        from nerfify_ns.registry import default_registry
        from nerfify_ns.verify.components import run_custom, run_terminal

        registry = default_registry()
        if terminal == "custom":
            production = load_grammar().production_at(path)
            interface = registry.interfaces.get(production or "")
            if interface is None:
                return None
            entry = self.plan.get(path) or {}
            return (
                f"custom {entry.get('class')} ({production})",
                interface.cases,
                lambda case: run_custom(interface, entry, self.package, case),
            )
        defn = registry[terminal]
        if defn.harness.in_model or defn.contract.empty:
            return None
        params = self.plan.get(path) if isinstance(self.plan.get(path), dict) else {}
        return terminal, defn.harness.cases, lambda case: run_terminal(defn, params, case)

    def _plan_components(self) -> list[tuple]:
        """(path, terminal, name, cases, run) of every component of the plan with a contract."""
        found = []
        for path, terminal in used_terminals(self.plan).items():
            component = self.component_of(path, terminal)
            if component is not None:
                found.append((path, terminal, *component))
        return found

    def record_components(self, rung: str, cases_of) -> None:
        """One record per component of the plan and case (``cases_of(spec)``), for the checker."""
        from nerfify_ns.verify.checker import component_specs
        from nerfify_ns.verify.components import record_spec

        for spec in component_specs(self.plan):
            implementation, owner = _owner(spec["terminal"])
            for case in cases_of(spec):
                header, arrays = record_spec(self.pipe.cap, spec, self.package, case)
                self.send({"kind": "component", "rung": rung, "component": spec["name"], "path": spec["path"],
                           "case": case, "owner": owner, "implementation": implementation, **header}, arrays)

    def contract_rung(self, spec, plan: dict | None) -> None:
        if self.pipe is not None:
            if plan is not None:
                self.record_components("contract", lambda s: ["nominal"])
            self.assembled_contract(spec)
            return
        if plan is not None:
            for path, _terminal, name, _cases, run in self._plan_components():
                result = run("nominal").to_dict()
                self.emit(event="component", rung="contract", component=name, path=path, **result)
                if result["status"] == "fail":
                    self.diagnose(
                        "contract",
                        "component-contract",
                        f"{name} ({path}): " + "; ".join(result["problems"]),
                        runfolder.PLAN,
                        None,
                        component=name,
                    )
        self.assembled_contract(spec)

    def model_record(self, model, rung: str, case: str, outputs, losses, require: bool) -> None:
        """Outputs and losses of a model step as arrays, and the summed absolute gradient of every trainable
        parameter of an optimiser group (None: no gradient arrived), for the checker."""
        from nerfify_ns.verify.checker import MODEL_OUTPUTS

        cap = self.pipe.cap
        arrays = {}
        for key in MODEL_OUTPUTS:
            if cap.is_tensor(outputs.get(key)):
                arrays[f"out:{key}"] = cap.array(outputs[key])[0]
        for key, value in losses.items():
            if cap.is_tensor(value):
                arrays[f"loss:{key}"] = cap.array(value)[0]
        ids = {id(p) for params in model.get_param_groups().values() for p in params}
        grads = {name: cap.abs_sum(p.grad) for name, p in model.named_parameters()
                 if id(p) in ids and p.requires_grad}
        owners = {name: list(self.owner_line(model, name)) for name, g in grads.items() if g is None} if require else {}
        self.send({"kind": "model", "rung": rung, "component": "<model>", "case": case, "status": "ran",
                   "owner": "plugin", "grads": grads, "owners": owners}, arrays)

    def assembled_contract(self, spec) -> None:
        import torch

        if self.pipe is not None:
            return self.assembled_contract_records(spec)

        from nerfify_ns.registry.contract import finite_problem
        from nerfify_ns.verify.assembled import field_forward, grad_problems, output_problems, plugin_fields

        model = self.shared_model(spec)
        for name, field in plugin_fields(model, self.package):
            file, line = self.class_line(type(field))
            try:
                out = field_forward(field)
            except Exception as exc:
                self.diagnose(
                    "contract",
                    "field-contract",
                    f"field {name} ({type(field).__name__}) fails on a small batch: "
                    f"{type(exc).__name__}: {exc}",
                    exc=exc,
                )
                continue
            problems = []
            shape = (16, 8)
            radiance = not name.startswith("proposal_networks")
            for key, dim, low, high in (("density", 1, 0.0, None), ("rgb", 3, 0.0, 1.0)):
                value = out.get(key)
                if value is None and key == "rgb" and not radiance:
                    continue
                if value is None:
                    problems.append(f"no {key} output")
                    continue
                if tuple(value.shape) != (*shape, dim):
                    problems.append(f"{key} shape {tuple(value.shape)}, expected {(*shape, dim)}")
                if value.dtype != torch.float32:
                    problems.append(f"{key} dtype {value.dtype}, expected float32")
                problems += [p for p in [finite_problem(key, value)] if p]
                if (
                    value.numel()
                    and float(value.min()) < low - 1e-5
                    or high is not None
                    and float(value.max()) > high + 1e-5
                ):
                    problems.append(f"{key} outside [{low}, {high}]")
            if problems:
                self.diagnose(
                    "contract",
                    "field-contract",
                    f"field {name} ({type(field).__name__}): " + "; ".join(problems),
                    file,
                    line,
                )
        try:
            outputs, losses, total = model_step(model)
        except Exception as exc:
            self.diagnose(
                "contract",
                "model-contract",
                f"a training step of the model fails: {type(exc).__name__}: {exc}",
                exc=exc,
            )
            return
        problems = output_problems(outputs, losses)
        if not losses:
            problems.append("get_loss_dict returned no losses")
        if problems:
            self.diagnose("contract", "non-finite", "model outputs/losses: " + "; ".join(problems))
        bad, missing = grad_problems(model, require=True)
        if bad:
            self.diagnose("contract", "non-finite", "; ".join(bad))
        groups: dict[str, list[str]] = {}
        for pname in missing:
            groups.setdefault(pname.rsplit(".", 2)[0] if pname.count(".") >= 2 else pname, []).append(pname)
        for _prefix, names in groups.items():
            file, line = self.owner_line(model, names[0])
            self.diagnose(
                "contract",
                "detached-parameter",
                f"trainable parameter(s) {', '.join(names[:4])}"
                f"{' ...' if len(names) > 4 else ''} receive no gradient from the losses (a wiring bug: detached, "
                "unused, or outside the graph)",
                file,
                line,
                parameter=names[0],
            )

    def assembled_contract_records(self, spec) -> None:
        from nerfify_ns.verify.assembled import field_forward, plugin_fields

        model = self.shared_model(spec)
        cap = self.pipe.cap
        for name, field in plugin_fields(model, self.package):
            file, line = self.class_line(type(field))
            header = {"kind": "field", "rung": "contract", "component": name, "case": "nominal",
                      "type": type(field).__name__, "radiance": not name.startswith("proposal_networks"),
                      "file": file, "line": line}
            try:
                out = field_forward(field)
            except Exception as exc:
                self.send({**header, "status": "raised", "message": f"field {name} ({type(field).__name__}) fails "
                           f"on a small batch: {type(exc).__name__}: {exc}"[:500]})
                continue
            arrays, dtypes = {}, {}
            for key in ("density", "rgb"):
                if cap.is_tensor(out.get(key)):
                    arrays[key], dtypes[key] = cap.array(out[key])
            self.send({**header, "status": "ran", "dtypes": dtypes}, arrays)
        try:
            outputs, losses, total = model_step(model)
        except Exception as exc:
            self.diagnose("contract", "model-contract",
                          f"a training step of the model fails: {type(exc).__name__}: {exc}", exc=exc)
            return
        self.model_record(model, "contract", "nominal", outputs, losses, require=True)

    def owner_line(self, model, pname: str) -> tuple:
        """File and line of the plugin code that creates the module holding ``pname`` (``self.<attr> = ...``)."""
        parts = pname.split(".")[:-1]
        for i in range(len(parts), -1, -1):
            owner = model.get_submodule(".".join(parts[:i])) if i else model
            if type(owner).__module__.split(".")[0] != self.package:
                continue
            file, line = self.class_line(type(owner))
            if i < len(parts) and file:
                try:
                    lines, start = inspect.getsourcelines(type(owner))
                    hit = next((start + k for k, t in enumerate(lines) if f"self.{parts[i]} =" in t), None)
                    return file, hit or line
                except (OSError, TypeError):
                    pass
            return file, line
        return None, None

    def stability_rung(self, spec, plan: dict | None, suite: str) -> None:
        """Every component on every stiff case that applies; a failure of a component of ours (or of the
        plugin) gates, one of Nerfstudio's is recorded."""
        if suite != "all" and self.pipe is not None:
            if plan is not None:
                self.record_components("stability", lambda s: ("nominal", *s["cases"]))
            if spec is not None:
                self.assembled_stability(spec)
                self.repeated_calls(spec)
            return
        if suite == "all":
            from nerfify_ns.verify.components import suite_components

            components = suite_components()
        else:
            components = [
                (name, cases, run, _owner(terminal))
                for _p, terminal, name, cases, run in self._plan_components()
            ]
        for name, cases, run, (implementation, owner) in components:
            for case in ("nominal", *cases):
                result = run(case).to_dict()
                self.emit(
                    event="case",
                    rung="stability",
                    component=name,
                    implementation=implementation,
                    owner=owner,
                    **result,
                )
                if result["status"] == "fail" and owner in ("ours", "plugin"):
                    self.diagnose(
                        "stability",
                        "stiff-case",
                        f"{name}, case {case}: " + "; ".join(result["problems"]),
                        component=name,
                        case=case,
                    )
        if spec is not None:
            self.assembled_stability(spec)

    def repeated_calls(self, spec) -> None:
        """:data:`~nerfify_ns.verify.checker.REPEAT_STEPS` training-mode forward passes, other random rays each,
        on the model instance the earlier checks used (its parts have counted their calls since the contract
        rung), every call of the plugin's parts watched: one record of per-pass and per-call sums for the
        checker. Forward only: a backward pass through a model's regularisers costs seconds on the CPU, and the
        smoke rung trains."""
        import torch

        from nerfify_ns.registry import examples
        from nerfify_ns.verify.assembled import renders_cameras, small_camera
        from nerfify_ns.verify.checker import MODEL_OUTPUTS, REPEAT_CASE, REPEAT_STEPS, ModuleWatch, watched_modules

        cap = self.pipe.cap
        header = {"kind": "model", "rung": "stability", "component": "<model>", "case": REPEAT_CASE,
                  "owner": "plugin"}
        base = examples.RUN_SEED
        sums: dict[str, list[float]] = {}
        watch, mods, steps = None, {}, 0
        try:
            model = self.shared_model(spec, 1.0)
            model.train()
            watch = ModuleWatch(cap, watched_modules(model, self.package))
            cameras = renders_cameras(model)
            for k in range(REPEAT_STEPS):
                examples.set_run_seed(base + 7919 * (k + 1))  # other rays each pass
                torch.manual_seed(examples.RUN_SEED)
                if cameras:  # another time each pass
                    outputs = model.get_outputs(small_camera(model, time=float(torch.rand(1))))
                else:
                    outputs = model(examples.ray_bundle("nominal", times=True))
                for key in MODEL_OUTPUTS:
                    if cap.is_tensor(outputs.get(key)):
                        sums.setdefault(f"out:{key}", []).append(cap.abs_sum(outputs[key]))
                steps += 1
        except Exception as exc:
            file, line = self.plugin_frame(exc.__traceback__)
            self.send({**header, "status": "raised", "steps": steps, "file": file, "line": line,
                       "message": f"forward pass {steps + 1} of {REPEAT_STEPS} on one model instance raised "
                       f"{type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''}"
                       + (f" at {file}:{line}" if file else "")})
            self.models.pop(1.0, None)
            return
        finally:
            examples.set_run_seed(base)
            if watch is not None:
                mods = watch.take()
                watch.close()
        arrays = {key: np.asarray(values, dtype=np.float64) for key, values in sums.items()}
        self.send({**header, "status": "ran", "steps": steps}, {**arrays, **mods})

    def _emit_model_case(self, case: str, status: str, problems: list[str]) -> None:
        """One stability case of the assembled model (component ``<model>``, owned by the plugin)."""
        if self.pipe is not None:  # a record for the checker: n/a with why, or what was raised
            if status in ("n/a", "fail", "warn"):
                self.send({"kind": "model", "rung": "stability", "component": "<model>", "case": case,
                           "owner": "plugin", "status": "n/a" if status == "n/a" else "raised",
                           "message": "; ".join(problems)[:500]})
            return
        self.emit(
            event="case",
            rung="stability",
            component="<model>",
            owner="plugin",
            case=case,
            status=status,
            problems=problems,
        )

    def assembled_stability(self, spec) -> None:
        import torch

        from nerfify_ns.registry.examples import RUN_SEED
        from nerfify_ns.verify.assembled import (
            MODEL_CASES,
            camera_case_not_applicable,
            grad_problems,
            output_problems,
            patch_density,
        )

        for case in MODEL_CASES:
            torch.manual_seed(RUN_SEED)
            problems: list[str] = []
            if case == "half" and not spec.config.mixed_precision:
                self._emit_model_case(
                    case, "n/a", ["the method trains in float32 (trainer.mixed_precision off)"]
                )
                continue
            scale = {"scene_scale_1e-3": 1e-3, "scene_scale_1e3": 1e3}.get(case, 1.0)
            try:
                model = self.shared_model(spec, scale)
                why = camera_case_not_applicable(model, case)
                if why:
                    self._emit_model_case(case, "n/a", [why])
                    continue
                why, restore = (
                    patch_density(model, self.package, case) if case.startswith("density") else (None, None)
                )
                if why:
                    self._emit_model_case(case, "n/a", [why])
                    continue
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=case == "half"):
                    outputs, losses, _ = model_step(
                        model, "nominal" if case.startswith("density") or case == "half" else case
                    )
                if self.pipe is not None:
                    self.model_record(model, "stability", case, outputs, losses, require=False)
                else:
                    problems = output_problems(outputs, losses) + grad_problems(model, require=False)[0]
                if restore:
                    restore()
                if self.pipe is not None:
                    continue
            except Exception as exc:
                problems = [f"raised {type(exc).__name__}: {str(exc).splitlines()[0][:200]}"]
                file, line = self.plugin_frame(exc.__traceback__)
                if file:
                    problems[0] += f" at {file}:{line}"
                self.models.pop(scale, None)  # possibly left patched or half-updated
            gating = case not in ADVISORY_CASES
            status = ("fail" if gating else "warn") if problems else "pass"
            self._emit_model_case(case, status, problems[:6])
            if problems and gating and self.pipe is None:
                self.diagnose(
                    "stability",
                    "stiff-case",
                    f"assembled model, case {case}: " + "; ".join(problems[:4]),
                    component="<model>",
                    case=case,
                )


# ----------------------------------------------------------------------------- main
def _base_of(plan) -> dict | None:
    if plan and plan.get("base"):
        from nerfify_ns.synthesis.resources import bases

        return bases().get(plan["base"])
    return None


def own_pid_namespace() -> bool:
    """Whether the probe runs in a PID namespace of its own (the ``bwrap`` sandbox: bubblewrap is its pid 1),
    read from ``/proc``, not from anything the environment says."""
    try:
        with open("/proc/1/cmdline", "rb") as f:
            first = f.read(4096).split(b"\0")[0]
    except OSError:
        return False
    return os.path.basename(first) == b"bwrap"


def leftover_processes() -> list[str]:
    """The processes other than ours (and the sandbox's init, pid 1) in the probe's PID namespace: what plugin
    code started and left running. Only in the ``bwrap`` sandbox, whose PID namespace is the probe's own
    (elsewhere ``/proc`` shows the whole host); zombies are not counted."""
    if not own_pid_namespace():
        return []
    found = []
    for entry in sorted(os.listdir("/proc"), key=lambda e: (len(e), e)):
        if not entry.isdigit() or int(entry) in (1, os.getpid()):
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X"):
                    continue
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                cmd = f.read(300).replace(b"\0", b" ").decode(errors="replace").strip()
        except (OSError, IndexError):
            continue
        found.append(f"pid {entry}: {cmd or '?'}")
    return found


def check_leftovers(probe: Probe, rung: str | None) -> None:
    """Fail ``rung`` when plugin code left processes running (they die with the sandbox, but it tried)."""
    found = leftover_processes()
    if found and rung:
        probe.diagnose(rung, "processes", f"plugin code left {len(found)} process(es) running when the probe "
                       f"finished (killed with the sandbox): " + "; ".join(found[:5]) +
                       (" ..." if len(found) > 5 else ""), processes=len(found))


def run_rungs(probe: Probe, info, rungs: list[str], suite: str) -> None:
    """The rungs in order, each between start and end events; the first that fails ends the run; then any
    process plugin code left running fails the last rung that ran."""
    try:
        _run_rungs(probe, info, rungs, suite)
    finally:
        check_leftovers(probe, probe.last_rung)


def _run_rungs(probe: Probe, info, rungs: list[str], suite: str) -> None:
    spec = None
    for rung in rungs:
        probe.last_rung = rung
        probe.emit(event="start", rung=rung)
        try:
            if rung == "static":
                modules = probe.check_imports(info.python_files)
                spec = probe.load_spec(info.config, info.entry_line)
                probe.check_classes(modules, _base_of(info.plan))
                if spec is not None:
                    probe.check_param_groups(spec, info.config_module)
            else:
                spec = spec or probe.load_spec(info.config, info.entry_line)
                if rung == "contract":
                    probe.contract_rung(spec, info.plan)
                elif rung == "stability":
                    probe.stability_rung(spec, info.plan, suite)
        except Exception as exc:  # a crash of the probe on plugin code is itself a finding
            probe.diagnose(rung, "crash", f"{type(exc).__name__}: {exc}", exc=exc)
        probe.emit(event="end", rung=rung)
        if rung in probe.failed:
            break  # the ladder stops at the first failing rung


def main(argv=None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("plugin")
    parser.add_argument("events")
    parser.add_argument("--rungs", default="static,contract,stability")
    parser.add_argument("--suite", default="plan", choices=["plan", "all"])
    parser.add_argument("--records", type=int, default=None, help="file descriptor of the checker's record pipe")
    parser.add_argument("--seed", type=int, default=0, help="moves every example input (drawn per run)")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore")
    from nerfify_ns.registry.examples import set_run_seed
    from nerfify_ns.runtime import activate
    from nerfify_ns.verify.checker import RecordPipe

    set_run_seed(args.seed)
    pipe = RecordPipe(args.records) if args.records is not None else None  # bound before any plugin code runs
    activate(force=True)  # the probe computes on the CPU whatever the machine has: its torch paths, even with CUDA
    with open(args.events, "a") as events:
        if args.plugin == "-":  # the component suite alone, no plugin
            probe = Probe(events)
            probe.emit(event="start", rung="stability")
            probe.stability_rung(None, None, "all")
            probe.emit(event="end", rung="stability")
            return 0
        from nerfify_ns.plan import Plan
        from nerfify_ns.verify.plugin import load_plugin

        info = load_plugin(Path(args.plugin))
        sys.path.insert(0, str(info.root))
        probe = Probe(events, info.root, info.package, Plan.of(info.plan) if info.plan else None, pipe)
        run_rungs(probe, info, args.rungs.split(","), args.suite)
    return 0


if __name__ == "__main__":
    sys.exit(main())
