"""A plan's method name must be able to name a plugin: a valid project name, an import name
that is a non-keyword identifier, and no clash with a Nerfstudio built-in, another installed plugin or an
importable module; an earlier build of the same plugin is fine. ``validate`` checks it, so a plan file, a
reference plan and a paper all get the check."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from nerfify_ns import plan as plan_module
from nerfify_ns.grammar import PlanError, check, validate
from nerfify_ns.plan import free_method_name, method_name_problems, nerfstudio_builtin_methods, package_name
from nerfify_ns.synthesis.resources import load_reference_plan, reference_plans


def named(method: str) -> dict:
    plan = load_reference_plan("nerfacto")
    plan["method"] = method
    return plan


def rules(method: str) -> list:
    return [(v.path, v.rule) for v in check(named(method))]


def test_nerfstudio_built_ins_are_read_from_its_source():
    builtins = nerfstudio_builtin_methods()
    assert {"nerfacto", "instant-ngp", "vanilla-nerf", "mipnerf", "tensorf", "splatfacto", "neus-facto"} <= builtins
    assert {"kplanes", "zipnerf", "seathru-nerf"} <= builtins  # the external methods it offers to install
    code = ("import sys; from nerfify_ns.plan import nerfstudio_builtin_methods as b; b(); "
            "print('torch' in sys.modules, 'nerfstudio.configs.method_configs' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.stdout.split() == ["False", "False"], done.stderr  # read, not imported: a dry run stays light


@pytest.mark.parametrize("method, rule", [
    ("nerfacto", "method_shadows"),
    ("instant-ngp", "method_shadows"),
    ("kplanes", "method_shadows"),
    ("import", "method_name"),
    ("lambda", "method_name"),
    ("async", "method_name"),
    ("gridlite-", "method_name"),
    ("yaml", "method_shadows"),
    ("json", "method_shadows"),
    ("nerfify-ns", "method_shadows"),
    ("nerfify-generated", "method_shadows"),
])
def test_names_that_cannot_name_a_plugin_are_refused_by_validate(method, rule):
    assert rules(method) == [("method", rule)]
    with pytest.raises(PlanError, match=f"method: Plan: {rule}"):
        validate(named(method))


@pytest.mark.parametrize("method", ["gridlite", "nerfacto-ref", "kplanes-static", "match", "fuzz-0-12", "a--b"])
def test_good_names_pass(method):
    assert rules(method) == []


def test_every_reference_plan_is_named_well():
    for name in reference_plans():
        assert method_name_problems(load_reference_plan(name)["method"]) == [], name


def test_another_installed_plugin_is_refused_but_an_earlier_build_of_the_same_one_is_fine(monkeypatch):
    monkeypatch.setattr(plan_module, "installed_plugins", lambda: (
        ("gridlite", "gridlite.config:gridlite", "nerfify-gridlite"),  # an earlier build of ours
        ("foonerf", "foonerf_ns.config:foonerf", "foonerf-nerfstudio")))  # someone else's plugin
    assert method_name_problems("gridlite") == []
    (problem,) = method_name_problems("foonerf")
    assert problem[0] == "method_shadows" and "installed Nerfstudio plugin 'foonerf'" in problem[1]
    assert "foonerf-nerfstudio" in problem[1]


def test_a_generated_plugin_folder_on_the_path_is_an_earlier_build(tmp_path, monkeypatch):
    """A plugin folder nerfify generated (nerfify.json next to the package) shadows nothing of someone else's;
    a package of the same name from elsewhere does."""
    ours = tmp_path / "ours" / "oldbuild"
    (ours / "oldbuild").mkdir(parents=True)
    (ours / "oldbuild" / "__init__.py").write_text("")
    (ours / "nerfify.json").write_text(json.dumps({"method": "oldbuild", "package": "oldbuild"}))
    theirs = tmp_path / "theirs"
    (theirs / "someonespkg").mkdir(parents=True)
    (theirs / "someonespkg" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(ours))
    monkeypatch.syspath_prepend(str(theirs))
    assert method_name_problems("oldbuild") == []
    (problem,) = method_name_problems("someonespkg")
    assert problem[0] == "method_shadows" and str(theirs) in problem[1]


def test_paper_names_step_aside_instead_of_shadowing():
    from nerfify_ns.synthesis.plan_from_paper import slug

    class Doc:
        title = ""

    for title, expected in [("TensoRF: Tensorial Radiance Fields", "tensorf-paper"),
                            ("Import: a NeRF", "import-paper"),
                            ("GridLite: hash grids", "gridlite")]:
        doc = Doc()
        doc.title = title
        assert slug(doc) == expected
    assert free_method_name("nerfacto") == "nerfacto-paper" and package_name("kplanes-static") == "kplanes_static"
