"""The equation compiler's binding stage (synthesis/novel): the shared notation table, the paper's own words, widths,
a paper never seen compiled into a component with persistent state, equations.yaml corrections and reuse, and
hostile symbol names. No shared papers needed (tests/synthesis/test_novel_papers.py has the real ones)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml
from novel_papers import GATENERF, GATENERF_NO_WIDTH

from nerfify_ns.equations import parse_equation
from nerfify_ns.paper import ingest
from nerfify_ns.synthesis.novel import IMPLEMENTED, NOT_IMPLEMENTED, implement_holes
from nerfify_ns.synthesis.novel.notation import NOTATION_FILE, Notation, PaperWords
from nerfify_ns.synthesis.novel.records import EquationsFileError, read_corrections, write_records
from nerfify_ns.synthesis.novel.widths import WidthError, Widths
from nerfify_ns.synthesis.plan_from_paper import plan_from_paper


@pytest.fixture(scope="module")
def gatenerf(tmp_path_factory):
    path = tmp_path_factory.mktemp("papers") / "gatenerf.md"
    path.write_text(GATENERF)
    doc = ingest(path)
    return doc, plan_from_paper(doc)


@pytest.fixture(scope="module")
def gate_result(gatenerf):
    doc, derived = gatenerf
    return implement_holes(doc, derived.plan)


def _component(result, hole_id):
    record = next(r for r in result.records if r.id == hole_id)
    namespace = {"__name__": "compiled_for_test"}
    exec(compile(record.source, "<component>", "exec"), namespace)  # noqa: S102 - our own generated source
    return record, namespace[record.component["class"]]


# ------------------------------------------------------------------------------------------ the table
def test_the_shared_table_holds_only_shared_notation():
    notation = Notation.load()
    data = yaml.safe_load(NOTATION_FILE.read_text())
    for name, entry in data["symbols"].items():
        assert entry["role"] in notation.roles
        assert re.fullmatch(r"[A-Za-z]+", name) and (len(name) == 1 or name.lower() in {
            "sigma", "tau", "delta", "alpha", "gamma", "theta", "lambda", "epsilon"}), name
    assert notation.table_role(parse_equation(r"y = \sigma_i").rhs) == "density"
    assert notation.table_role(parse_equation(r"y = C^*(\mathbf{r})").rhs) == "target_colour"
    assert notation.table_role(parse_equation(r"y = \hat{C}(\mathbf{r})").rhs) == "ray_colour"
    assert notation.table_role(parse_equation(r"y = \mathbf{W}_{\gamma}").rhs) == "weight_matrix"
    assert notation.table_role(parse_equation(r"y = \Psi").rhs) is None  # a paper's own symbol is not shared


def test_the_papers_own_words_are_read(gatenerf):
    doc, _ = gatenerf
    words = PaperWords.read(doc)
    w_g = parse_equation(r"y = \mathbf{W}_g").rhs
    assert words.definition(w_g).role == "weight_matrix" and "gate weight matrix" in words.definition(w_g).quote
    assert words.definition(parse_equation(r"y = \mathbf{b}_g").rhs).role == "bias"
    (rows, _, _), (width, _, _) = words.shape_of(parse_equation(r"y = \mathbf{m}").rhs)
    assert (rows, width) == (64, 32)
    assert words.names(parse_equation(r"y = \mathbf{h}_a").rhs)
    assert not words.names(parse_equation(r"y = \mathbf{h}_x").rhs)
    assert [w for w, _, _ in words.widths][:1] == [32] and [n for n, _, _ in words.layers] == [2]


def test_text_layer_symbols_and_definitions():
    class Para:
        def __init__(self, text):
            self.text, self.loc = text, type("L", (), {"page": 3, "line": None})()

    class Sec:
        heading, paragraphs = "3 Method", [Para("where WΨ and bΨ are the memory weight matrix and bias, respectively. "
                                                 "The memory is concatenated with the camera 3D coordinates. Update "
                                                 "the memory Ψ ∈Rz×h, where z = 8, 192 is the number of rays and "
                                                 "h = 256. Assuming σobj, cobj, σmed, cmed constant.")]

    words = PaperWords.read(type("D", (), {"sections": [Sec()], "hyperparameters": []})())
    assert words.definition(parse_equation(r"y = W_{\Psi}").rhs).role == "weight_matrix"
    assert words.definition(parse_equation(r"y = b_{\Psi}").rhs).role == "bias"
    assert [r for r, _, _ in words.concat_roles] == ["position"]
    (rows, _, _), (width, _, _) = words.shape_of(parse_equation(r"y = \Psi").rhs)
    assert (rows, width) == (8192, 256)
    assert words.names(parse_equation(r"y = \sigma^{med}").rhs) and words.names(parse_equation(r"y = c^{obj}").rhs)


def test_widths_follow_the_equations_and_refuse_contradictions():
    eqs = [parse_equation(r"g = \sigma(W [a, b] + v)"), parse_equation(r"o = g \odot c")]
    w = Widths()
    w.known("a", (3,)), w.known("b", (5,)), w.known("c", (7,))
    w.matrix("W"), w.vector("v")
    w.run(eqs)
    assert w.value("W") == (7, 8) and w.value("v") == (7,) and w.value("o") == (7,)
    bad = Widths()
    bad.known("g", (4,)), bad.known("c", (7,))
    with pytest.raises(WidthError, match="widths 4 and 7"):
        bad.run([parse_equation(r"o = g \odot c", number="9")])


# ------------------------------------------------------------------------------------------ a paper never seen
def test_a_paper_never_seen_compiles_into_its_backbone(gate_result):
    (record,) = gate_result.records
    assert record.status == IMPLEMENTED, record.reason
    assert record.component["implements"] == ["Eq. 1", "Eq. 2", "Eq. 3"]
    assert record.bindings["h_a"]["as"] == "network" and record.bindings["h_a"]["network"]["width"] == 32
    assert record.bindings["W_g"]["source"] == "paper" and record.bindings["m"]["as"] == "state"
    assert record.sizes["W_g"]["shape"] == [32, 64] and record.sizes["W_m"]["shape"] == [32, 32]
    assert record.state["m"]["rows"] == 64 and "detached" in record.state["m"]["note"]
    assert record.checks["lowering"].startswith("passed") and "gradcheck passed" in record.checks["lowering"]
    entry = gate_result.plan.get("model.field.MLPField.backbone.custom")
    assert entry["source"] == "compiler" and entry["module"] in gate_result.sources
    assert gate_result.plan["holes"][0]["status"] == IMPLEMENTED


def test_persistent_state_is_kept_detached_checkpointed_and_unchanged_at_eval(gate_result):
    import torch

    record, cls = _component(gate_result, "backbone")
    module = cls(in_dim=11)
    assert module.get_out_dim() == 64
    assert "state_m" in module.state_dict() and module.state_m.shape == (64, 32)
    x = torch.randn(2, 5, 11)
    with torch.no_grad():
        module.equations.p_b_m.fill_(0.3)  # as after some training: m = tanh(W_m (g . m) + b_m) leaves zero
    module.train()
    out = module(x)
    assert out.shape == (2, 5, 64) and not module.state_m.requires_grad
    after_one = module.state_m.clone()
    assert after_one.abs().sum() > 0  # the step stored its memory
    out.sum().backward()  # no gradient flows into the stored state
    module.eval()
    with torch.no_grad():
        module(x)
    assert torch.equal(module.state_m, after_one)  # evaluation reads the memory, never writes it


def test_the_compiled_module_is_the_papers_equations(gate_result):
    """A reference written by hand from GateNeRF's Eqs. 1-3, against the generated module."""
    import torch

    record, cls = _component(gate_result, "backbone")
    module = cls(in_dim=11).double()
    eq = module.equations
    rng = np.random.default_rng(0)
    ha, hb, m = (rng.normal(size=(6, 32)) for _ in range(3))
    wg, bg = eq.p_w_g.detach().numpy(), eq.p_b_g.detach().numpy()
    wm, bm = eq.p_w_m.detach().numpy(), eq.p_b_m.detach().numpy()
    g = 1 / (1 + np.exp(-(np.concatenate([ha, hb], -1) @ wg.T + bg)))
    m_new = np.tanh((g * m) @ wm.T + bm)
    want = np.concatenate([m_new * ha, hb], -1)
    got = eq(*(torch.from_numpy(a) for a in (ha, hb, m)))
    np.testing.assert_allclose(got[0].detach().numpy(), want, rtol=1e-10)
    np.testing.assert_allclose(got[1].detach().numpy(), m_new, rtol=1e-10)


def test_corrupt_then_fix_in_equations_yaml(gatenerf, gate_result, tmp_path):
    """A wrong subscript is reported with its reason and the base's part stands in; fixing it in equations.yaml
    compiles it; a hole left as it was is not recompiled."""
    doc, derived = gatenerf
    first = tmp_path / "first"
    first.mkdir()
    write_records(first, gate_result, doc)
    data = yaml.safe_load((first / "equations.yaml").read_text())
    good = data["holes"][0]["equations"][0]["latex"]
    data["holes"][0]["equations"][0]["latex"] = good.replace(r"\mathbf{h}_b", r"\mathbf{h}_x")  # a wrong subscript
    (first / "equations.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    corrections, reuse = read_corrections(first / "equations.yaml")
    assert [h["id"] for h in corrections["holes"]] == ["backbone"] and not reuse
    broken = implement_holes(doc, derived.plan, corrections=corrections, reuse=reuse)
    (record,) = broken.records
    assert record.status == NOT_IMPLEMENTED and "'h_x' (equation (1))" in record.reason
    assert "never names" in record.reason and not broken.sources
    assert broken.plan.get("model.field.MLPField.backbone") == derived.plan.get("model.field.MLPField.backbone")
    assert record.equations[0]["corrected"] is True
    second = tmp_path / "second"
    second.mkdir()
    write_records(second, broken, doc)
    data = yaml.safe_load((second / "equations.yaml").read_text())
    data["holes"][0]["equations"][0]["latex"] = good
    (second / "equations.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    corrections, reuse = read_corrections(second / "equations.yaml")
    fixed = implement_holes(doc, derived.plan, corrections=corrections, reuse=reuse)
    assert fixed.records[0].status == IMPLEMENTED, fixed.records[0].reason
    third = tmp_path / "third"
    third.mkdir()
    write_records(third, fixed, doc)
    corrections, reuse = read_corrections(third / "equations.yaml")
    assert not corrections["holes"] and list(reuse) == ["backbone"]
    again = implement_holes(doc, derived.plan, corrections=corrections, reuse=reuse)
    assert again.records[0].status == IMPLEMENTED and again.records[0].notes[-1].startswith("not recompiled")
    assert again.sources == fixed.sources


def test_a_missing_width_is_reported_and_a_size_in_equations_yaml_fixes_it(tmp_path):
    paper = tmp_path / "nowidth.md"
    paper.write_text(GATENERF_NO_WIDTH)
    doc = ingest(paper)
    derived = plan_from_paper(doc)
    result = implement_holes(doc, derived.plan)
    (record,) = result.records
    assert record.status == NOT_IMPLEMENTED and "is not fixed by the equations" in record.reason, record.reason
    write_records(tmp_path, result, doc)
    data = yaml.safe_load((tmp_path / "equations.yaml").read_text())
    data["holes"][0]["sizes"] = {"h_a": {"shape": [16]}, "h_b": {"shape": [16]}, "W_g": {"shape": [16, 32]}}
    (tmp_path / "equations.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    corrections, reuse = read_corrections(tmp_path / "equations.yaml")
    fixed = implement_holes(doc, derived.plan, corrections=corrections, reuse=reuse)
    assert fixed.records[0].status == IMPLEMENTED, fixed.records[0].reason
    assert fixed.records[0].sizes["W_m"]["shape"] == [16, 16]


def test_a_bad_equations_file_is_one_clear_error(tmp_path):
    bad = tmp_path / "equations.yaml"
    bad.write_text("holes: 3\n")
    with pytest.raises(EquationsFileError, match="not an equations.yaml"):
        read_corrections(bad)
    with pytest.raises(EquationsFileError, match="cannot read"):
        read_corrections(tmp_path / "absent.yaml")


def test_hostile_symbols_never_reach_the_code(tmp_path):
    """Symbol names and scripts a hostile paper might write appear in the component only as safe comments."""
    hostile = GATENERF.replace(r"\mathbf{h}_b", r"\mathbf{h}_{\text{__import__('os').system('x')}}") \
        .replace(r"\mathbf{b}_g", r"\mathbf{b}_{\text{a\"b}}")
    paper = tmp_path / "hostile.md"
    paper.write_text(hostile)
    doc = ingest(paper)
    result = implement_holes(doc, plan_from_paper(doc).plan)
    for source in result.sources.values():
        code = "\n".join(line.split("#", 1)[0] for line in source.splitlines())
        assert "__import__" not in code and "system" not in code and '\\"' not in code
        compile(source, "<hostile>", "exec")


def test_a_ladder_failure_on_a_compiled_part_brings_back_the_base_part(gatenerf, tmp_path):
    """The pipeline's fallback: the ladder names the compiled class -> the plan without it, the record says why."""
    import copy

    from nerfify_ns.pipeline import _fallback

    doc, derived = gatenerf
    result = implement_holes(doc, derived.plan)

    class Failure:
        rung, rule, message = "stability", "stiff-case", "custom BackboneFromEquations (Backbone), case values_1e8: x"

        def where(self):
            return "-"

    plan, sources = _fallback(result, tmp_path, doc)(type("Ladder", (), {"failures": [Failure()], "ok": False})())
    assert plan.get("model.field.MLPField.backbone") == derived.plan.get("model.field.MLPField.backbone")
    assert not sources and result.records[0].status == NOT_IMPLEMENTED
    assert "stability rung failed" in result.records[0].reason and "base's part stands in" in result.records[0].reason
    saved = yaml.safe_load((tmp_path / "equations.yaml").read_text())
    assert saved["holes"][0]["status"] == NOT_IMPLEMENTED and plan["holes"][0]["status"] == NOT_IMPLEMENTED
    assert copy.deepcopy(plan["holes"][0]["stands_in"]).startswith("mlp")


def test_a_matrix_on_the_interfaces_input_takes_its_width_when_built(tmp_path):
    import torch
    from novel_papers import PROJNERF

    paper = tmp_path / "projnerf.md"
    paper.write_text(PROJNERF)
    doc = ingest(paper)
    result = implement_holes(doc, plan_from_paper(doc).plan)
    record, cls = _component(result, "backbone")
    assert record.status == IMPLEMENTED, record.reason
    assert record.bindings["x"]["as"] == "input" and "nn.Parameter(torch.empty(64, in_dim))" in record.source
    for in_dim in (13, 63):
        module = cls(in_dim=in_dim)
        assert module.equations.p_w_1.shape == (64, in_dim) and module(torch.randn(3, in_dim)).shape == (3, 64)


def test_a_loss_on_densities_becomes_a_regulariser_with_the_papers_constants(tmp_path):
    import torch
    from novel_papers import SPARSEFIELD

    from nerfify_ns.grammar import validate

    paper = tmp_path / "sparsefield.md"
    paper.write_text(SPARSEFIELD)
    doc = ingest(paper)
    result = implement_holes(doc, plan_from_paper(doc).plan)
    record, module = _component(result, "regularizers")  # the ledger puts it at Regularizers: no placing needed
    assert record.status == IMPLEMENTED and record.production == "Regularizers", record.reason
    # lambda is the term's own weight: taken out of the component, the plugin adds the term times 0.01
    assert "lambda" not in record.bindings and record.component["weight"] == 0.01
    assert any(n.startswith("weight 0.01: cal L_s's own weight lambda") for n in record.notes), record.notes
    assert record.bindings["c"]["value"] == 0.5 and "where $\\lambda = 0.01$" in record.bindings["c"]["evidence"]
    member = [k for k in result.plan.get("model.regularizers") if k.startswith("custom_")]
    assert member == ["custom_regularizers"] and validate(result.plan)
    sigma = torch.rand(4, 6, 1, dtype=torch.float64)
    want = ((torch.sqrt(1 + sigma[..., 0] ** 2 / 0.5) - 1).sum(1)).mean()  # Eq. 3 without lambda, per ray, a mean
    torch.testing.assert_close(module().double()(sigma), want)


def _built_within_records():
    from nerfify_ns.synthesis.novel.results import HoleResult

    sentence = "Fog branch: an MLP with 3 linear layers (64 units) maps the direction to $b^{fog}$ and $a^{fog}$."
    network = {"layers": 3, "width": 64, "sentences": [sentence]}
    host = HoleResult("renderer", "model.renderer", "Renderer", "3.1", status=IMPLEMENTED, source="# compiled",
                      component={"module": "components.renderer_equations", "class": "RendererFromEquations"},
                      bindings={"a^fog": {"as": "network", "network": network},
                                "b^fog": {"as": "network", "network": network},
                                "sigma_i^sc": {"as": "input", "role": "density"}, "delta": {"as": "input"}})
    paragraph = HoleResult("field_wrappers", "model.field_wrappers", "FieldWrapper", "3.2",
                           reason="the compiler has no adapter for the FieldWrapper production yet")
    text = ("**Scene branch:** $\\sigma^{sc}(\\mathbf x)$ depends on the position, as in NeRF.\n**" + sentence)
    return host, paragraph, text


def test_a_paragraph_whose_networks_another_part_built_from_its_sentence_is_built_within_that_part():
    """An architecture paragraph found at a production with no adapter, describing the networks a compiled
    renderer uses (sized from this paragraph's own sentence, every labelled quantity it names bound there), is
    implemented within the renderer and says so; a ladder revert of the renderer takes it back."""
    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel.implement import _built_within, revert
    from nerfify_ns.synthesis.novel.results import Implementation

    host, paragraph, text = _built_within_records()
    plan = Plan.of({"holes": [{"slot": "model.field_wrappers", "status": NOT_IMPLEMENTED, "cause": "x"}]})
    _built_within([host, paragraph], {"model.field_wrappers": text}, plan)
    assert paragraph.status == IMPLEMENTED and paragraph.component["within"] == "model.renderer"
    assert "a^fog, b^fog" in paragraph.reason and "3 linear layers" in paragraph.reason
    assert plan["holes"][0]["compiled"] == "components.renderer_equations" and "cause" not in plan["holes"][0]
    revert(Implementation(plan, {}, [host, paragraph]), ["renderer"], "the smoke rung failed")
    assert host.status == paragraph.status == NOT_IMPLEMENTED
    assert "smoke rung failed" in paragraph.reason and plan["holes"][0]["compiled"] == ""


@pytest.mark.parametrize("change", ["other sentence", "unbound quantity", "host not built"])
def test_a_paragraph_is_not_built_within_a_part_that_does_not_cover_it(change):
    from nerfify_ns.plan import Plan
    from nerfify_ns.synthesis.novel.implement import _built_within

    host, paragraph, text = _built_within_records()
    if change == "other sentence":  # the host's networks were sized from another paragraph
        for b in host.bindings.values():
            if "network" in b:
                b["network"] = {**b["network"], "sentences": ["The MLP has 8 layers of 256 units."]}
    elif change == "unbound quantity":  # the paragraph names a quantity the host does not have
        text += " A third output $\\mathbf q^{\\mathrm{emit}}$ is the fog's emission."
    else:
        host.status = NOT_IMPLEMENTED
    _built_within([host, paragraph], {"model.field_wrappers": text}, Plan.of({"holes": []}))
    assert paragraph.status == NOT_IMPLEMENTED
