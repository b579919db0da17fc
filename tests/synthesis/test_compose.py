"""The composer: reference plans -> plugin packages that are clean Python, traced to the plan, written
atomically, and (in a subprocess, since generated code is untrusted) build the same model as the
built-in Nerfstudio method they are equivalent to."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from nerfify_ns.atomic import OutputExistsError
from nerfify_ns.grammar import PlanError
from nerfify_ns.plan import Plan, PlanFileError
from nerfify_ns.synthesis.compose import compose, plugin_files
from nerfify_ns.synthesis.plugin_lookup import ENV_GENERATED, generated_plugin_dir
from nerfify_ns.synthesis.resources import UnknownReferencePlanError, load_reference_plan, reference_plans

RUFF = Path(sys.executable).with_name("ruff")
BUILTIN = {"vanilla-nerf": "vanilla-nerf", "mipnerf": "mipnerf", "nerfacto": "nerfacto",
           "instant-ngp": "instant-ngp", "tensorf": "tensorf"}


@pytest.fixture(scope="module")
def plugins(tmp_path_factory):
    root = tmp_path_factory.mktemp("plugins")
    return {name: compose(load_reference_plan(name), root / name, record=False) for name in reference_plans()}


def test_every_reference_plan_composes_into_a_complete_package(plugins):
    for name, plugin in plugins.items():
        pkg = plugin.package
        files = set(plugin.files)
        field = {f"{pkg}/field.py"} if "field" in load_reference_plan(name)["model"] else set()  # Gaussians: none
        assert {f"{pkg}/config.py", f"{pkg}/model.py", *field, f"{pkg}/__init__.py", "pyproject.toml",
                "README.md", "plan.yaml"} <= files
        assert field or f"{pkg}/field.py" not in files
        pyproject = (plugin.out / "pyproject.toml").read_text()
        assert '[project.entry-points."nerfstudio.method_configs"]' in pyproject
        assert f'{plugin.method} = "{pkg}.config:{pkg}_method"' in pyproject
        assert yaml.safe_load((plugin.out / "plan.yaml").read_text()) == load_reference_plan(name)


def test_generated_code_is_formatted_and_has_no_unused_imports(plugins):
    for plugin in plugins.values():
        py_files = [str(plugin.out / f) for f in plugin.files if f.endswith(".py")]
        fmt = subprocess.run([str(RUFF), "format", "--check", "--line-length", "110", *py_files],
                             capture_output=True, text=True)
        assert fmt.returncode == 0, fmt.stdout + fmt.stderr
        lint = subprocess.run([str(RUFF), "check", "--select", "F,I", "--line-length", "110", *py_files],
                              capture_output=True, text=True)
        assert lint.returncode == 0, lint.stdout


def test_no_dead_template_branches(plugins):
    """Only what the plan uses is rendered: no contraction, appearance code or components when absent."""
    vanilla = (plugins["vanilla-nerf"].out / "vanilla_nerf_ref" / "field.py").read_text()
    assert "SceneContraction" not in vanilla and "Embedding" not in vanilla and "SceneBox" not in vanilla
    assert not (plugins["vanilla-nerf"].out / "vanilla_nerf_ref" / "components").exists()
    kplanes = plugins["kplanes-static"].out / "kplanes_static"
    assert (kplanes / "components" / "kplanes.py").is_file()
    assert "nerfify_ns" not in "".join(p.read_text() for p in kplanes.rglob("*.py"))  # stands alone


def test_files_are_generated_in_dependency_order(plugins):
    ctx = {"package": "pkg", "components": ["kplanes"], "custom_modules": ["components.novel"],
           "field_template": "field_mlp.py.j2", "model_template": "model.py.j2"}
    graph = plugin_files(ctx)
    order = list(__import__("networkx").topological_sort(graph))
    for before, after in [("pkg/components/kplanes.py", "pkg/field.py"), ("pkg/components/novel.py", "pkg/field.py"),
                          ("pkg/components/__init__.py", "pkg/components/novel.py"), ("pkg/field.py", "pkg/model.py"),
                          ("pkg/model.py", "pkg/config.py"), ("pkg/config.py", "pyproject.toml"),
                          ("plan.yaml", "README.md")]:
        assert order.index(before) < order.index(after)


def test_readme_maps_parts_to_plan_entries_and_evidence(plugins):
    readme = (plugins["kplanes-static"].out / "README.md").read_text()
    plan = load_reference_plan("kplanes-static")
    assert "`model.field.MLPField.pos_encoding.kplanes`" in readme
    assert plan["evidence"]["model.field.MLPField.pos_encoding"] in readme
    assert "K-Planes: Explicit Radiance Fields in Space, Time, and Appearance" in readme
    config = (plugins["kplanes-static"].out / "kplanes_static" / "config.py").read_text()
    assert "near_plane=2.0,  # model.bounds.near_plane" in config


def test_invalid_plan_writes_nothing(tmp_path):
    plan = load_reference_plan("nerfacto")
    del plan["model"]["losses"]["interlevel"]
    with pytest.raises(PlanError, match="requires_loss"):
        compose(plan, tmp_path / "out", record=False)
    assert not (tmp_path / "out").exists() and list(tmp_path.iterdir()) == []


def test_existing_output_is_not_overwritten_without_asking(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError):
        compose(load_reference_plan("nerfacto"), tmp_path / "out", record=False)
    assert (tmp_path / "out" / "keep.txt").read_text() == "mine"


def test_bad_plan_files_and_names_get_clear_errors(tmp_path):
    (tmp_path / "bad.yaml").write_text("model: [unclosed")
    with pytest.raises(PlanFileError, match="cannot read plan"):
        Plan.load(tmp_path / "bad.yaml")
    (tmp_path / "list.yaml").write_text("- a\n- b\n")
    with pytest.raises(PlanFileError, match="not a plan"):
        Plan.load(tmp_path / "list.yaml")
    with pytest.raises(UnknownReferencePlanError, match="known: instant-ngp"):
        load_reference_plan("nerf-w")


def test_compose_keeps_no_global_pointer_and_the_env_overrides(tmp_path, monkeypatch):
    """No "last generated" file (parallel runs would race through it): a plugin composed elsewhere is not
    what nerfify-generated trains; the newest under ./nerfify-out is, or the folder in the variable."""
    monkeypatch.setenv("NERFIFY_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(ENV_GENERATED, raising=False)
    monkeypatch.chdir(tmp_path)
    assert generated_plugin_dir() is None
    compose(load_reference_plan("vanilla-nerf"), tmp_path / "v")
    assert generated_plugin_dir() is None and not (tmp_path / "cache").exists()
    plugin = compose(load_reference_plan("vanilla-nerf"), tmp_path / "nerfify-out" / "v")
    assert generated_plugin_dir() == plugin.out
    monkeypatch.setenv(ENV_GENERATED, str(tmp_path / "elsewhere"))
    assert generated_plugin_dir() == tmp_path / "elsewhere"


_BUILD = textwrap.dedent('''
    import dataclasses, json, sys, torch
    from nerfstudio.configs.method_configs import all_methods
    from nerfify_ns.benchmarks.step_timing import build_model, ray_batch, run_before_iteration_callbacks
    from nerfify_ns.synthesis.plugin_lookup import load_plugin_method

    def build(config):
        model = build_model(config, seed=0)
        return model, torch.random.get_rng_state()

    def flat(obj, prefix=""):
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
            items = [(f.name, getattr(obj, f.name)) for f in dataclasses.fields(obj)]
        elif isinstance(obj, dict):
            items = list(obj.items())
        else:
            return {prefix[:-1]: obj if isinstance(obj, (bool, int, float, str, type(None))) else repr(obj)}
        return {k: v for name, value in items for k, v in flat(value, f"{prefix}{name}.").items()}

    generated = load_plugin_method(sys.argv[1]).config
    builtin = all_methods[sys.argv[2]]
    for cfg in (generated, builtin):
        cfg.pipeline.model.eval_num_rays_per_chunk = 64
    (a, rng_a), (b, rng_b) = build(generated), build(builtin)
    fa, fb = flat(generated), flat(builtin)
    differ = sorted(k for k in set(fa) | set(fb) if fa.get(k) != fb.get(k))
    empty_groups = sorted(k for k in builtin.optimizers if not b.get_param_groups().get(k))
    groups = {k: sum(p.numel() for p in v) for k, v in a.get_param_groups().items()}
    same_init = all(torch.equal(x, y) for x, y in zip(
        sorted((p for p in a.parameters()), key=lambda t: (tuple(t.shape), t.sum().item())),
        sorted((p for p in b.parameters()), key=lambda t: (tuple(t.shape), t.sum().item()))))
    bundle, _ = ray_batch(256)
    rgb_max_diff = {}
    for training in (True, False):
        rgbs = []
        for model in (a, b):
            model.train(training)
            torch.manual_seed(3)
            if training:  # nerfacc's occupancy grid refuses updates in eval mode; eval keeps the trained grid
                run_before_iteration_callbacks(model, 0)
            with torch.no_grad():
                outputs = model.get_outputs(bundle._apply_fn_to_fields(torch.clone))
            rgbs.append(outputs["rgb_fine"] if "rgb_fine" in outputs else outputs["rgb"])
        rgb_max_diff["train" if training else "eval"] = (rgbs[0] - rgbs[1]).abs().max().item()
    print(json.dumps({"type": type(a).__mro__[1].__name__, "builtin": type(b).__name__,
                      "rgb_max_diff": rgb_max_diff,
                      "params": sum(p.numel() for p in a.parameters()),
                      "builtin_params": sum(p.numel() for p in b.parameters()),
                      "groups": groups, "optimizers": sorted(generated.optimizers), "same_init": same_init,
                      "same_rng_after_init": torch.equal(rng_a, rng_b), "config_differs": differ,
                      "builtin_empty_groups": empty_groups,
                      "regularization": getattr(generated.pipeline.model, "regularization", None)}))
''')

# Config entries a generated plugin may set differently from the built-in method: its names, the
# device (our runtime picks it at ns-train time), logging/viewer and evaluation chunk sizes.
MAY_DIFFER = re.compile(r"^(method_name|machine\.device_type|vis|pipeline\.model\._target|"
                        r"viewer\.num_rays_per_chunk|"
                        # the generated field's backbone depth and width, fields of the generated config only (the
                        # plan's values their defaults: a CPU proxy may set the width)
                        r"pipeline\.model\.mlp_(num_layers|layer_width))$")


def _unexplained_config_differences(result: dict) -> list:
    """Differences left after the allowed ones: an optimiser group the built-in configures but its model
    gives no parameters (camera optimiser off, NeRF's temporal_distortion) and TensoRF's l1_reg
    coefficient, which its model reads only under ``regularization='l1'``."""
    empty = tuple(f"optimizers.{g}." for g in result["builtin_empty_groups"])
    return [k for k in result["config_differs"] if not MAY_DIFFER.match(k) and not k.startswith(empty)
            and not (k == "pipeline.model.loss_coefficients.l1_reg" and result["regularization"] != "l1")]


BENCH_ONLY = {"instant-ngp", "mipnerf", "tensorf", "kplanes-static"}
"""Equivalence of these bases is checked in the benchmark lane (and by the parity benchmark); CI keeps nerfacto (hash
grid and proposal sampler) and vanilla-nerf (MLP field, hierarchical sampling)."""


@pytest.mark.parametrize("name", [pytest.param(n, marks=[pytest.mark.bench] if n in BENCH_ONLY else [])
                                  for n in sorted(BUILTIN)])
def test_generated_model_matches_the_builtin_method(plugins, name):
    """Same base class, parameter count, optimiser groups, every training-relevant config value and (same
    seed) the same initial weights and random stream afterwards: so a run draws the same rays."""
    out = subprocess.run([sys.executable, "-c", _BUILD, str(plugins[name].out), BUILTIN[name]],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["type"] == result["builtin"]
    assert result["params"] == result["builtin_params"]
    assert sorted(result["groups"]) == result["optimizers"]
    assert result["same_init"], result
    assert result["same_rng_after_init"], "the generated model draws a different number of random values"
    assert _unexplained_config_differences(result) == [], result["config_differs"]
    # the same weights render the same colours, while training (stratified jitter under one seed) and
    # when rendering a held-out view (where e.g. an unseen image's appearance code is chosen)
    assert result["rgb_max_diff"] == {"train": 0.0, "eval": 0.0}, result["rgb_max_diff"]
