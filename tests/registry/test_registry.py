"""The terminal registry: one complete definition per terminal, contracts that a program checks (and that
fail when corrupted), the grammar export kept current."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from nerfify_ns.grammar import load_grammar, validate
from nerfify_ns.grammar.spec import parse_grammar
from nerfify_ns.knowledge.cards import load_cards
from nerfify_ns.registry import Contract, TensorSpec, default_registry
from nerfify_ns.registry.contract import SIZES, dims, symbols
from nerfify_ns.registry.terminal import replace
from nerfify_ns.synthesis.resources import load_reference_plan, reference_plans
from nerfify_ns.verify.components import run_terminal

ROOT = Path(__file__).resolve().parents[2]
FRAME = {"Method", "Base", "Optimizer", "Scheduler", "*"}
"""Productions of the method's frame (no technique card, no contract)."""
CARDLESS = {"deformation", "gaussian_deformation", "time_embedding", "frame_codes", "camera_time_offset", "field_blend",
            "gradient_importance", "view_selection", "anneal", "freeze", "image_curriculum"}
"""Terminals of the field-wrapper, pixel-sampler and schedule-hook productions whose technique cards are not in the
knowledge base yet (it is kept apart from the registry); their implementations' docstrings name the papers."""
REGISTRY = default_registry()
CHECKED = [t for t in REGISTRY if not t.contract.empty and not t.harness.in_model]


@pytest.fixture(scope="module", autouse=True)
def cpu_runtime():
    from nerfify_ns.runtime import activate

    activate(force=True)  # the contracts run on CPU tensors, also on a machine with CUDA


def test_committed_grammar_spec_is_the_registry_export():
    committed = (ROOT / "grammar_spec.yaml").read_text()
    assert committed == REGISTRY.export_yaml(), "grammar_spec.yaml is stale: run `python -m nerfify_ns.registry`"


def test_export_reads_back_as_the_same_grammar():
    exported = parse_grammar(REGISTRY.export_yaml())
    built = load_grammar()
    assert set(exported.terminals) == set(built.terminals)
    assert set(exported.nonterminals) == set(built.nonterminals)
    for name, term in built.terminals.items():
        assert exported.terminals[name].params == term.params, name
        assert exported.terminals[name].duties == term.duties, name
    for name in reference_plans():
        assert validate(load_reference_plan(name), exported).used == validate(load_reference_plan(name)).used


@pytest.mark.parametrize("name", list(REGISTRY.terminals))
def test_every_terminal_has_every_part(name):
    t = REGISTRY[name]
    assert t.doc and t.implementation and t.production, name
    for pname, spec in t.param_specs.items():
        assert spec.doc, f"{name}.{pname} has no docstring"
        if spec.type in ("int", "float"):
            assert spec.range is not None, f"{name}.{pname} has no range"
    if t.production in FRAME:
        return
    if name in CARDLESS and t.card is None:
        import importlib

        module, cls = t.implementation.rsplit(".", 1)
        doc = importlib.import_module(module).__doc__ or ""
        assert "arXiv" in doc and getattr(importlib.import_module(module), cls).__doc__, name
    else:
        assert t.card in load_cards(), f"{name}: card {t.card!r} is not in the knowledge base"
    if t.harness.in_model:
        return
    assert not t.contract.empty, f"{name} has no contract"
    assert t.harness.cases, f"{name} has no stiff cases"
    assert t.harness.build is not None or t.code.ctor, f"{name}: the ladder cannot build it"


@pytest.mark.parametrize("name", [t.name for t in CHECKED])
def test_contract_shapes_use_known_symbols(name):
    t = REGISTRY[name]
    known = set(SIZES) | set(t.param_specs) | set(t.contract.sizes) | set(t.contract.free) | {"out_dim"}
    for spec in [*t.contract.inputs.values(), *t.contract.outputs.values()]:
        assert set(symbols(spec.shape)) <= known, (name, spec.shape)


@pytest.mark.parametrize("name", [t.name for t in CHECKED])
def test_component_satisfies_its_contract(name):
    result = run_terminal(REGISTRY[name], None, "nominal")
    assert result.status == "pass", result.problems


def _corrupted(spec: TensorSpec) -> TensorSpec:
    parts = dims(spec.shape)
    return dataclasses.replace(spec, shape="[" + ", ".join([*parts, "2"]) + "]")


CORRUPTIONS = [(t.name, out) for t in CHECKED for out, spec in t.contract.outputs.items()
               if spec.dtype in ("float", "long")]


@pytest.mark.parametrize("name,output", CORRUPTIONS)
def test_a_corrupted_output_shape_fails_the_contract(name, output):
    """Every declared output shape is checked: declare it wrong and the contract check fails, naming the
    tensor, what the contract says and what the component returned (a placeholder contract cannot pass)."""
    t = REGISTRY[name]
    outputs = {**t.contract.outputs, output: _corrupted(t.contract.outputs[output])}
    corrupt = Contract(t.contract.inputs, outputs, t.contract.sizes, t.contract.free)
    result = run_terminal(replace(t, contract=corrupt), None, "nominal")
    assert result.status == "fail"
    message = next(p for p in result.problems if p.startswith(f"{output}: shape"))
    assert "contract" in message and outputs[output].shape in message


def test_every_production_that_accepts_custom_has_an_interface():
    g = load_grammar()
    for name, nt in g.nonterminals.items():
        if nt.accepts_custom:
            assert name in REGISTRY.interfaces, name
            assert not REGISTRY.interfaces[name].contract.empty


def test_card_terminals_are_registry_terminals():
    for card in load_cards().values():
        for terminal in card.terminals:
            assert terminal in REGISTRY, f"card {card.name} names unknown terminal {terminal}"


# ------------------------------------------------------------------ a technique is a card and one terminal
PACKAGE = ROOT / "nerfify_ns"


def _generic_hyperparameters() -> dict[str, dict]:
    import yaml

    return {e["name"]: e for e in yaml.safe_load((PACKAGE / "paper" / "hyperparams.yaml").read_text())}


def test_a_hyperparameter_one_technique_maps_lives_in_its_card():
    """A name of the generic hyperparameter file that exactly one card maps is that card's: its patterns belong in
    the card (``hyperparameter_patterns``), so adding a technique never edits ``paper/hyperparams.yaml``."""
    users: dict[str, set[str]] = {}
    for c in load_cards().values():
        for terminal in c.terminals:
            for m in c.hyperparameters_for(terminal):
                users.setdefault(m.name, set()).add(c.name)
    generic = _generic_hyperparameters()
    misplaced = {n: sorted(u) for n, u in users.items() if n in generic and len(u) == 1 and n not in GENERIC_NAMES}
    assert not misplaced, f"move these patterns into their card's hyperparameter_patterns: {misplaced}"
    own = {n: c.name for c in load_cards().values() for n in c.hyperparameter_patterns}
    assert not set(own) & set(generic), f"patterns both in hyperparams.yaml and a card: {set(own) & set(generic)}"


GENERIC_NAMES = {"lambda", "num_frequencies"}
"""Generic names a card may map (a loss weight of any term; the frequency count of several encodings)."""


def test_a_techniques_notation_and_signals_live_in_its_card():
    import yaml

    notation = yaml.safe_load((PACKAGE / "synthesis" / "novel" / "notation.yaml").read_text())
    assert not notation.get("cards"), "a card's notation belongs in the card (`notation:`), not in notation.yaml"
    detect = yaml.safe_load((PACKAGE / "knowledge" / "detect.yaml").read_text())["hyperparameter_cards"]
    own = {n for c in load_cards().values() for n in c.hyperparameter_patterns}
    assert not own & set(detect), f"signalled in detect.yaml and declared by a card: {own & set(detect)}"


def test_every_card_is_provided_by_its_own_paper():
    """A card's source paper comes from the card: the known paper of its arXiv id or title provides it (a card
    whose paper ``papers.yaml`` lacks adds that paper), so adding a technique never edits ``papers.yaml``."""
    from nerfify_ns.knowledge.papers import load_papers, normalize_title

    papers = load_papers()
    for c in load_cards().values():
        sources = [p for p in papers.values() if (c.paper.arxiv and p.arxiv == c.paper.arxiv)
                   or p.normalized_title == normalize_title(c.paper.title)]
        assert sources and any(c.name in p.provides for p in sources), c.name


def test_a_technique_needs_no_registry_file_beyond_its_terminal():
    """Terminal modules are found, not listed, and a terminal joins the production it names."""
    import pkgutil

    from nerfify_ns.registry import terminals

    found = {m.name for m in pkgutil.iter_modules(terminals.__path__)}
    assert found == {m.__name__.rsplit(".", 1)[1] for m in terminals.MODULES}
    for t in REGISTRY:
        if t.production in REGISTRY.nonterminals:
            nt = REGISTRY.nonterminals[t.production]
            assert t.name in (nt.get("alternatives") or nt.get("members") or [t.name]) or nt.get("kind") in (
                "sequence", "open", "map"), t.name


def test_a_base_model_is_defined_once():
    """``registry/bases.yaml`` is the one definition of a base: the Base terminals, the templates' facts, the smoke
    presets and the knowledge base's reference models read it; no other file names a base's facts."""
    import re

    import yaml

    from nerfify_ns.knowledge.patterns import read_bases
    from nerfify_ns.registry.bases import base_definitions, plugin_facts
    from nerfify_ns.runtime.presets import smoke_presets
    from nerfify_ns.synthesis.resources import reference_plans

    defined = base_definitions()
    assert [t.name for t in REGISTRY.of_production("Base")] == list(defined)
    assert set(plugin_facts()) == set(defined) and set(defined) <= set(smoke_presets())
    assert not (ROOT / "templates" / "bases.yaml").exists()
    presets = yaml.safe_load((PACKAGE / "runtime" / "smoke_presets.yaml").read_text()) or {}
    assert not set(presets) & set(defined), "a base's smoke preset belongs in registry/bases.yaml"
    assert "models" not in yaml.safe_load((PACKAGE / "knowledge" / "bases.yaml").read_text())
    from nerfify_ns.synthesis.resources import load_reference_plan

    assert set(reference_plans()) == set(read_bases().order)
    for name, base in defined.items():
        for plan in base["reference_plans"]:
            assert load_reference_plan(plan)["base"] == name, plan
    context = (PACKAGE / "synthesis" / "context.py").read_text()
    names = "|".join(re.escape(n) for n in defined)
    assert not re.search(rf"base_name\s*(?:==|!=|in)\s*[\(\[\"'](?:[^)\]]*[\"'](?:{names})[\"'])?", context), \
        "a base's special case belongs in its definition (registry/bases.yaml), not in synthesis/context.py"
