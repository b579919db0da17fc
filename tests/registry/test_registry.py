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
CARDLESS = {"deformation", "time_embedding", "frame_codes", "camera_time_offset", "field_blend",
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
