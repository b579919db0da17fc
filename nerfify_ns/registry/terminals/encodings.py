"""Position and direction encodings, spatial distortions, appearance codes, tensor decompositions."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from nerfify_ns.registry.contract import Contract, T
from nerfify_ns.registry.examples import DIRECTION_CASES, POINT_CASES
from nerfify_ns.registry.params import param
from nerfify_ns.registry.terminal import Code, Constraint, Harness, TerminalDef

NERF_ENCODING = ("NeRFEncoding(in_dim=3, num_frequencies={{ p.num_frequencies }}, min_freq_exp={{ p.min_freq_exp }}, "
                 "max_freq_exp={{ p.max_freq_exp }}, include_input={{ p.include_input }})")
NERF_ENCODING_IMPORT = ("from nerfstudio.field_components.encodings import NeRFEncoding",)
SINUSOID_DIM = "3 * 2 * num_frequencies + 3 * include_input"
SMALL = {"num_levels": 4, "log2_hashmap_size": 12, "max_res": 64, "num_components": 8, "resolution": 16,
         "init_resolution": 16, "final_resolution": 16, "density_components": 4, "color_components": 6,
         "num_frequencies": 6, "resolutions": 16, "time_resolution": 4, "dim": 8}


def features(shape: str, doc: str = "encoded features") -> dict[str, Any]:
    return {"features": T(shape, grad=True, doc=doc)}


# ---------------------------------------------------------------------------------------- positions
@dataclass
class Positional:
    num_frequencies: int = param(10, range=(1, 32))
    """Number of frequencies L of gamma(p) (NeRF: 10 for positions)."""
    min_freq_exp: float = param(0.0, range=(-4.0, 32.0))
    """Exponent of the lowest frequency, 2^min_freq_exp."""
    max_freq_exp: float = param(8.0, range=(0.0, 32.0))
    """Exponent of the highest frequency, 2^max_freq_exp (NeRF: L - 1)."""
    include_input: bool = param(True)
    """Append the raw coordinates to the sinusoids."""


@dataclass
class IntegratedPositional(Positional):
    num_frequencies: int = param(16, range=(1, 32))
    """Number of frequencies L of the integrated encoding (Mip-NeRF: 16)."""
    max_freq_exp: float = param(16.0, range=(0.0, 32.0))
    """Exponent of the highest frequency (Mip-NeRF: 16)."""


@dataclass
class Hash:
    num_levels: int = param(16, range=(1, 32))
    """Number of resolution levels L."""
    min_res: int = param(16, range=(2, 8192))
    """Coarsest grid resolution N_min."""
    max_res: int = param(2048, range=(2, 65536))
    """Finest grid resolution N_max."""
    log2_hashmap_size: int = param(19, range=(8, 26))
    """log2 of the hash table size T per level."""
    features_per_level: int = param(2, range=(1, 8))
    """Feature dimension F stored per table entry."""


@dataclass
class KPlanes:
    resolutions: list[int] = param([64, 128, 256, 512], range=(2, 2048), length=(1, 6))
    """Spatial resolution of every scale (K-Planes: 64, 128, 256, 512)."""
    num_components: int = param(32, range=(1, 256))
    """Features per plane, C."""
    reduce: Literal["product", "sum"] = param("product")
    """How the planes of one scale combine: Hadamard product (K-Planes Eq. 2) or sum."""


@dataclass
class KPlanesTime(KPlanes):
    reduce: Literal["product", "sum", "paired"] = param("product")
    """How the planes of one scale combine: Hadamard product (K-Planes Eq. 2), sum, or HexPlane's pairs of a spatial
    and the complementary space-time plane multiplied, concatenated and projected by a learned basis (HexPlane
    Eq. 6)."""
    time_resolution: int = param(25, range=(2, 1024))
    """Resolution of the time axis of the space-time planes."""


@dataclass
class Triplane:
    resolution: int = param(128, range=(2, 2048))
    """Resolution of each of the three planes."""
    num_components: int = param(32, range=(1, 256))
    """Features per plane."""
    reduce: Literal["sum", "product"] = param("sum")
    """How the three planes combine."""


@dataclass
class FourierFeatures:
    num_frequencies: int = param(256, range=(1, 4096))
    """Number m of random frequencies, the rows of B (Tancik et al. 2020: 256)."""
    scale: float = param(10.0, range=(1.0e-3, 1000.0))
    """Standard deviation sigma of the Gaussian B ~ N(0, sigma^2) (Tancik et al. 2020: 10 for 3D scenes)."""
    include_input: bool = param(False)
    """Append the raw coordinates to the features."""


def _call_integrated(module, inputs, p):
    return {"features": module(inputs["means"], covs=inputs["covs"])}


def _call_times(module, inputs, p):
    return {"features": module(inputs["positions"], inputs["times"])}


POSITIONS_RAW = T("[N, 3]", grad=True, role="positions", doc="sample positions in world space")
POSITIONS_UNIT = T("[N, 3]", range=(0.0, 1.0), grad=True, role="positions", doc="positions normalised to the box")
POSITIONS_SIGNED = T("[N, 3]", range=(-1.0, 1.0), grad=True, role="positions", doc="positions in [-1, 1]")

TIMES_NEED_PADDED_SAMPLES = Constraint(
    "a space-time encoding reads each sample's ray time; instant-ngp's packed samples carry none",
    lambda p, plan: plan.get("base") != "instant-ngp")
"""Found by the fuzzer (seed 0 plans 10, 21): every training step failed for want of times."""

def coarse_to_fine(layout: str, bands: str) -> dict[str, Any]:
    """Traits of a field encoding whose bands a schedule hook may switch on from coarse to fine: an anneal of
    ``encoding_window.window`` wraps it in ``components.encoding_window.CoarseToFine`` (bands laid out as
    ``layout``, as many as its parameter ``bands``)."""
    return {"schedulable": ["encoding_window.window"], "window_layout": layout, "window_bands": bands}


POSITION_TERMINALS = [
    TerminalDef(
        "positional", "PosEncoding", Positional,
        "Sinusoidal positional encoding gamma(p) of raw positions (NeRF Eq. 4).",
        "nerfstudio.field_components.encodings.NeRFEncoding", card="positional_encoding", input_domain="raw",
        contract=Contract({"positions": POSITIONS_RAW}, features(f"[N, {SINUSOID_DIM}]")),
        code=Code(NERF_ENCODING_IMPORT, ctor=NERF_ENCODING,
                  traits={"domain": "raw", **coarse_to_fine("sinusoids", "num_frequencies")}),
        harness=Harness(cases=POINT_CASES, small=SMALL)),
    TerminalDef(
        "integrated_positional", "PosEncoding", IntegratedPositional,
        "Integrated positional encoding of conical-frustum Gaussians (Mip-NeRF Eq. 14).",
        "nerfstudio.field_components.encodings.NeRFEncoding", card="integrated_positional_encoding",
        input_domain="raw",
        contract=Contract({"means": POSITIONS_RAW,
                           "covs": T("[N, 3, 3]", grad=True, role="covariances", doc="Gaussian covariances")},
                          features(f"[N, {SINUSOID_DIM}]")),
        code=Code(NERF_ENCODING_IMPORT, ctor=NERF_ENCODING, traits={"domain": "gaussian"}),
        harness=Harness(call=_call_integrated, cases=POINT_CASES, small=SMALL),
        duties=({"requires_base": ["mipnerf"]},)),
    TerminalDef(
        "hash", "PosEncoding", Hash, "Multiresolution hash encoding (Instant-NGP Eq. 3).",
        "nerfstudio.field_components.encodings.HashEncoding", card="hash_grid", input_domain="unit",
        contract=Contract({"positions": POSITIONS_UNIT}, features("[N, num_levels * features_per_level]")),
        code=Code(("from nerfstudio.field_components.encodings import HashEncoding",),
                  ctor="HashEncoding(num_levels={{ p.num_levels }}, min_res={{ p.min_res }}, max_res={{ p.max_res }}, "
                       "log2_hashmap_size={{ p.log2_hashmap_size }}, features_per_level={{ p.features_per_level }}, "
                       "implementation=\"tcnn\")",
                  traits={"feature_grid": True, "domain": "unit", **coarse_to_fine("levels", "num_levels")}),
        harness=Harness(cases=POINT_CASES, small=SMALL)),
    TerminalDef(
        "kplanes", "PosEncoding", KPlanes,
        "Multi-scale k-planes (3 planes per scale, Hadamard product across planes; K-Planes Eq. 2-3).",
        "nerfify_ns.components.kplanes.MultiScaleKPlanes", card="kplanes", input_domain="signed_unit",
        contract=Contract({"positions": POSITIONS_SIGNED}, features("[N, len(resolutions) * num_components]")),
        code=Code(("from .components.kplanes import MultiScaleKPlanes",),
                  ctor="MultiScaleKPlanes(resolutions={{ p.resolutions }}, num_components={{ p.num_components }}, "
                       "reduce={{ p.reduce | tojson }})",
                  component="kplanes", traits={"feature_grid": True, "domain": "signed_unit"}),
        harness=Harness(cases=POINT_CASES, small=SMALL)),
    TerminalDef(
        "kplanes_time", "PosEncoding", KPlanesTime,
        "Space-time k-planes (6 planes over x,y,z,t per scale; K-Planes Eq. 2-3 with time).",
        "nerfify_ns.components.kplanes.MultiScaleKPlanes", card="kplanes", input_domain="signed_unit",
        contract=Contract({"positions": POSITIONS_SIGNED,
                           "times": T("[N, 1]", range=(0.0, 1.0), grad=True, role="values", doc="frame times")},
                          features("[N, len(resolutions) * num_components]")),
        code=Code(("from .components.kplanes import MultiScaleKPlanes",),
                  ctor="MultiScaleKPlanes(resolutions={{ p.resolutions }}, num_components={{ p.num_components }}, "
                       "reduce={{ p.reduce | tojson }}, time_resolution={{ p.time_resolution }})",
                  component="kplanes", traits={"feature_grid": True, "domain": "signed_unit", "times": True}),
        harness=Harness(call=_call_times, cases=POINT_CASES, small=SMALL),
        duties=({"requires_scene": {"timestamps": True}},), constraints=(TIMES_NEED_PADDED_SAMPLES,)),
    TerminalDef(
        "triplane", "PosEncoding", Triplane,
        "Single-resolution triplane features summed over the three planes (EG3D-style triplane).",
        "nerfstudio.field_components.encodings.TriplaneEncoding", card="triplane", input_domain="signed_unit",
        contract=Contract({"positions": POSITIONS_SIGNED}, features("[N, num_components]")),
        code=Code(("from nerfstudio.field_components.encodings import TriplaneEncoding",),
                  ctor="TriplaneEncoding(resolution={{ p.resolution }}, num_components={{ p.num_components }}, "
                       "reduce={{ p.reduce | tojson }})",
                  traits={"feature_grid": True, "domain": "signed_unit"}),
        harness=Harness(cases=POINT_CASES, small=SMALL)),
    TerminalDef(
        "fourier_features", "PosEncoding", FourierFeatures,
        "Random Fourier features gamma(v) = [cos(2 pi B v), sin(2 pi B v)], B ~ N(0, sigma^2) "
        "(Tancik et al. 2020, Eq. 5 / Sec. 6.1).",
        "nerfstudio.field_components.encodings.RFFEncoding", card="fourier_features", input_domain="unit",
        contract=Contract({"positions": POSITIONS_UNIT},
                          features("[N, 2 * num_frequencies + 3 * include_input]")),
        code=Code(("from nerfstudio.field_components.encodings import RFFEncoding",),
                  ctor="RFFEncoding(in_dim=3, num_frequencies={{ p.num_frequencies }}, scale={{ p.scale }}, "
                       "include_input={{ p.include_input }})",
                  traits={"domain": "unit"}),
        harness=Harness(cases=POINT_CASES, small={"num_frequencies": 16})),
]


# ---------------------------------------------------------------------------------------- directions
@dataclass
class SH:
    levels: int = param(4, range=(1, 4))
    """Number of spherical-harmonic bands (levels^2 coefficients)."""


@dataclass
class Frequency(Positional):
    num_frequencies: int = param(4, range=(1, 16))
    """Number of frequencies L of gamma(d) (NeRF: 4 for directions)."""
    min_freq_exp: float = param(0.0, range=(-4.0, 16.0))
    """Exponent of the lowest frequency."""
    max_freq_exp: float = param(4.0, range=(0.0, 16.0))
    """Exponent of the highest frequency."""


DIRECTIONS = T("[N, 3]", grad=True, role="directions", doc="unit viewing directions")

DIRECTION_TERMINALS = [
    TerminalDef(
        "sh", "DirEncoding", SH, "Real spherical harmonics of the view direction (Plenoxels / Instant-NGP).",
        "nerfstudio.field_components.encodings.SHEncoding", card="spherical_harmonics",
        contract=Contract({"directions": DIRECTIONS}, features("[N, levels ** 2]")),
        code=Code(("from nerfstudio.field_components.encodings import SHEncoding",),
                  ctor="SHEncoding(levels={{ p.levels }}, implementation=\"tcnn\")",
                  traits={"normalized_input": True}),
        harness=Harness(cases=DIRECTION_CASES)),
    TerminalDef(
        "frequency", "DirEncoding", Frequency, "Sinusoidal encoding of the view direction (NeRF Eq. 4 with L = 4).",
        "nerfstudio.field_components.encodings.NeRFEncoding", card="positional_encoding",
        contract=Contract({"directions": DIRECTIONS}, features(f"[N, {SINUSOID_DIM}]")),
        code=Code(NERF_ENCODING_IMPORT, ctor=NERF_ENCODING, traits={"normalized_input": False}),
        harness=Harness(cases=DIRECTION_CASES, small=SMALL)),
]


# ---------------------------------------------------------------------------------------- field parts
@dataclass
class Contraction:
    order: Literal["inf", "l2"] = param("inf")
    """Norm of the contraction: L-infinity (Nerfacto) or L2 (Mip-NeRF 360 Eq. 10)."""


@dataclass
class AppearanceEmbedding:
    dim: int = param(32, range=(1, 256))
    """Width of the per-image appearance code."""
    average_at_eval: bool = param(True)
    """Unseen images use the mean code (else zeros, as Nerfstudio's instant-ngp)."""


def _build_embedding(p, env):
    from nerfstudio.field_components.embedding import Embedding

    return Embedding(int(env["cameras"]), p["dim"])


FIELD_PART_TERMINALS = [
    TerminalDef(
        "scene_contraction", "SpatialDistortion", Contraction,
        "Mip-NeRF 360 contraction of unbounded space into a ball of radius 2 (Eq. 10).",
        "nerfstudio.field_components.spatial_distortions.SceneContraction", card="scene_contraction",
        contract=Contract({"positions": POSITIONS_RAW},
                          {"positions": T("[N, 3]", range=(-2.0, 2.0), doc="contracted positions")}),
        code=Code(("from nerfstudio.field_components.spatial_distortions import SceneContraction",),
                  ctor="SceneContraction(order={{ 'float(\"inf\")' if p.order == 'inf' else 'None' }})"),
        harness=Harness(cases=POINT_CASES),
        duties=({"requires_scene": {"bounded": False}},)),
    TerminalDef(
        "appearance_embedding", "MLPField", AppearanceEmbedding,
        "A per-image latent appearance code fed to the colour head (NeRF-W Eq. 11).",
        "nerfstudio.field_components.embedding.Embedding", card="appearance_embedding",
        contract=Contract({"camera_indices": T("[N]", "long", role="camera_indices")},
                          {"embedding": T("[N, dim]", doc="appearance codes")}),
        code=Code(("from nerfstudio.field_components.embedding import Embedding",)),
        harness=Harness(build=_build_embedding, cases=("empty_batch",), small=SMALL)),
]


# ---------------------------------------------------------------------------------------- tensorial
@dataclass
class TensorVM:
    init_resolution: int = param(128, range=(8, 1024))
    """Grid resolution at the start of training."""
    final_resolution: int = param(300, range=(8, 1024))
    """Grid resolution after the last upsampling."""
    upsampling_iters: list[int] = param([2000, 3000, 4000, 5500, 7000], range=(1, 10000000), length=(0, 16))
    """Iterations at which the grids are upsampled."""
    density_components: int = param(16, range=(1, 512))
    """Components of the density tensor."""
    color_components: int = param(48, range=(1, 512))
    """Components of the appearance tensor."""


@dataclass
class TensorCP(TensorVM):
    density_components: int = param(96, range=(1, 1024))
    """Rank-one components of the density tensor."""
    color_components: int = param(288, range=(1, 1024))
    """Rank-one components of the appearance tensor."""


TENSORF_CONFIG = {"tensorf": {"init_resolution": "init_resolution", "final_resolution": "final_resolution",
                              "upsampling_iters": "upsampling_iters", "density_components": "num_den_components",
                              "color_components": "num_color_components"}}


def _tensor_builder(cls_name: str):
    def build(p, env):
        from nerfstudio.field_components import encodings

        return getattr(encodings, cls_name)(resolution=p["init_resolution"], num_components=p["density_components"])

    return build


TENSOR_TERMINALS = [
    TerminalDef(
        "tensor_vm", "TensorDecomposition", TensorVM,
        "TensoRF vector-matrix decomposition of density and appearance grids (TensoRF Eq. 3).",
        "nerfstudio.field_components.encodings.TensorVMEncoding", card="tensorf_vm",
        contract=Contract({"positions": POSITIONS_SIGNED}, features("[N, 3 * density_components]")),
        code=Code(("from nerfstudio.field_components.encodings import TensorVMEncoding",),
                  traits={"feature_grid": True, "cls": "TensorVMEncoding"}),
        harness=Harness(build=_tensor_builder("TensorVMEncoding"), cases=POINT_CASES, small=SMALL),
        config=TENSORF_CONFIG),
    TerminalDef(
        "tensor_cp", "TensorDecomposition", TensorCP,
        "TensoRF CANDECOMP/PARAFAC decomposition (rank-one vector triples; TensoRF Eq. 2).",
        "nerfstudio.field_components.encodings.TensorCPEncoding", card="tensorf_cp",
        contract=Contract({"positions": POSITIONS_SIGNED}, features("[N, density_components]")),
        code=Code(("from nerfstudio.field_components.encodings import TensorCPEncoding",),
                  traits={"feature_grid": True, "cls": "TensorCPEncoding"}),
        harness=Harness(build=_tensor_builder("TensorCPEncoding"), cases=POINT_CASES, small=SMALL),
        config=TENSORF_CONFIG),
]

TERMINALS = [*POSITION_TERMINALS, *DIRECTION_TERMINALS, *FIELD_PART_TERMINALS, *TENSOR_TERMINALS]
