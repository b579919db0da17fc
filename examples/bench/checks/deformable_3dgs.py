"""Checks of Deformable 3D Gaussians (Yang et al. 2024) items: reference functions written from the paper, run
against the generated components (the Gaussian deformation and schedule hooks of the plan, built from its
sentences)."""

import _refs  # checks/_refs.py: the check's folder is on sys.path in the check process
import torch


def _part(target, name: str) -> dict:
    params = (_refs.as_derived(target) or {}).get(name)
    assert params is not None, f"no {name} in the plan's {target.path}"
    return params


def deformation_of(params: dict) -> None:
    """Eqs. 4-5 (shared with 4D-GS's decoder, Eq. 8): (dx, dr, ds) = F(gamma(sg(x)), gamma(t)), the Gaussian at t
    has centre x + dx, rotation r + dr and scale s + ds: every offset depends on the time, the centre learns only
    through x + dx (sg), the time is kept."""
    from nerfify_ns.components.field_wrappers import GaussianDeformation

    net = GaussianDeformation(**params).double()
    torch.nn.init.normal_(net.network[-1].weight, std=0.1)  # trained weights: the offsets are no longer zero
    if params.get("encoding") == "planes":  # trained space-time planes (they start at 1: no motion over t)
        for plane in net.position_encoding.time_planes:
            torch.nn.init.uniform_(plane, 0.5, 1.5)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(5, 3, generator=g, dtype=torch.float64, requires_grad=True)
    cams = torch.zeros(5, dtype=torch.long)
    t_a, t_b = torch.full((5, 1), 0.3, dtype=torch.float64), torch.full((5, 1), 0.7, dtype=torch.float64)
    moved_a, kept, offsets_a = net(x, t_a, cams)
    moved_b, _, offsets_b = net(x, t_b, cams)
    assert torch.equal(kept, t_a) and offsets_a.shape == (5, 7), offsets_a.shape
    assert not torch.allclose(moved_a, moved_b), "the centres' offset does not depend on the time"
    assert not torch.allclose(offsets_a[:, :4], offsets_b[:, :4]), "the rotation offset does not depend on the time"
    assert not torch.allclose(offsets_a[:, 4:], offsets_b[:, 4:]), "the scale offset does not depend on the time"
    if params.get("stop_gradient", True):
        moved_a.sum().backward()
        torch.testing.assert_close(x.grad, torch.ones_like(x))  # sg: no gradient through gamma(x)


def deformation_field(target):
    """Sec. 3.2, Eqs. 4-5: the deformation MLP of depth D = 8 and width W = 256 on gamma(sg(x)), gamma(t)."""
    params = _part(target, "gaussian_deformation")
    assert (params["num_layers"], params["layer_width"]) == (8, 256), params
    deformation_of(params)


def annealing_smooth_training(target):
    """Sec. 3.3, Eq. 6: gamma(t) + X(i), X(i) = N(0, 1) beta dt max(1 - i / tau, 0), beta = 0.1, tau = 20k: the
    noise's scale decays linearly from beta to 0 at tau and stays 0."""
    from nerfify_ns.components.schedule_hooks import Anneal

    params = _part(target, "anneal")
    assert params["target"] == "deformation.time_noise", params
    hook = Anneal(**params)
    values = hook(torch.tensor([0, 10000, 20000, 30000])).double()
    torch.testing.assert_close(values, torch.tensor([0.1, 0.05, 0.0, 0.0], dtype=torch.float64))


def warmup_of(params: dict, steps: int) -> None:
    """The Gaussians are trained alone for the first ``steps`` iterations: the deformation is held until then."""
    from nerfify_ns.components.schedule_hooks import Freeze

    assert params["module"] == "deformation", params
    frozen = Freeze(**params)(torch.tensor([0, steps - 1, steps, steps + 1000]))
    assert frozen.tolist() == [1, 1, 0, 0], frozen.tolist()


def gaussian_warmup(target):
    """Sec. 4.1: "During the initial 3k iterations, we solely trained the 3D Gaussians"."""
    warmup_of(_part(target, "freeze"), 3000)


def gaussians(target):
    """Sec. 3.1 (3D-GS's Gaussians): the canonical Gaussians are what the deformation moves, one offset each: the
    plan deforms Gaussians, not a field's samples."""
    assert "gaussian_deformation" in (_refs.as_derived(target) or {}), target.path
    assert target.plan.get("base") == "splatfacto", target.plan.get("base")


def density_control(target):
    """Sec. 3.1 (3D-GS's adaptive density control, followed by the paper): transparent Gaussians are pruned, small
    ones with large positional gradients cloned, large ones split, every so many steps: the plan stands on
    splatfacto, whose model refines its Gaussians with gsplat's strategy of clone, split and prune."""
    assert target.value == "splatfacto", f"the plan stands on {target.value}, which has no Gaussians to refine"
    from gsplat.strategy import DefaultStrategy
    from nerfstudio.models.splatfacto import SplatfactoModelConfig

    config = SplatfactoModelConfig()
    assert config.refine_every > 0 and config.stop_split_at > config.warmup_length, "no refinement steps"
    assert config.cull_alpha_thresh > 0, "transparent Gaussians are never pruned"
    assert config.densify_grad_thresh > 0 and config.densify_size_thresh > 0, "no clone or split by gradient and size"
    strategy = DefaultStrategy(prune_opa=config.cull_alpha_thresh, grow_grad2d=config.densify_grad_thresh,
                               grow_scale3d=config.densify_size_thresh, refine_every=config.refine_every)
    assert callable(getattr(strategy, "step_post_backward", None)), "the strategy does not act after a step"
