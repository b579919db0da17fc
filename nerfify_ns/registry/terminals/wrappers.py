"""Field wrappers: deformation into a canonical space, time conditioning, per-camera time offsets, and several
fields blended by density or by a learned mixer (``nerfify_ns/components/field_wrappers.py``).

Every conditioner reads a sample's position, time and camera and writes the position and time the field is
queried at and features appended to the backbone's input; each terminal's contract names only what it reads and
writes. A blend reads the densities and colours of K fields at a sample and writes one density and colour.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import POINT_CASES
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Constraint, Harness, TerminalDef
from nerfify_ns.registry.terminals.custom import CUSTOM_MEMBER

COMPONENT = "field_wrappers"
IMPORT = "from .components.field_wrappers import {}"
SMALL = {"num_layers": 2, "layer_width": 16, "position_frequencies": 4, "time_frequencies": 2, "num_frequencies": 2,
         "out_dim": 8, "num_frames": 8, "dim": 8, "mixer_width": 16, "mixer_layers": 1, "plane_resolution": 8,
         "plane_features": 4, "time_resolution": 4}
TIMES = {"requires_scene": {"timestamps": True}}
"""Duty of a wrapper that reads the samples' times: only for scenes whose frames carry times."""
MLP_FIELD = {"requires_terminal": {"slot": "model.field", "any_of": ["MLPField"]}}
"""Duty of a wrapper of samples: the generated neural field (MLPField) applies them."""
MLP_FIELD_OR_PRIMITIVES = {"requires_terminal": {"slot": "model.field", "any_of": ["MLPField", None]}}
"""Duty of a wrapper that also conditions explicit primitives: the neural field applies it, or, in a model of
Gaussians (no field), the model applies it to the Gaussians' centres and the camera's time."""
PRIMITIVES = {"requires_base": ["splatfacto"]}
"""Duty of a wrapper of explicit primitives (3D Gaussians): a splatting base."""

TIMES_NEED_PADDED_SAMPLES = Constraint(
    "a wrapper that reads times reads each sample's ray time; instant-ngp's packed samples carry none",
    lambda p, plan: plan.get("base") != "instant-ngp")

def _reads_times(plan) -> bool:
    """Another part of the plan reads the samples' times: a terminal whose contract takes them and writes more than
    a time (an encoding over space-time, a deformation, a time embedding), or a component of the paper's own at the
    field (its reads are not declared)."""
    from nerfify_ns.registry.core import default_registry
    from nerfify_ns.registry.terminals.training import _terminals_in

    terminals = default_registry().terminals
    model = plan.get("model") or {}
    for key in _terminals_in({"field": model.get("field"), "field_wrappers": model.get("field_wrappers")}):
        if CUSTOM_MEMBER.match(key):
            return True
        term = terminals.get(key)
        if term is not None and "times" in term.contract.inputs and set(term.contract.outputs) != {"times"}:
            return True
    return False


TIMES_ARE_READ = Constraint(
    "a wrapper that only shifts the samples' times needs a part that reads them (space-time planes, a deformation, "
    "a time embedding or frame codes); otherwise its values receive no gradient",
    lambda p, plan: _reads_times(plan))

ONE_BLEND = Constraint(
    "one blend per field: no custom field wrapper with `wrapper: blend` beside field_blend",
    lambda p, plan: not any(isinstance(v, dict) and v.get("wrapper") == "blend" for k, v in (
        ((plan.get("model") or {}).get("field_wrappers") or {}).items()) if str(k).startswith("custom")))

POSITIONS = T("[N, 3]", grad=True, role="positions", doc="sample positions in world space")
TIMES_IN = T("[N, 1]", range=(0.0, 1.0), grad=True, doc="sample times (the ray's frame time)")
CAMERAS = T("[N]", "long", role="camera_indices", doc="training camera (image) index of the sample's ray")


@dataclass
class Deformation:
    num_layers: int = param(8, range=(1, 16))
    """Hidden layers of the deformation MLP Psi_t (D-NeRF: 8)."""
    layer_width: int = param(256, range=(8, 1024))
    """Units per hidden layer of the deformation MLP (D-NeRF: 256)."""
    position_frequencies: int = param(10, range=(1, 16))
    """Frequencies of the deformation's own encoding of x (D-NeRF: 10, NeRF's)."""
    time_frequencies: int = param(6, range=(1, 16))
    """Frequencies of the deformation's own encoding of t."""
    zero_at_t0: bool = param(True)
    """No displacement at t = 0: the canonical space is the scene at the first time (D-NeRF Eq. 2)."""


@dataclass
class GaussianDeformation:
    num_layers: int = param(8, range=(1, 16))
    """Hidden layers of the deformation MLP F_theta (Deformable 3D Gaussians: D = 8)."""
    layer_width: int = param(256, range=(8, 1024))
    """Units per hidden layer of the deformation MLP (Deformable 3D Gaussians: W = 256)."""
    position_frequencies: int = param(10, range=(1, 16))
    """Frequencies of the deformation's encoding of a Gaussian's centre (Deformable 3D Gaussians: 10)."""
    time_frequencies: int = param(6, range=(1, 16))
    """Frequencies of the deformation's encoding of t (Deformable 3D Gaussians: 6)."""
    zero_at_t0: bool = param(False)
    """No deformation at t = 0: the canonical Gaussians are the scene at the first time."""
    stop_gradient: bool = param(True)
    """The encoding reads a Gaussian's centre without its gradient (Deformable 3D Gaussians Eq. 4: gamma(sg(x)))."""
    encoding: Literal["frequency", "planes"] = param("frequency")
    """What the MLP reads: frequency, the sinusoidal encodings of the centre and t (Deformable 3D Gaussians Eq. 4);
    planes, 4D-GS's spatial-temporal structure encoder, six multi-resolution planes over (x, y, z, t) (Eq. 7)."""
    plane_resolution: int = param(64, range=(2, 1024))
    """Spatial resolution N of the planes' first level (encoding planes; K-Planes' 64)."""
    plane_levels: int = param(2, range=(1, 4))
    """Levels of the planes, resolution N x 2^l each (encoding planes; 4D-GS: l in {1, 2})."""
    plane_features: int = param(32, range=(1, 256))
    """Features h of every plane (encoding planes; K-Planes' 32)."""
    time_resolution: int = param(25, range=(2, 1024))
    """Cells of the planes' time axis (encoding planes; K-Planes on D-NeRF's scenes: 25)."""


@dataclass
class TimeEmbedding:
    num_frequencies: int = param(6, range=(1, 16))
    """Frequencies of the sinusoidal encoding gamma(t) the embedding MLP reads."""
    layer_width: int = param(64, range=(4, 1024))
    """Units per hidden layer of the embedding MLP."""
    num_layers: int = param(2, range=(0, 8))
    """Hidden layers of the embedding MLP (0: a linear map of gamma(t))."""
    out_dim: int = param(16, range=(1, 1024))
    """Width of the time embedding appended to the field's input."""


@dataclass
class FrameCodes:
    num_frames: int = param(64, range=(2, 100000))
    """Number of learned codes over t in [0, 1] (one per frame of the sequence; interpolated between frames)."""
    dim: int = param(32, range=(1, 4096))
    """Width D of each latent code z_t (DyNeRF: 1024)."""


@dataclass
class CameraTimeOffset:
    init: float = param(0.0, range=(-1.0, 1.0))
    """Initial time offset of every camera (times are in [0, 1])."""


@dataclass
class FieldBlend:
    num_fields: int = param(2, range=(2, 4))
    """Number of fields blended (each a copy of the plan's field)."""
    mode: Literal["density", "mixer"] = param("density")
    """density: sigma = sum sigma_k, colour weighted by density (NeRF-W); mixer: per-sample softmax weights from
    an MLP on (gamma(x), t) (NeRFPlayer's decomposition)."""
    mixer_width: int = param(64, range=(4, 1024))
    """Units per hidden layer of the mixer MLP (mode mixer)."""
    mixer_layers: int = param(2, range=(0, 8))
    """Hidden layers of the mixer MLP (mode mixer)."""
    static_first: bool = param(True)
    """The first field ignores the plan's conditioners (a static field beside the time-dependent ones)."""


def _conditioner_build(cls: str, *names: str):
    def build(p, env):
        from nerfify_ns.components import field_wrappers

        kwargs = {n: p[n] for n in names}
        if cls == "CameraTimeOffset":
            kwargs["num_images"] = int(env["cameras"])
        return getattr(field_wrappers, cls)(**kwargs)

    return build


def _conditioner_call(*outputs: str):
    """Run a conditioner on (positions, times, camera indices) and name the outputs its contract declares."""
    def call(module, inputs, env):
        import torch

        x = inputs["positions"]
        t = inputs.get("times")
        t = t if t is not None else x.new_zeros(x.shape[0], 1)
        cams = inputs.get("camera_indices")
        cams = cams if cams is not None else torch.zeros(x.shape[0], dtype=torch.long)
        positions, times, features = module.to(x.dtype)(x, t, cams)
        return {k: v for k, v in (("positions", positions), ("times", times), ("features", features))
                if k in outputs}

    return call


def _blend_build(p, env):
    from nerfify_ns.components.field_wrappers import FieldBlend as Blend

    return Blend(num_fields=p["num_fields"], mode=p["mode"], mixer_width=p["mixer_width"],
                 mixer_layers=p["mixer_layers"])


def _blend_call(module, inputs, env):
    density, rgb = module.to(inputs["positions"].dtype)(inputs["densities"], inputs["rgbs"], inputs["positions"],
                                                        inputs["times"])
    return {"density": density, "rgb": rgb}


def blend_contract(fields: str = "num_fields") -> Contract:
    """What a blend of ``fields`` fields reads and writes (a count or the parameter's name)."""
    return Contract({"densities": T(f"[N, {fields}, 1]", range=(0.0, 5.0), grad=True, role="densities",
                                    doc="each field's density"),
                     "rgbs": T(f"[N, {fields}, 3]", range=(0.0, 1.0), grad=True, doc="each field's colour"),
                     "positions": POSITIONS, "times": TIMES_IN},
                    {"density": T("[N, 1]", range=(0.0, None), doc="blended density"),
                     "rgb": T("[N, 3]", range=(0.0, 1.0), doc="blended colour")},
                    doc="reads the fields' densities and colours (and, mixer, positions and times); writes one "
                        "density and colour per sample")


def ctor(cls: str, args: str) -> str:
    return f"{cls}({args})"


TERMINALS = [
    TerminalDef(
        "deformation", "FieldWrapper", Deformation,
        "A deformation network Psi_t(gamma(x), gamma(t)) -> Delta x into a canonical space, the field queried at "
        "x + Delta x (D-NeRF Eqs. 2-3).",
        "nerfify_ns.components.field_wrappers.DeformationNetwork",
        contract=Contract({"positions": POSITIONS, "times": TIMES_IN},
                          {"positions": T("[N, 3]", doc="canonical positions x + Delta x")},
                          doc="reads positions and times; writes positions"),
        code=Code((IMPORT.format("DeformationNetwork"),),
                  ctor=ctor("DeformationNetwork", "num_layers={{ p.num_layers }}, layer_width={{ p.layer_width }}, "
                            "position_frequencies={{ p.position_frequencies }}, "
                            "time_frequencies={{ p.time_frequencies }}, zero_at_t0={{ p.zero_at_t0 }}"),
                  component=COMPONENT, traits={"stage": "condition", "schedulable": ["deformation",
                                                                                    "deformation.window"]}),
        harness=Harness(build=_conditioner_build("DeformationNetwork", "num_layers", "layer_width",
                                                 "position_frequencies", "time_frequencies", "zero_at_t0"),
                        call=_conditioner_call("positions"), cases=POINT_CASES, small=SMALL),
        duties=(TIMES, MLP_FIELD), constraints=(TIMES_NEED_PADDED_SAMPLES,)),
    TerminalDef(
        "gaussian_deformation", "FieldWrapper", GaussianDeformation,
        "A deformation field of 3D Gaussians from a canonical set to time t: an MLP F(gamma(sg(x)), gamma(t)) -> "
        "(Delta x, Delta r, Delta s) added to each Gaussian's centre, rotation and log-scale (Deformable 3D "
        "Gaussians Eqs. 4-5; 4D-GS's multi-head decoder, Eq. 8).",
        "nerfify_ns.components.field_wrappers.GaussianDeformation",
        contract=Contract({"positions": T("[N, 3]", grad=True, role="positions", doc="canonical Gaussians' centres"),
                           "times": TIMES_IN},
                          {"positions": T("[N, 3]", doc="the centres at time t, x + Delta x"),
                           "features": T("[N, 7]", doc="rotation (quaternion) and log-scale offsets (Delta r, "
                                                       "Delta s)")},
                          doc="reads the Gaussians' centres and the time; writes centres and offsets"),
        code=Code((IMPORT.format("GaussianDeformation"),),
                  ctor=ctor("GaussianDeformation", "num_layers={{ p.num_layers }}, layer_width={{ p.layer_width }}, "
                            "position_frequencies={{ p.position_frequencies }}, "
                            "time_frequencies={{ p.time_frequencies }}, zero_at_t0={{ p.zero_at_t0 }}, "
                            "stop_gradient={{ p.stop_gradient }}, encoding={{ p.encoding | tojson }}, "
                            "plane_resolution={{ p.plane_resolution }}, plane_levels={{ p.plane_levels }}, "
                            "plane_features={{ p.plane_features }}, time_resolution={{ p.time_resolution }}"),
                  component=COMPONENT, traits={"stage": "condition", "schedulable": [
                      "deformation", "deformation.window", "deformation.time_noise"]}),
        harness=Harness(build=_conditioner_build("GaussianDeformation", "num_layers", "layer_width",
                                                 "position_frequencies", "time_frequencies", "zero_at_t0",
                                                 "stop_gradient", "encoding", "plane_resolution", "plane_levels",
                                                 "plane_features", "time_resolution"),
                        call=_conditioner_call("positions", "features"), cases=POINT_CASES, small=SMALL),
        duties=(TIMES, PRIMITIVES)),
    TerminalDef(
        "time_embedding", "FieldWrapper", TimeEmbedding,
        "A learned time embedding, an MLP on gamma(t), appended to the field's input (time conditioning).",
        "nerfify_ns.components.field_wrappers.TimeEmbedding",
        contract=Contract({"positions": POSITIONS, "times": TIMES_IN},
                          {"features": T("[N, out_dim]", doc="time embedding appended to the backbone's input")},
                          doc="reads times; writes features"),
        code=Code((IMPORT.format("TimeEmbedding"),),
                  ctor=ctor("TimeEmbedding", "num_frequencies={{ p.num_frequencies }}, "
                            "layer_width={{ p.layer_width }}, num_layers={{ p.num_layers }}, out_dim={{ p.out_dim }}"),
                  component=COMPONENT, traits={"stage": "condition", "schedulable": ["time_embedding"]}),
        harness=Harness(build=_conditioner_build("TimeEmbedding", "num_frequencies", "layer_width", "num_layers",
                                                 "out_dim"),
                        call=_conditioner_call("features"), cases=("empty_batch", "half"), small=SMALL),
        duties=(TIMES, MLP_FIELD), constraints=(TIMES_NEED_PADDED_SAMPLES,)),
    TerminalDef(
        "frame_codes", "FieldWrapper", FrameCodes,
        "Learned time-variant latent codes z_t, one per frame, interpolated in time and appended to the field's "
        "input (DyNeRF Eq. 2).",
        "nerfify_ns.components.field_wrappers.FrameCodes",
        contract=Contract({"positions": POSITIONS, "times": TIMES_IN},
                          {"features": T("[N, dim]", doc="the latent code of the sample's time")},
                          doc="reads times; writes features"),
        code=Code((IMPORT.format("FrameCodes"),),
                  ctor=ctor("FrameCodes", "num_frames={{ p.num_frames }}, dim={{ p.dim }}"),
                  component=COMPONENT, traits={"stage": "condition", "schedulable": ["frame_codes"]}),
        harness=Harness(build=_conditioner_build("FrameCodes", "num_frames", "dim"),
                        call=_conditioner_call("features"), cases=("empty_batch", "half"), small=SMALL),
        duties=(TIMES, MLP_FIELD), constraints=(TIMES_NEED_PADDED_SAMPLES,)),
    TerminalDef(
        "camera_time_offset", "FieldWrapper", CameraTimeOffset,
        "One learned time offset per training camera, t + delta_c (unsynchronised cameras); none at evaluation.",
        "nerfify_ns.components.field_wrappers.CameraTimeOffset",
        contract=Contract({"positions": POSITIONS, "times": TIMES_IN, "camera_indices": CAMERAS},
                          {"times": T("[N, 1]", doc="the sample's time plus its camera's offset")},
                          doc="reads times and camera indices; writes times"),
        code=Code((IMPORT.format("CameraTimeOffset"),),
                  ctor=ctor("CameraTimeOffset", "num_images=num_images, init={{ p.init }}"),
                  component=COMPONENT, traits={"stage": "condition", "schedulable": ["camera_time_offset"]}),
        harness=Harness(build=_conditioner_build("CameraTimeOffset", "init"), call=_conditioner_call("times"),
                        cases=("empty_batch", "half")),
        duties=(TIMES, MLP_FIELD_OR_PRIMITIVES), constraints=(TIMES_NEED_PADDED_SAMPLES, TIMES_ARE_READ)),
    TerminalDef(
        "field_blend", "FieldWrapper", FieldBlend,
        "Several copies of the field blended per sample: by density (NeRF-W Eq. 10) or by a learned mixer's "
        "softmax weights (NeRFPlayer's decomposition).",
        "nerfify_ns.components.field_wrappers.BlendedField",
        contract=blend_contract(),
        code=Code((IMPORT.format("BlendedField"), IMPORT.format("FieldBlend")),
                  ctor=ctor("FieldBlend", "num_fields={{ p.num_fields }}, mode={{ p.mode | tojson }}, "
                            "mixer_width={{ p.mixer_width }}, mixer_layers={{ p.mixer_layers }}"),
                  component=COMPONENT, traits={"stage": "blend", "schedulable": ["blend"]}),
        harness=Harness(build=_blend_build, call=_blend_call, cases=("zeros", "empty_batch", "half"), small=SMALL),
        duties=(MLP_FIELD,), constraints=(ONE_BLEND,)),
]
