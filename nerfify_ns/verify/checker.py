"""The checker: verdicts computed outside the process that runs the code under test.

The probe (:mod:`nerfify_ns.verify.probe`) runs plugin code in the sandbox and does not judge it: it sends
*records* (what it ran, on which case, and the raw values that came out: outputs and losses as ``.npy``
arrays, the summed absolute gradient of every trainable parameter) down a pipe that our process holds. This
module, in our process, which never imports plugin code, turns the records into checks:

* shapes, dtypes, ranges and finiteness of every output against the registry's contract (data of ours);
* finiteness of outputs, losses and gradients of the assembled model; parameters without a gradient;
* parameter groups against optimiser keys;
* every check the plan calls for must have arrived, exactly once: a component, case or model step whose
  record is missing (the probe was killed, or its records were tampered with) fails its rung, and a record
  that arrives twice is a forgery;
* a rung that ran no check at all fails ("nothing checked").

What the plugin prints, writes to the run folder or patches in its own interpreter (``torch.isfinite``,
``math.isnan``, the events file) changes no verdict: the arrays are judged here with our own numpy and
torch. A failure the probe reports (an import that fails, a component that raises) is kept as a failure: a
plugin can only forge failures of its own that way.

Wire format (one record): 8-byte little-endian length of a JSON header, the header, then per name in
``header["arrays"]`` an 8-byte length and an ``.npy`` file (no pickles; header checked before any array is
built).
"""

from __future__ import annotations

import io
import json
import os
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MAX_HEADER = 1 << 20
MAX_ARRAY = 64 << 20
MAX_TOTAL = 512 << 20
"""Bounds on what the sandboxed probe may hand over (a header, one array, all records)."""


# ----------------------------------------------------------------------------------------------- the wire
_WRITE_ARRAY = np.lib.format.write_array
_DUMPS = json.dumps
_PACK = struct.pack
"""Bound when this module is imported (by the probe, before any plugin code): a plugin patching numpy's or
json's functions later does not change what the probe sends."""


def encode(header: dict, arrays: dict[str, np.ndarray] | None = None) -> bytes:
    """One record: the header (JSON) and its arrays (``.npy``)."""
    arrays = arrays or {}
    header = {**header, "arrays": list(arrays)}
    text = _DUMPS(header, default=str).encode()
    parts = [_PACK("<Q", len(text)), text]
    for value in arrays.values():
        buf = io.BytesIO()
        value = np.asarray(value)
        _WRITE_ARRAY(buf, value if value.flags.c_contiguous else np.ascontiguousarray(value), allow_pickle=False)
        data = buf.getvalue()
        parts += [_PACK("<Q", len(data)), data]
    return b"".join(parts)


class Captured:
    """Torch functions the probe uses to hand values over, bound before plugin code is imported (a plugin
    that later replaces ``torch.isfinite`` or ``Tensor.numpy`` changes what its own code sees, not these)."""

    def __init__(self) -> None:
        import torch

        self.torch = torch
        self.isfinite, self.where, self.zeros_like = torch.isfinite, torch.where, torch.zeros_like
        self.detach, self.to, self.numpy = torch.Tensor.detach, torch.Tensor.to, torch.Tensor.numpy
        self.abs, self.sum, self.backward = torch.Tensor.abs, torch.Tensor.sum, torch.Tensor.backward
        self.is_tensor = torch.is_tensor
        self.write = os.write
        self.register_hook = torch.nn.Module.register_forward_hook
        self.is_float, self.numel = torch.Tensor.is_floating_point, torch.Tensor.numel

    def array(self, t) -> tuple[np.ndarray, str]:
        """(float32/int array, the tensor's own dtype name) of a tensor."""
        torch = self.torch
        dtype = str(t.dtype).replace("torch.", "")
        t = self.detach(t)
        if t.dtype in (torch.bfloat16, torch.float16):
            t = self.to(t, torch.float32)
        return self.numpy(self.to(t, "cpu")).copy(), dtype

    def abs_sum(self, t) -> float | None:
        """The float64 sum of absolute values: finite exactly when every value is."""
        if t is None:
            return None
        return float(self.sum(self.abs(self.to(self.detach(t), self.torch.float64))))

    def tree_sum(self, value, depth: int = 0) -> float | None:
        """:meth:`abs_sum` over every floating tensor of a module's output (a tensor, or dicts, lists and tuples
        of them); None when it holds none."""
        if self.is_tensor(value):
            return self.abs_sum(value) if self.is_float(value) and self.numel(value) else None
        items = value.values() if isinstance(value, dict) else value if isinstance(value, list | tuple) else ()
        total = None
        for item in list(items)[:64] if depth < 4 else ():
            part = self.tree_sum(item, depth + 1)
            if part is not None:
                total = part if total is None else total + part
        return total


class ModuleWatch:
    """Every call of the watched modules, seen from outside their code: a forward hook (registered with the
    function :class:`Captured` bound before plugin code was imported) adds the summed absolute value of the
    call's floating outputs to that module's list, so a part whose output turns non-finite on its N-th call is
    seen on that call even where the caller masks it (``nan_to_num``, a weight of zero). At most
    :data:`WATCH_MODULES` modules, :data:`WATCH_CALLS` calls each between two :meth:`take`."""

    def __init__(self, cap: Captured, modules) -> None:
        self.cap = cap
        self.calls: dict[str, list[float]] = {}
        self.handles = []
        for name, module in list(modules)[:WATCH_MODULES]:
            self.handles.append(cap.register_hook(module, self._hook(str(name))))

    def _hook(self, name: str):
        def hook(module, inputs, output):
            calls = self.calls.setdefault(name, [])
            if len(calls) < WATCH_CALLS:
                total = self.cap.tree_sum(output)
                calls.append(0.0 if total is None else total)
        return hook

    def take(self) -> dict[str, np.ndarray]:
        """``mod:NAME`` -> the per-call sums since the last take, as float64 arrays (for a record)."""
        out = {f"mod:{name}": np.asarray(calls, dtype=np.float64) for name, calls in self.calls.items() if calls}
        self.calls = {}
        return out

    def close(self) -> None:
        for handle in self.handles:
            handle.remove()
        self.handles = []


WATCH_MODULES = 64
WATCH_CALLS = 256
"""Bounds of a :class:`ModuleWatch` (modules watched; calls kept per module between two records)."""


def watched_modules(model, own_package: str | None = None) -> list[tuple[str, Any]]:
    """The modules of ``model`` whose every call is watched: each one whose class is not torch's or Nerfstudio's
    (the plugin's own parts, its fields among them, and ours), never the model itself (its outputs are judged
    directly). ``own_package``: the plugin's package where known (then only its classes and ours)."""
    found = []
    for name, module in model.named_modules():
        if not name:
            continue
        top = type(module).__module__.split(".")[0]
        if top in ("torch", "nerfstudio") or (own_package and top not in (own_package, "nerfify_ns")):
            continue
        found.append((name, module))
    return found


class RecordPipe:
    """The probe's end of the record pipe (a file descriptor our process passed into the sandbox)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.cap = Captured()
        self.send = _sender(fd, self.cap.write, encode)  # this instance's: patching the class or encode() later
        # changes nothing it sends


def _sender(fd: int, write, encoder):
    def send(header: dict, arrays: dict[str, np.ndarray] | None = None) -> None:
        """One record down the pipe."""
        view = memoryview(encoder(header, arrays))
        while view:
            n = write(fd, view)
            view = view[n:]

    return send


def read_npy(data: bytes) -> np.ndarray:
    """An ``.npy`` file from untrusted bytes: numeric dtype, no pickle, a header whose shape matches the bytes
    that follow (checked before anything is allocated)."""
    f = io.BytesIO(data)
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(f, max_header_size=10000)
    elif version in ((2, 0), (3, 0)):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(f, max_header_size=10000)
    else:
        raise ValueError(f"npy version {version}")
    if dtype.hasobject or dtype.kind not in "biufc":
        raise ValueError(f"dtype {dtype} is not numeric")
    count = 1
    for n in shape:
        count *= int(n)
    if count * dtype.itemsize != len(data) - f.tell():
        raise ValueError(f"an array header claims {shape} {dtype}, {len(data) - f.tell()} bytes follow")
    array = np.frombuffer(data, dtype=dtype, count=count, offset=f.tell())
    return array.reshape(shape, order="F" if fortran else "C")


def decode(data: bytes) -> tuple[list[tuple[dict, dict[str, np.ndarray]]], list[str]]:
    """(records, problems) of a byte stream; a malformed record ends the stream (a problem, not a crash)."""
    records, problems, pos = [], [], 0
    while pos < len(data):
        try:
            (n,) = struct.unpack_from("<Q", data, pos)
            if n > MAX_HEADER:
                raise ValueError(f"a record header of {n} bytes")
            header = json.loads(data[pos + 8:pos + 8 + n])
            if not isinstance(header, dict) or not isinstance(header.get("arrays", []), list):
                raise ValueError("a record header is not a mapping")
            pos += 8 + n
            arrays = {}
            for name in header.get("arrays", []):
                (m,) = struct.unpack_from("<Q", data, pos)
                if m > MAX_ARRAY or pos + 8 + m > len(data):
                    raise ValueError(f"array {str(name)[:60]} of {m} bytes")
                arrays[str(name)] = read_npy(data[pos + 8:pos + 8 + m])
                pos += 8 + m
        except (ValueError, struct.error, RecursionError) as exc:
            problems.append(f"malformed record at byte {pos}: {str(exc)[:200]}")
            break
        records.append((header, arrays))
    return records, problems


class PipeReader:
    """Our end of the pipe the sandboxed probe writes records to, read by a thread into a bounded buffer
    (what comes beyond :data:`MAX_TOTAL` is drained and counted, never kept)."""

    def __init__(self) -> None:
        read, write = os.pipe()
        self.read_fd = read
        self.write_fd = os.dup(write) if write >= 100 else _high(write)
        os.close(write)
        os.set_inheritable(self.write_fd, True)
        self.chunks: list[bytes] = []
        self.size = 0
        self.overflow = 0
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        while True:
            try:
                chunk = os.read(self.read_fd, 1 << 20)
            except OSError:
                return
            if not chunk:
                return
            if self.size + len(chunk) > MAX_TOTAL:
                self.overflow += len(chunk)
                continue
            self.chunks.append(chunk)
            self.size += len(chunk)

    def close_writer(self) -> None:
        """After the child started (it has its copy): our copy closed, so the reader sees the end."""
        if self.write_fd >= 0:
            os.close(self.write_fd)
            self.write_fd = -1

    def finish(self, timeout: float = 30.0) -> bytes:
        self.close_writer()
        self._thread.join(timeout)
        os.close(self.read_fd)
        return b"".join(self.chunks)


def _high(fd: int) -> int:
    import fcntl

    return fcntl.fcntl(fd, fcntl.F_DUPFD, 100)


# ----------------------------------------------------------------------------------------------- judging
@dataclass
class Finding:
    """One failed check (becomes a :class:`nerfify_ns.verify.verdicts.Diagnosis` of the rung)."""

    rung: str
    rule: str
    message: str
    component: str | None = None
    case: str | None = None
    file: str | None = None
    line: int | None = None
    data: dict[str, Any] = field(default_factory=dict)


@dataclass
class Verdicts:
    """Per rung: checks made here, failures found here, and the cases seen (for ``verify.json``)."""

    checks: dict[str, int] = field(default_factory=dict)
    findings: list[Finding] = field(default_factory=list)
    cases: dict[str, list[dict]] = field(default_factory=dict)

    def count(self, rung: str, n: int = 1) -> None:
        self.checks[rung] = self.checks.get(rung, 0) + n

    def fail(self, rung: str, rule: str, message: str, **where: Any) -> None:
        self.findings.append(Finding(rung, rule, message, **where))


def _nonfinite(name: str, value: np.ndarray) -> str | None:
    if value.dtype.kind in "fc" and value.size:
        bad = int(value.size - np.count_nonzero(np.isfinite(value)))
        if bad:
            return f"{name}: {bad} of {value.size} values not finite"
    return None


def _tensor(array: np.ndarray, dtype: str | None):
    import torch

    t = torch.from_numpy(np.array(array))
    if dtype and hasattr(torch, dtype) and isinstance(getattr(torch, dtype), torch.dtype):
        t = t.to(getattr(torch, dtype))
    return t


def grad_findings(header: dict, require: bool) -> tuple[list[str], list[str]]:
    """(non-finite gradients, trainable parameters without a gradient) from ``header["grads"]`` (name ->
    summed absolute gradient, None when no gradient arrived): a sum of absolute float32 values is finite
    exactly when every value is."""
    bad, missing = [], []
    for name, total in (header.get("grads") or {}).items():
        if total is None:
            missing.append(str(name))
        elif not (isinstance(total, int | float) and np.isfinite(total)):
            bad.append(f"gradient of {name} not finite")
    for name, total in (header.get("input_grads") or {}).items():
        if total is not None and not (isinstance(total, int | float) and np.isfinite(total)):
            bad.append(f"gradient of input {name} not finite")
    return bad, (missing if require else [])


def judge_component(header: dict, arrays: dict[str, np.ndarray], contract, env: dict[str, Any]) -> list[str]:
    """Problems of one component case: the contract on the outputs (shapes, dtypes, ranges, finiteness),
    then the gradients."""
    from nerfify_ns.registry.contract import check_outputs

    case = header.get("case", "nominal")
    if header.get("status") == "raised":
        return [str(header.get("message", "raised"))[:300]]
    dtypes = header.get("dtypes") or {}
    outputs: dict[str, Any] = {k: _tensor(v, dtypes.get(k)) for k, v in arrays.items()}
    for name, kind in (header.get("others") or {}).items():
        outputs[str(name)] = _Other(str(kind))
    if header.get("out_dim") is not None:
        env = {**env, "out_dim": int(header["out_dim"])}
    problems = check_outputs(contract, outputs, env, float_inputs=case != "half")
    bad, missing = grad_findings(header, require=case == "nominal")
    return problems + bad + [f"parameter {name} receives no gradient" for name in missing]


class _Other:
    """An output that is not a tensor (rays, samples, a list): only its kind crossed the pipe."""

    def __init__(self, kind: str) -> None:
        self.kind = kind


FIELD_OUTPUTS = (("density", 1, 0.0, None), ("rgb", 3, 0.0, 1.0))
FIELD_SHAPE = (16, 8)
"""The assembled field's probe: 16 rays of 8 uniform samples; density [.., 1] >= 0, rgb [.., 3] in [0, 1]."""


def judge_field(header: dict, arrays: dict[str, np.ndarray]) -> list[str]:
    problems = []
    dtypes = header.get("dtypes") or {}
    for key, dim, low, high in FIELD_OUTPUTS:
        value = arrays.get(key)
        if value is None and key == "rgb" and not header.get("radiance", True):
            continue
        if value is None:
            problems.append(f"no {key} output")
            continue
        if tuple(value.shape) != (*FIELD_SHAPE, dim):
            problems.append(f"{key} shape {tuple(value.shape)}, expected {(*FIELD_SHAPE, dim)}")
        if dtypes.get(key, str(value.dtype)) != "float32":
            problems.append(f"{key} dtype {dtypes.get(key, value.dtype)}, expected float32")
        problem = _nonfinite(key, value)
        if problem:
            problems.append(problem)
        elif value.size and (float(value.min()) < low - 1e-5 or high is not None and float(value.max()) > high + 1e-5):
            problems.append(f"{key} outside [{low}, {high}]")
    return problems


MODEL_OUTPUTS = ("rgb", "accumulation", "depth", "expected_depth", "rgb_fine", "rgb_coarse")


def judge_model(header: dict, arrays: dict[str, np.ndarray], require: bool) -> tuple[list[str], list[str]]:
    """(problems, parameters without gradient) of one step of the assembled model."""
    problems = []
    for name, value in arrays.items():
        kind, _, key = name.partition(":")
        label = f"outputs[{key!r}]" if kind == "out" else f"loss {key!r}"
        problem = _nonfinite(label, value)
        if problem:
            problems.append(problem)
    if require and not any(n.startswith("loss:") for n in arrays):
        problems.append("get_loss_dict returned no losses")
    bad, missing = grad_findings(header, require)
    return problems + bad, missing


REPEAT_STEPS = 64
REPEAT_CASE = "repeated_calls"
"""The stability rung's last check: this many training-mode forward passes (other random rays each) on the one
model instance every earlier check of the probe used, every pass and every call of the plugin's parts recorded,
so a part that turns non-finite (or raises) from its N-th call is caught for any N <= REPEAT_STEPS."""


def judge_repeated(header: dict, arrays: dict[str, np.ndarray]) -> list[str]:
    """Problems of the repeated passes: ``out:KEY`` (one summed absolute value per pass) and ``mod:NAME`` (one
    per call of a watched part) must be finite; every pass must have run."""
    if header.get("status") == "raised":
        return [str(header.get("message", "raised"))[:300]]
    problems = []
    steps = header.get("steps")
    if not isinstance(steps, int) or steps < REPEAT_STEPS:
        problems.append(f"{steps} of {REPEAT_STEPS} repeated forward passes recorded")
    labels = {"out": "outputs[{!r}]", "mod": "the output of part {}"}
    for name, value in arrays.items():
        kind, _, key = name.partition(":")
        if kind not in labels or value.ndim != 1 or value.dtype.kind not in "fc":
            problems.append(f"an unexpected record {name[:60]} {value.shape}")
            continue
        bad = np.flatnonzero(~np.isfinite(value))
        if bad.size:
            unit = "call" if kind == "mod" else "pass"
            problems.append(f"{labels[kind].format(key)} not finite from {unit} {int(bad[0]) + 1} of {value.size} "
                            f"({bad.size} non-finite)")
    if not any(n.startswith("out:") for n in arrays) and not problems:
        problems.append("the repeated passes recorded no outputs")
    return problems


# ----------------------------------------------------------------------------------------------- what to expect
def component_specs(plan) -> list[dict]:
    """Every component of ``plan`` (a :class:`nerfify_ns.plan.Plan`) that has a contract: its path, terminal,
    name, stability cases, contract and the parameters its example sizes come from. Data only: nothing of the
    plugin is imported (the probe builds the components from the same list)."""
    from nerfify_ns.grammar import load_grammar, validate
    from nerfify_ns.registry import default_registry

    registry = default_registry()
    found = []
    for path, terminal in dict(validate(plan, load_grammar()).used).items():
        if terminal == "custom":
            production = load_grammar().production_at(path)
            interface = registry.interfaces.get(production or "")
            if interface is None:
                continue
            entry = plan.get(path) or {}
            found.append({"path": path, "terminal": terminal, "name": f"custom {entry.get('class')} ({production})",
                          "cases": tuple(interface.cases), "contract": interface.contract_for(entry),
                          "params": dict(entry), "interface": interface, "entry": entry})
            continue
        defn = registry[terminal]
        if defn.harness.in_model or defn.contract.empty:
            continue
        params = plan.get(path) if isinstance(plan.get(path), dict) else {}
        found.append({"path": path, "terminal": terminal, "name": terminal, "cases": tuple(defn.harness.cases),
                      "contract": defn.contract, "params": defn.small(params), "defn": defn, "raw": params})
    return found


def case_env(spec: dict, case: str) -> dict[str, Any]:
    from nerfify_ns.registry.examples import case_sizes

    return spec["contract"].environment(spec["params"], case_sizes(case), {"case": case})


def expected(plan, rungs: Sequence[str], with_model: bool) -> dict[tuple[str, str, str, str], dict]:
    """The records each rung must deliver: (kind, rung, component, case) -> the component's spec."""
    from nerfify_ns.verify.assembled import MODEL_CASES

    out: dict[tuple[str, str, str, str], dict] = {}
    specs = component_specs(plan) if plan is not None else []
    if "static" in rungs and with_model:
        out[("param_groups", "static", "<model>", "-")] = {}
    if "contract" in rungs:
        for spec in specs:
            out[("component", "contract", spec["name"], "nominal")] = spec
        if with_model:
            out[("model", "contract", "<model>", "nominal")] = {}
    if "stability" in rungs:
        for spec in specs:
            for case in ("nominal", *spec["cases"]):
                out[("component", "stability", spec["name"], case)] = spec
        if with_model:
            for case in (*MODEL_CASES, REPEAT_CASE):
                out[("model", "stability", "<model>", case)] = {}
    return out


ADVISORY_CASES = ("empty_batch", "half")
"""Model cases recorded but not gating: Nerfstudio's own samplers and losses fail on them."""
JUDGED = ("component", "field", "model", "param_groups")


def judge(records: Sequence[tuple[dict, dict[str, np.ndarray]]], plan, rungs: Sequence[str],
          finished: Sequence[str], with_model: bool = True) -> Verdicts:
    """The verdicts of the probe's records: each expected check judged here, missing and duplicated records
    named. ``finished``: the rungs the probe reported as ended (a rung that never ended is failed elsewhere)."""
    v = Verdicts()
    want = expected(plan, rungs, with_model)
    seen: set = set()
    for header, arrays in records:
        kind = header.get("kind")
        if kind not in JUDGED:
            continue
        rung = str(header.get("rung"))
        if rung not in rungs:
            continue
        key = (kind, rung, str(header.get("component") or "<model>"), str(header.get("case") or "-"))
        if key in seen and kind != "field":
            v.fail(rung, "forged-record", f"the check of {key[2]}, case {key[3]} was delivered twice: something "
                   "besides the probe wrote to its record pipe")
            continue
        seen.add(key)
        _judge_one(v, kind, rung, key, header, arrays, want.get(key))
    for key, _spec in want.items():
        kind, rung, name, case = key
        if key not in seen and rung in finished:
            v.fail(rung, "missing-check", f"the check of {name}, case {case} never arrived from the probe (the "
                   "process stopped early, or something interfered with its records)", component=name, case=case)
    for rung in finished:
        if not v.checks.get(rung):
            v.fail(rung, "nothing-checked", f"nothing checked: the {rung} rung delivered no check to judge")
    return v


def _judge_one(v: Verdicts, kind: str, rung: str, key: tuple, header: dict, arrays: dict, spec: dict | None) -> None:
    name, case = key[2], key[3]
    status = header.get("status")
    v.count(rung)
    if kind == "param_groups":
        groups = {str(k): int(n) if isinstance(n, int) else 0 for k, n in (header.get("groups") or {}).items()}
        keys = {str(k) for k in header.get("optimizers") or []}
        missing, extra = sorted(set(groups) - keys), sorted(keys - set(groups))
        where = {"file": header.get("file"), "line": header.get("line")}
        if missing or extra:
            v.fail(rung, "param-groups", f"model parameter groups {sorted(groups)} != optimizer keys {sorted(keys)} "
                   f"(missing optimizers: {missing}; optimizers without a group: {extra})", **where,
                   data={"missing": missing, "extra": extra})
        empty = sorted(k for k, n in groups.items() if n == 0)
        if empty:
            v.fail(rung, "param-groups", f"parameter groups without parameters: {empty}", **where)
        return
    if status == "n/a":
        v.cases.setdefault(rung, []).append({"component": name, "case": case, "status": "n/a",
                                             "problems": [str(header.get("message", ""))[:300]],
                                             "owner": header.get("owner"), "path": header.get("path")})
        return
    if kind == "component":
        if spec is None:
            v.fail(rung, "forged-record", f"a check of {name}, case {case} that the plan does not call for")
            return
        problems = judge_component(header, arrays, spec["contract"], case_env(spec, case))
        rule = "component-contract" if rung == "contract" else "stiff-case"
        label = f"{name} ({spec['path']})" if rung == "contract" else f"{name}, case {case}"
        gating = rung == "contract" or header.get("owner") in ("ours", "plugin")  # Nerfstudio's own: recorded
    elif kind == "field":
        problems = ([str(header.get("message"))[:300]] if status == "raised" else judge_field(header, arrays))
        rule, label, gating = "field-contract", f"field {name} ({header.get('type')})", True
    elif case == REPEAT_CASE:
        problems = judge_repeated(header, arrays)
        rule, label, gating = "repeated-calls", f"assembled model, {REPEAT_STEPS} forward passes on one instance", True
    else:  # the assembled model
        if status == "raised":
            problems, missing = [str(header.get("message", "raised"))[:300]], []
        else:
            problems, missing = judge_model(header, arrays, require=rung == "contract")
        if missing:
            _detached(v, rung, missing, header.get("owners") or {})
        rule = "non-finite" if rung == "contract" else "stiff-case"
        label = "model outputs/losses" if rung == "contract" else f"assembled model, case {case}"
        gating = rung == "contract" or case not in ADVISORY_CASES
    status = ("fail" if gating else "warn") if problems else "pass"
    v.cases.setdefault(rung, []).append({"component": name, "case": case, "status": status, "problems": problems[:6],
                                         "owner": header.get("owner"), "implementation": header.get("implementation"),
                                         "path": header.get("path")})
    if problems and gating:
        v.fail(rung, rule, f"{label}: " + "; ".join(problems[:4]), component=name, case=case,
               file=header.get("file"), line=header.get("line"))


def _detached(v: Verdicts, rung: str, missing: list[str], owners: dict) -> None:
    groups: dict[str, list[str]] = {}
    for pname in missing:
        groups.setdefault(pname.rsplit(".", 2)[0] if pname.count(".") >= 2 else pname, []).append(pname)
    for names in groups.values():
        where = owners.get(names[0]) or [None, None]
        v.fail(rung, "detached-parameter", f"trainable parameter(s) {', '.join(names[:4])}"
               f"{' ...' if len(names) > 4 else ''} receive no gradient from the losses (a wiring bug: detached, "
               "unused, or outside the graph)", file=where[0], line=where[1] if isinstance(where[1], int) else None,
               data={"parameter": names[0]})
