"""Compositional citation recovery: patterns, reference matching, transitive resolution, graph output."""

from __future__ import annotations

import json

import pytest
from synthetic_papers import REFERENCES, real_paper, write_paper

from nerfify_ns.knowledge.citations import (
    TARGET,
    build_citation_graph,
    builds_on,
    find_citation_uses,
    load_patterns,
    match_reference,
)
from nerfify_ns.knowledge.detect import detect_techniques
from nerfify_ns.knowledge.papers import load_papers
from nerfify_ns.paper import Reference, ingest


def uses_of(tmp_path, sentence: str, heading: str = "3 Method"):
    return find_citation_uses(write_paper(tmp_path, {heading: sentence}))


@pytest.mark.parametrize("sentence, relation, components", [
    ("We adopt the proposal network from [3].", "adopts", ["proposal_networks"]),
    ("We use the proposal network of [3] to place the samples.", "adopts", ["proposal_networks"]),
    ("We borrow the scene contraction proposed in [3] for unbounded scenes.", "adopts", ["scene_contraction"]),
    ("The distortion loss is computed as in [3].", "adopts", ["distortion_loss"]),
    ("Following [3], we train with a Charbonnier loss.", "follows", ["charbonnier"]),
    ("The field is trained as in [3].", "follows", []),
    ("Our sampler is similar to [3].", "follows", []),
    ("Our model is based on [3].", "builds_on", []),
    ("The model is built upon [3].", "builds_on", []),
    ("We build on [3] and change only the field.", "builds_on", []),
    ("We follow Mip-NeRF 360 for the sampling schedule.", "follows", []),  # a known paper named, no marker
])
def test_each_pattern(tmp_path, sentence, relation, components):
    uses = uses_of(tmp_path, sentence)
    assert uses, sentence
    use = uses[0]
    assert use.relation == relation and use.papers == ["mipnerf360"]
    assert use.components == components
    assert use.section.startswith("3")


def test_patterns_are_data():
    names = {p.name for p in load_patterns().patterns}
    assert {"adopt_from", "following", "builds_on"} <= names
    assert {p.relation for p in load_patterns().patterns} == {"adopts", "follows", "builds_on"}


@pytest.mark.parametrize("sentence, heading", [
    ("Barron et al. [3] proposed proposal networks based on [2].", "2 Related Work"),
    ("Mip-NeRF 360 [3] builds on Mip-NeRF [2].", "2 Related Work"),
    ("Unlike [3], we do not use a proposal network.", "3 Method"),
    ("We compare against [3], which we outperform.", "5 Experiments"),
])
def test_related_work_contrast_and_comparisons_are_not_uses(tmp_path, sentence, heading):
    assert uses_of(tmp_path, sentence, heading) == []


def test_latex_cite_keys_are_targets(tmp_path):
    tex = tmp_path / "p.tex"
    tex.write_text(r"""\documentclass{article}
\title{BarNeRF: A Radiance Field}
\begin{document}
\maketitle
\begin{abstract}We present BarNeRF, a neural radiance field.\end{abstract}
\section{Method}
We use the proposal network of~\cite{barron2022mip}. Our encoding follows \citet{muller2022}.
\begin{thebibliography}{9}
\bibitem{barron2022mip} J. T. Barron, B. Mildenhall, D. Verbin, P. P. Srinivasan, and P. Hedman. Mip-NeRF 360: Unbounded anti-aliased neural radiance fields. In CVPR, 2022.
\bibitem{muller2022} T. M\"uller et al. Instant neural graphics primitives with a multiresolution hash encoding. ACM TOG, 2022.
\end{thebibliography}
\end{document}
""")  # noqa: E501
    uses = find_citation_uses(ingest(tex))
    assert [(u.relation, u.keys, u.papers, u.components) for u in uses][0] == (
        "adopts", ["barron2022mip"], ["mipnerf360"], ["proposal_networks"])


def test_reference_matching_by_arxiv_then_title():
    by_arxiv = Reference(key="4", raw="T. Müller et al. Some garbled title. ACM TOG 2022. arXiv:2201.05989v2",
                         title="Some garbled title")
    assert match_reference(by_arxiv).key == "instant-ngp"
    by_title = Reference(key="2",
                         title="Mip-nerf: A multiscale representation for anti-aliasing neural radiance fields")
    assert match_reference(by_title).key == "mipnerf"
    in_raw = Reference(key="9", raw="B. Mildenhall et al. NeRF: Representing scenes as neural radiance fields for "
                                    "view synthesis. In ECCV, 2020.", title="")
    assert match_reference(in_raw).key == "nerf"
    assert match_reference(Reference(key="5", title="A totally unknown paper about other things")) is None


def test_builds_on_registry_is_consistent():
    papers = load_papers()
    relation = builds_on()
    assert relation["mipnerf360"] == ("mipnerf",) and relation["mipnerf"] == ("nerf",)
    assert all(dep in papers for deps in relation.values() for dep in deps)


def test_proposal_sampler_brings_its_interlevel_loss(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": "We use the proposal sampler of [3] in front of our field."})
    graph = build_citation_graph(doc, detect_techniques(doc))
    res = graph.resolution
    assert res.filled["Sampler"].card == "proposal_networks" and res.filled["Sampler"].paper == "mipnerf360"
    taken = {c.card: c for c in res.taken}
    assert taken["interlevel_loss"].paper == "mipnerf360" and taken["interlevel_loss"].relation == "requires"
    edge = graph.graph.edges[TARGET, "mipnerf360"]
    assert edge["relation"] == "adopts"
    assert edge["components"] == ["proposal_networks", "interlevel_loss"]
    # nothing else is taken from Mip-NeRF 360 (not its Charbonnier loss): the rest is reported missing
    assert "charbonnier" not in taken
    assert set(res.missing) == {"PosEncoding", "DirEncoding", "MLPField", "DensityHead", "Model", "RGBLoss"}


def test_transitive_recovery_through_builds_on(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": "Our model builds on [2]; only the colour head changes."},
                      references={"2": REFERENCES["2"], "5": REFERENCES["5"]})
    graph = build_citation_graph(doc, detect_techniques(doc))
    res = graph.resolution
    assert res.missing == []
    assert res.filled["PosEncoding"].card == "integrated_positional_encoding"
    assert res.filled["PosEncoding"].path == [TARGET, "mipnerf"]
    assert res.filled["PosEncoding"].quote == "Our model builds on [2]; only the colour head changes."
    assert res.filled["MLPField"].path == [TARGET, "mipnerf", "nerf"]  # Mip-NeRF builds on NeRF (papers.yaml)
    assert res.filled["MLPField"].relation == "registry"
    assert graph.graph.nodes["nerf"]["kind"] == "transitive"
    assert "mlp_backbone" in graph.graph.edges["mipnerf", "nerf"]["components"]
    assert graph.dependencies() == ["mipnerf"] and graph.transitive() == ["nerf"]


def test_json_and_drawing(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": (
        "We use the proposal sampler of [3] and a multiresolution hash encoding following Instant-NGP [4]. "
        "Our field is built upon [2].")})
    graph = build_citation_graph(doc, detect_techniques(doc))
    data = json.loads(graph.to_json())
    nodes = {n["id"]: n for n in data["graph"]["nodes"]}
    assert {TARGET, "mipnerf360", "instant-ngp", "mipnerf", "nerf", "ref:5"} <= set(nodes)
    links = {(e["source"], e["target"]): e for e in data["graph"]["links"]}
    assert links[(TARGET, "instant-ngp")]["components"] == ["hash_grid"]
    assert links[(TARGET, "mipnerf")]["relation"] == "builds_on"
    assert data["resolution"]["missing"] == []
    png = graph.draw(tmp_path / "deps.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


def test_no_references_reports_everything_missing(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": "We model the scattering medium explicitly."}, references={})
    graph = build_citation_graph(doc, [])
    assert graph.resolution.filled == {} and len(graph.resolution.missing) == 7
    assert graph.draw(tmp_path / "empty.png").is_file()


# ------------------------------------------------------------------ real papers
def test_real_papers_dependencies():
    gh = ingest(real_paper("gh_nerf/gh_nerf.pdf"))
    graph = build_citation_graph(gh, detect_techniques(gh))
    res = graph.resolution
    assert res.filled["PosEncoding"].card == "integrated_positional_encoding"
    assert res.filled["PosEncoding"].paper == "mipnerf" and res.filled["PosEncoding"].relation == "adopts"
    assert "Mip-NeRF[1]" in res.filled["PosEncoding"].quote
    assert res.filled["Sampler"].card == "hierarchical_sampling"
    assert res.missing == []
    bio = ingest(real_paper("bionerf/bionerf.pdf"))
    graph = build_citation_graph(bio, detect_techniques(bio))
    assert graph.dependencies() == ["nerf"]  # "based on the methodology employed in [16]"
    assert graph.graph.edges[TARGET, "mipnerf360"]["relation"] == "cites"  # related work and baselines only
    for comp in graph.resolution.taken:
        if comp.quote:
            assert bio.find(comp.quote) is not None
