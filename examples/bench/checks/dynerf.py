"""Checks of DyNeRF (Li et al. 2022) items: reference functions written from the paper, run against the generated
components (typed field wrappers, schedule hooks and pixel samplers of the plan, built from its sentences)."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
import numpy as np
import torch


def _codes(target) -> dict:
    params = (_refs.as_derived(target) or {}).get("frame_codes")
    assert params, "no time-variant latent codes in the plan"
    return params


def latent_codes(target):
    """Eq. 2: F(x, d, z_t) -> (c, sigma), z_t a learned latent code per frame, the codes of different frames
    independent: the plan's codes give each frame its own learned code, appended to the field's input, and leave
    positions and times as they are."""
    from nerfify_ns.components.field_wrappers import FrameCodes

    params = _codes(target)
    codes = FrameCodes(num_frames=params["num_frames"], dim=params["dim"]).double()
    n = params["num_frames"]
    t = torch.tensor([[0.0], [1.0 / (n - 1)], [1.0]], dtype=torch.float64)
    x = torch.rand(3, 3, dtype=torch.float64)
    x_out, t_out, z = codes(x, t, torch.zeros(3, dtype=torch.long))
    assert torch.equal(x_out, x) and torch.equal(t_out, t)
    torch.testing.assert_close(z, codes.codes[[0, 1, n - 1]].detach())
    z.sum().backward()
    assert codes.codes.grad is not None and codes.codes.grad[[0, 1, n - 1]].abs().sum() > 0, "the codes are not learned"


def latent_code_size(target):
    """Sec. 5 (implementation details): 1024-dimensional latent codes."""
    dim = _codes(target)["dim"]
    assert dim == 1024, f"latent codes of {dim} values, the paper's 1024"


def hierarchical_training(target):
    """Sec. 3.3: training first on keyframes, K = 30 frames apart, then on the full sequence: the plan's curriculum
    keeps only every 30th frame active at the start and every frame at the end."""
    from nerfify_ns.components.schedule_hooks import ImageCurriculum

    params = (_refs.as_derived(target) or {}).get("image_curriculum")
    assert params, "no curriculum over frames in the plan"
    assert params["rule"] == "keyframes" and params["keyframe_stride"] == 30, params
    hook = ImageCurriculum(**params)
    early, late = hook(torch.tensor([0])), hook(torch.tensor([int(params["end_step"]) + 1]))
    assert float(early) < float(late), (float(early), float(late))


def ray_importance_sampling(target):
    """Sec. 3.4, Eq. 5 (DyNeRF-ISG): rays are drawn in proportion to a weight of their colour's temporal
    variation, the residual against the global median over time: a pixel that never changes is drawn no more
    often than the floor, one that changes is drawn more. Checked on a video whose frames are identical except a
    flat band that changes in time: the plan's map must weight the changing band above static textured pixels."""
    from nerfify_ns.components import pixel_samplers

    (name, params), = (target.value or {}).items()
    cls = {"gradient_importance": pixel_samplers.GradientImportance,
           "view_selection": pixel_samplers.ViewSelection}.get(name)
    assert cls is not None, f"the plan's pixel sampler {name} has no map to check"
    frames = torch.full((4, 16, 16, 3), 0.5)
    frames[:, 10:14, 10:14] = 0.0
    frames[:, 10:14, 10:14:2] = 1.0  # static stripes: a strong spatial gradient, no change in time
    for k in range(4):
        frames[k, :, 0:4] = k / 3.0  # a flat band whose colour changes over time
    weights = cls(**params)(frames, torch.arange(4))
    changing = float(weights[:, 1:15, 0:2].mean())  # inside the band, away from its edge
    static = float(weights[:, 10:14, 10:14].mean())
    assert changing > static, f"the changing patch weighs {changing:.3g}, the static stripes {static:.3g}"


def loss(target):
    """Eq. 4: the squared error between rendered and observed colours (of the coarse and the fine rendering)."""
    assert target.path.endswith(".l2") or "l2" in (target.value or {}), f"colour loss {target.value}, not L2"
    _refs.mse(torch.nn.MSELoss())


def mlp(target):
    """Sec. 5 (implementation details): NeRF's MLP with 512 activations in its first 8 layers instead of 256."""
    v = _refs.as_derived(target)
    assert (v["num_layers"], v["layer_width"]) == (8, 512), \
        f"{v['num_layers']} layers of {v['layer_width']}, the paper's 8 of 512"
    assert np.isfinite(v["layer_width"])
