"""The knowledge base: cards against the grammar (read directly with yaml), papers, alias detection."""

from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path

import pytest
import yaml

from nerfify_ns.errors import NerfifyError
from nerfify_ns.knowledge import (
    CARDS_DIR,
    PAPERS_FILE,
    CardFormatError,
    KnownPaper,
    UnknownCardError,
    card,
    cards_for_terminal,
    find_by_alias,
    find_papers_by_alias,
    load_cards,
    load_papers,
    match_aliases,
    match_paper,
    normalize_arxiv_id,
    normalize_title,
)
from nerfify_ns.knowledge.cards import TERMINAL_FIELDS

ROOT = Path(__file__).resolve().parents[2]
GRAMMAR_FILE = ROOT / "grammar_spec.yaml"

REQUIRED_CARDS = {
    "appearance_embedding",
    "background_model",
    "camera_optimizer",
    "charbonnier",
    "density_activation",
    "density_sparsity",
    "distortion_loss",
    "hash_grid",
    "hierarchical_sampling",
    "integrated_positional_encoding",
    "interlevel_loss",
    "kplanes",
    "mlp_backbone",
    "nerfacto",
    "occupancy_grid",
    "plane_tv",
    "positional_encoding",
    "proposal_networks",
    "ray_entropy",
    "rgb_l1",
    "rgb_l2",
    "scene_contraction",
    "spherical_harmonics",
    "tensorf_cp",
    "tensorf_vm",
    "time_smoothness",
    "triplane",
}
CARD_FIELDS = (
    "name",
    "title",
    "aliases",
    "paper",
    "production",
    "parameters",
    "equation",
    "signals",
    "requires",
)


@pytest.fixture(scope="module")
def grammar() -> dict:
    return yaml.safe_load(GRAMMAR_FILE.read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def cards():
    return load_cards()


def resolve(dotted: str):
    """The object at a dotted path 'package.module.attr[.attr]' (longest importable module prefix)."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(dotted)


def symbols_of(grammar: dict, nonterminal: str) -> set[str]:
    """Terminals/nonterminals a nonterminal derives directly (alternatives, members, slots, map value), and
    the terminal of an open production it holds (``Model.renderer`` holds ``Renderer``, whose terminal is
    ``renderer``)."""
    nts = grammar["nonterminals"]
    nt = nts[nonterminal]
    out = set(nt.get("alternatives", [])) | set(nt.get("members", []))
    out |= {str(v).rstrip("?") for v in (nt.get("slots") or {}).values()}
    if nt.get("value"):
        out.add(nt["value"])
    return out | {nts[s]["terminal"] for s in out if s in nts and nts[s].get("kind") == "open"}


def check_value(spec: dict, value) -> str | None:
    """None when ``value`` satisfies the grammar's param spec, else what is wrong."""
    kind = spec["type"]

    def in_range(x, rng):
        if rng is None:
            return True
        lo, hi = rng
        return (lo is None or x >= lo) and (hi is None or x <= hi)

    if kind == "int":
        ok = isinstance(value, int) and not isinstance(value, bool) and in_range(value, spec.get("range"))
    elif kind == "float":
        ok = isinstance(value, float) and in_range(value, spec.get("range"))
    elif kind == "bool":
        ok = isinstance(value, bool)
    elif kind == "str":
        ok = isinstance(value, str)
    elif kind == "enum":
        ok = value in spec["values"]
    elif kind in ("int_list", "float_list"):
        item = int if kind == "int_list" else float
        ok = (
            isinstance(value, list)
            and in_range(len(value), spec.get("length"))
            and all(
                isinstance(v, item) and not isinstance(v, bool) and in_range(v, spec.get("range"))
                for v in value
            )
        )
    else:
        return f"unknown grammar type {kind!r}"
    return None if ok else f"{value!r} is not a valid {kind} (spec {spec})"


# ---------------------------------------------------------------- cards
def test_every_required_card_loads_with_every_field(cards):
    assert REQUIRED_CARDS <= set(cards), f"missing cards: {REQUIRED_CARDS - set(cards)}"
    for path in sorted(CARDS_DIR.glob("*.yaml")):
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
        missing = [f for f in CARD_FIELDS if f not in raw]
        assert not missing, f"{path.name} lacks {missing}"
        assert ("terminal" in raw) != ("terminals" in raw), f"{path.name}: terminal xor terminals"
        assert raw["name"] == path.stem
    for c in cards.values():
        assert c.title and c.aliases and c.terminals and c.production
        assert c.paper.title and c.paper.authors and c.paper.year and c.paper.venue
        assert c.paper.arxiv is None or normalize_arxiv_id(c.paper.arxiv) == c.paper.arxiv
        assert c.equation.latex.strip() and c.equation.text.strip()
        assert c.signals.hyperparameters is not None and (c.signals.phrases or c.signals.equations)
        assert all(a == a.lower() for a in c.aliases)


def test_every_grammar_card_reference_exists_and_lists_its_terminal(grammar, cards):
    referenced = {name: t["card"] for name, t in grammar["terminals"].items() if t.get("card")}
    assert referenced, "grammar_spec.yaml references no cards"
    for terminal, name in referenced.items():
        assert name in cards, f"terminal {terminal!r} references unknown card {name!r}"
        assert terminal in cards[name].terminals, f"card {name!r} does not list terminal {terminal!r}"
        assert cards[name] in cards_for_terminal(terminal)


def test_card_terminals_exist_and_fill_their_production(grammar, cards):
    terminals, nonterminals = grammar["terminals"], grammar["nonterminals"]
    for c in cards.values():
        for t in c.terminals:
            assert t in terminals, f"card {c.name!r}: terminal {t!r} is not in grammar_spec.yaml"
            assert (
                terminals[t].get("card") == c.name
            ), f"grammar terminal {t!r} names card {terminals[t].get('card')!r}, not {c.name!r}"
        assert (
            c.production in nonterminals
        ), f"card {c.name!r}: production {c.production!r} is not a nonterminal"
        assert c.terminal in symbols_of(
            grammar, c.production
        ), f"card {c.name!r}: {c.terminal!r} is not derived by {c.production!r}"


def test_card_parameters_are_params_of_their_terminal_and_valid(grammar, cards):
    terminals = grammar["terminals"]
    for c in cards.values():
        if len(c.terminals) > 1:
            assert set(c.parameters) <= set(
                c.terminals
            ), f"card {c.name!r}: parameters must be keyed by terminal"
        for t in c.terminals:
            spec = terminals[t].get("params") or {}
            for key, value in c.params_for(t).items():
                assert (
                    key in spec
                ), f"card {c.name!r}: {key!r} is not a param of terminal {t!r} ({sorted(spec)})"
                problem = check_value(spec[key], value)
                assert problem is None, f"card {c.name!r}, {t}.{key}: {problem}"


def test_a_cards_hosts_are_terminals_whose_parameters_take_the_values(grammar, cards):
    """``hosted_in``: each host is a terminal of the grammar and each value one its parameter accepts; at least one
    card uses it (K-Planes in a deformation of Gaussians)."""
    terminals = grammar["terminals"]
    hosted = [c for c in cards.values() if c.hosted_in]
    assert any(c.name == "kplanes" for c in hosted)
    for c in hosted:
        for t, params in c.hosted_in.items():
            assert t in terminals, f"card {c.name!r}: host {t!r} is not a terminal"
            spec = terminals[t].get("params") or {}
            for key, value in params.items():
                assert key in spec, f"card {c.name!r}: {key!r} is not a param of host {t!r}"
                assert check_value(spec[key], value) is None, f"card {c.name!r}, {t}.{key}: {value!r}"


def test_a_cards_terminals_are_implemented_and_the_card_does_not_say_how(grammar, cards):
    """Implementation lives in the terminal only: every card's terminals resolve to a callable, and no card
    file carries a field that is the terminal's (a second home that could disagree with it)."""
    terminals = grammar["terminals"]
    for c in cards.values():
        for t in c.terminals:
            assert callable(resolve(terminals[t]["implementation"])), terminals[t]["implementation"]
    for path in sorted(CARDS_DIR.glob("*.yaml")):
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
        assert not set(raw) & set(TERMINAL_FIELDS), f"{path.name} states {set(raw) & set(TERMINAL_FIELDS)}"


def test_aliases_are_unique_across_cards(cards):
    owner: dict[str, str] = {}
    for c in cards.values():
        for alias in c.aliases:
            key = normalize_title(alias)
            assert (
                key not in owner or owner[key] == c.name
            ), f"alias {alias!r} in {owner.get(key)!r} and {c.name!r}"
            owner[key] = c.name


def test_requires_related_and_provides_resolve(cards):
    papers = load_papers()
    for c in cards.values():
        assert set(c.requires) <= set(
            cards
        ), f"card {c.name!r} requires unknown {set(c.requires) - set(cards)}"
        assert set(c.related_papers) <= set(
            papers
        ), f"card {c.name!r}: unknown papers {set(c.related_papers) - set(papers)}"
    provided = set()
    for p in papers.values():
        assert set(p.provides) <= set(
            cards
        ), f"paper {p.key!r} provides unknown {set(p.provides) - set(cards)}"
        provided |= set(p.provides)
    assert provided == set(cards), f"cards no paper provides: {set(cards) - provided}"
    assert "interlevel_loss" in card("proposal_networks").requires


def test_card_papers_are_in_the_registry_and_provide_the_card(cards):
    for c in cards.values():
        known = match_paper(title=c.paper.title, arxiv=c.paper.arxiv)
        assert known is not None, f"card {c.name!r}: its paper {c.paper.title!r} is not in papers.yaml"
        assert normalize_title(known.title) == normalize_title(c.paper.title)
        assert known.arxiv == c.paper.arxiv
        assert c.name in known.provides, f"paper {known.key!r} should provide {c.name!r}"


def test_lookup_helpers_and_errors():
    assert card("hash_grid").terminal == "hash"
    assert card("hash_grid").params_for() == {
        "num_levels": 16,
        "log2_hashmap_size": 19,
        "features_per_level": 2,
        "min_res": 16,
        "max_res": 2048,
    }
    assert [c.name for c in cards_for_terminal("frequency")] == ["positional_encoding"]
    assert card("positional_encoding").params_for("frequency")["num_frequencies"] == 4
    assert card("positional_encoding").params_for("positional")["num_frequencies"] == 10
    assert [c.name for c in cards_for_terminal("vanilla-nerf")] == ["hierarchical_sampling"]
    assert card("hierarchical_sampling").params_for("vanilla-nerf") == {}
    assert cards_for_terminal("no_such_terminal") == []
    with pytest.raises(UnknownCardError) as err:
        card("no_such_card")
    assert isinstance(err.value, NerfifyError) and "hash_grid" in str(err.value)
    with pytest.raises(UnknownCardError):
        card("hash_grid").params_for("kplanes")
    assert load_cards() is not load_cards() and load_cards() == load_cards()  # cached, copies handed out


def test_malformed_cards_raise_typed_errors(tmp_path):
    good = (CARDS_DIR / "rgb_l2.yaml").read_text(encoding="utf-8")
    (tmp_path / "rgb_l2.yaml").write_text(good.replace("equation:", "equation_typo:"), encoding="utf-8")
    with pytest.raises(CardFormatError, match="equation"):
        load_cards(tmp_path)
    (tmp_path / "rgb_l2.yaml").write_text(good + "implementation: torch.nn.MSELoss\n", encoding="utf-8")
    with pytest.raises(CardFormatError, match="belong.* to the terminal"):
        load_cards(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / "renamed.yaml").write_text(good, encoding="utf-8")
    with pytest.raises(CardFormatError, match="file stem"):
        load_cards(other)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "x.yaml").write_text("name: x\n  : [", encoding="utf-8")
    with pytest.raises(CardFormatError):
        load_cards(bad)
    assert issubclass(CardFormatError, NerfifyError)


# ---------------------------------------------------------------- alias detection
def test_find_by_alias_detects_techniques():
    assert [c.name for c in find_by_alias("In practice we use a multiresolution hash encoding [30].")] == [
        "hash_grid"
    ]
    assert [c.name for c in find_by_alias("Multi-Resolution Hash Encodings are fast")] == ["hash_grid"]
    assert [c.name for c in find_by_alias("a multiresolution~hash encoding")] == ["hash_grid"]
    found = [
        c.name
        for c in find_by_alias(
            "We adopt the distortion loss and proposal networks of Mip-NeRF 360, " "with scene contraction."
        )
    ]
    assert found == ["distortion_loss", "proposal_networks", "scene_contraction"]
    # the longest alias wins: IPE is not also plain positional encoding; TensoRF-CP is not also VM
    assert [c.name for c in find_by_alias("integrated positional encoding")] == [
        "integrated_positional_encoding"
    ]
    assert [c.name for c in find_by_alias("TensoRF-CP")] == ["tensorf_cp"]
    hits = match_aliases("the K-Planes model")
    assert (
        hits
        and hits[0].card.name == "kplanes"
        and "the K-Planes model"[hits[0].start : hits[0].end] == "K-Planes"
    )


@pytest.mark.parametrize(
    "text",
    [
        "we rehash encodings of the graph",
        "tensorflow was used",
        "the nerfactory",
        "hash gridding",
        "a recipe",
        "multiresolutionhash encoding",
        "",
    ],
)
def test_find_by_alias_does_not_match_inside_words(text):
    assert [
        c.name
        for c in find_by_alias(text)
        if c.name in {"hash_grid", "tensorf_vm", "nerfacto", "integrated_positional_encoding"}
    ] == []


# ---------------------------------------------------------------- papers
def test_papers_registry_loads():
    papers = load_papers()
    for key in (
        "nerf",
        "mipnerf",
        "mipnerf360",
        "instant-ngp",
        "tensorf",
        "kplanes",
        "nerfw",
        "plenoxels",
        "infonerf",
        "snerg",
        "nerfstudio",
        "eg3d",
        "nerfpp",
        "refnerf",
        "zipnerf",
        "dvgo",
        "dnerf",
        "hexplane",
        "plenoctrees",
    ):
        assert key in papers, key
        assert isinstance(papers[key], KnownPaper) and papers[key].title and papers[key].authors
    assert papers["mipnerf360"].arxiv == "2111.12077" and "proposal_networks" in papers["mipnerf360"].provides
    raw = yaml.safe_load(PAPERS_FILE.read_text(encoding="utf-8"))["papers"]
    assert len({p["key"] for p in raw}) == len(raw)


@pytest.mark.parametrize(
    "value, expected",
    [
        ("2111.12077", "2111.12077"),
        ("2111.12077v2", "2111.12077"),
        ("arXiv:2111.12077v3", "2111.12077"),
        ("https://arxiv.org/abs/2003.08934v2", "2003.08934"),
        ("https://arxiv.org/pdf/2003.08934.pdf", "2003.08934"),
        ("arXiv preprint arXiv:2010.07492, 2020", "2010.07492"),
        ("1412.6980", "1412.6980"),
        ("2301.10241V1", "2301.10241"),
        ("cs.CV/0502076v2", "cs/0502076"),
        ("hep-th/9901001", "hep-th/9901001"),
        ("arXiv:math.GT/0309136", "math/0309136"),
        ("no id here", None),
        ("", None),
        (None, None),
    ],
)
def test_normalize_arxiv_id(value, expected):
    assert normalize_arxiv_id(value) == expected


@pytest.mark.parametrize(
    "arxiv, key",
    [
        ("2111.12077v2", "mipnerf360"),
        ("arXiv:2003.08934", "nerf"),
        ("https://arxiv.org/abs/2201.05989v1", "instant-ngp"),
        ("2301.10241", "kplanes"),
        ("2112.15399v3", "infonerf"),
    ],
)
def test_match_paper_by_arxiv(arxiv, key):
    assert match_paper(arxiv=arxiv).key == key
    assert match_paper(title="a wrong title entirely", arxiv=arxiv).key == key  # the id comes first


def test_match_paper_old_style_ids():
    old = KnownPaper(
        key="old", title="An Old Paper", authors=("A. Author",), year=2005, venue="x", arxiv="cs/0502076"
    )
    assert match_paper(arxiv="cs.CV/0502076v3", papers={"old": old}) is old
    assert match_paper(arxiv="cs/0502077", papers={"old": old}) is None


@pytest.mark.parametrize(
    "title, key",
    [
        ("NeRF: Representing Scenes as Neural Radiance Fields for View Synthesis", "nerf"),
        ("nerf: representing scenes as neural radiance fields for view synthesis.", "nerf"),
        ("{NeRF}: Representing Scenes as Neural Radiance Fields for View Synthesis", "nerf"),
        ("\\emph{Mip-NeRF 360}: Unbounded Anti-Aliased Neural Radiance Fields", "mipnerf360"),
        ("Mip‐NeRF 360 — unbounded anti‐aliased neural radiance fields", "mipnerf360"),
        ("Mip-nerf: A multiscale representation for anti-aliasing neural radiance fields", "mipnerf"),
        ("{K}-{P}lanes: {E}xplicit radiance fields in space, time, and appearance", "kplanes"),
        ("Instant neural graphics primitives with a multiresolution hash encoding", "instant-ngp"),
        ("Tensorf: Tensorial radiance fields", "tensorf"),
        ("NeRF++: Analyzing and improving neural radiance fields", "nerfpp"),
        ("Plenoctrees for real-time rendering of neural radiance fields", "plenoctrees"),
        ("Mip-NeRF 360", "mipnerf360"),  # an alias
        ("Nerf: Representing scenes as neural radiance field for view synthesis", "nerf"),  # near-identical
    ],
)
def test_match_paper_by_title_variants(title, key):
    found = match_paper(title=title)
    assert found is not None and found.key == key


@pytest.mark.parametrize(
    "title", ["NeRF", "Neural radiance fields", "A completely different paper about meshes", "", None]
)
def test_match_paper_rejects_unknown_titles(title):
    assert match_paper(title=title) is None


def test_find_papers_by_alias_prefers_the_longest():
    keys = [p.key for p in find_papers_by_alias("we follow Mip-NeRF 360 and Instant-NGP, unlike mip-NeRF")]
    assert keys == ["mipnerf360", "instant-ngp", "mipnerf"]


# ---------------------------------------------------------------- package boundaries
def _imports(folder: Path) -> set[str]:
    names = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module)
    return names


def test_knowledge_imports_only_errors_from_the_project():
    """Besides the errors, only the package's sentence splitter, a standard-library leaf shared with the paper
    package."""
    folder = ROOT / "nerfify_ns" / "knowledge"
    project = {n for n in _imports(folder) if n.split(".")[0] == "nerfify_ns"}
    assert project <= {"nerfify_ns.errors", "nerfify_ns.sentence_split"} | {
        n for n in project if n.startswith("nerfify_ns.knowledge")}


def test_components_import_only_torch_nerfstudio_and_stdlib():
    folder = ROOT / "nerfify_ns" / "components"
    roots = {n.split(".")[0] for n in _imports(folder)}
    foreign = {
        r
        for r in roots
        if r not in {"torch", "nerfstudio", "nerfify_ns"} and r not in sys.stdlib_module_names
    }
    assert not foreign, foreign
    project = {n for n in _imports(folder) if n.split(".")[0] == "nerfify_ns"}
    assert all(n.startswith("nerfify_ns.components") for n in project), project


def test_an_alias_matches_the_script_l_papers_set_for_l():
    from nerfify_ns.knowledge.text import alias_pattern

    l2 = alias_pattern("l2 loss")
    assert l2.search("by minimizing the ℓ2-loss between the rendered colours") and l2.search("an L2 loss")
    assert not l2.search("a kl2 loss") and not alias_pattern("l1").search("the 2ℓ1 term")
