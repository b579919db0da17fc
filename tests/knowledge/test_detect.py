"""Technique detection with evidence: uses in the method, mentions in related work are not uses."""

from __future__ import annotations

import json

import pytest
from synthetic_papers import real_paper, write_paper

from nerfify_ns.knowledge.detect import Detection, detect_techniques, used_cards
from nerfify_ns.paper import ingest


def by_card(detections: list[Detection]) -> dict[str, Detection]:
    return {d.card: d for d in detections}


def assert_quotes_found(doc, detections):
    for d in detections:
        assert d.evidence, d.card
        for e in d.evidence:
            assert doc.find(e.quote) is not None, (d.card, e.quote)
            assert e.section is not None and (e.page is not None or e.line is not None or e.role in ("abstract",))
            assert 0.0 <= d.confidence <= 1.0


@pytest.fixture()
def mixed_paper(tmp_path):
    return write_paper(tmp_path, {
        "1 Introduction": (
            "Neural radiance fields [1] represent a scene with an MLP. Barron et al. [2] proposed integrated "
            "positional encoding to reduce aliasing. Unlike the multiresolution hash encoding of [4], our field is "
            "a plain MLP."),
        "2 Related Work": (
            "Plenoxels [6] represents view-dependent colour with spherical harmonics. Proposal networks were "
            "introduced in Mip-NeRF 360 [3]."),
        "3 Method": (
            "We encode positions with a positional encoding of $L=10$ frequencies and sample each ray with "
            "hierarchical volume sampling, drawing $N_c=64$ coarse and $N_f=128$ fine samples.\n\n"
            "$$\n\\gamma(p) = (\\sin(2^{0}\\pi p), \\cos(2^{0}\\pi p), \\dots, "
            "\\sin(2^{L-1}\\pi p), \\cos(2^{L-1}\\pi p))\n\\tag{1}\n$$\n\n"
            "The loss is the mean squared error between rendered and true pixel colours."),
        "4 Experiments": (
            "We compare against Instant-NGP and its multiresolution hash encoding, which we outperform on every "
            "scene. TensoRF obtains 31.2 32.1 30.4 on these scenes."),
    })


def test_method_uses_are_detected_with_located_evidence(mixed_paper):
    detections = detect_techniques(mixed_paper)
    found = by_card(detections)
    for card in ("positional_encoding", "hierarchical_sampling", "rgb_l2"):
        assert found[card].used, card
        assert found[card].confidence >= 0.5
    pe = found["positional_encoding"]
    kinds = {e.kind for e in pe.uses}
    assert {"alias", "equation", "hyperparameter"} <= kinds  # alias, Eq. 1 fragment, L = 10
    assert all(e.role == "method" for e in pe.uses)
    assert any(e.kind == "hyperparameter" and "num_coarse_samples" in e.detail
               for e in found["hierarchical_sampling"].uses)
    assert_quotes_found(mixed_paper, detections)


def test_related_work_and_comparisons_are_mentions_not_uses(mixed_paper):
    found = by_card(detect_techniques(mixed_paper))
    ipe = found["integrated_positional_encoding"]  # "Barron et al. [2] proposed ..."
    assert ipe.status == "mentioned_only" and ipe.confidence == 0.0
    assert any(e.kind == "alias" and e.role == "prior" and "Barron et al." in e.quote for e in ipe.mentions)
    assert found["spherical_harmonics"].status == "mentioned_only"  # related work only
    assert found["proposal_networks"].status == "mentioned_only"    # "were introduced in ..."
    hashed = found["hash_grid"]  # "unlike ... [4]" in the intro, a comparison in the experiments
    assert not hashed.used and hashed.confidence < 0.5
    assert all(e.weight == 0 for e in hashed.evidence if e.kind == "alias")
    assert "tensorf_vm" not in used_cards(list(found.values()))


def test_explicit_citation_use_names_the_technique(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": "We use the proposal sampler of [3] to place samples along each ray."})
    found = by_card(detect_techniques(doc))
    prop = found["proposal_networks"]
    assert prop.used
    assert any(e.kind == "citation" and "mipnerf360" in e.detail for e in prop.uses)


def test_detection_to_dict_is_json(mixed_paper):
    data = [d.to_dict() for d in detect_techniques(mixed_paper)]
    text = json.dumps(data)
    assert '"status": "used"' in text and '"mentioned_only"' in text
    first = data[0]
    assert set(first) >= {"card", "status", "confidence", "evidence", "production", "terminals"}
    assert set(first["evidence"][0]) >= {"quote", "section", "page", "line", "kind"}


def test_a_paper_without_techniques_detects_nothing_used(tmp_path):
    doc = write_paper(tmp_path, {"3 Method": "We train a radiance field on underwater scenes with a new medium model."},
                      references={})
    assert used_cards(detect_techniques(doc)) == []


# ------------------------------------------------------------------ real papers
@pytest.fixture(scope="module")
def real_detections():
    out = {}
    for key, rel in (("nerf", "nerf/nerf.md"), ("bionerf", "bionerf/bionerf.pdf"), ("gh_nerf", "gh_nerf/gh_nerf.pdf"),
                     ("seathru", "seathru_nerf/seathru_nerf_appendix.pdf")):
        path = real_paper(rel)
        doc = ingest(path)
        out[key] = (doc, detect_techniques(doc))
    return out


def test_nerf_text_detects_nerf_techniques(real_detections):
    doc, detections = real_detections["nerf"]
    assert {"positional_encoding", "hierarchical_sampling", "mlp_backbone", "rgb_l2", "background_model"} <= set(
        used_cards(detections))
    assert not {"integrated_positional_encoding", "hash_grid", "proposal_networks"} & set(used_cards(detections))
    assert_quotes_found(doc, detections)


def test_gh_nerf_uses_ipe_and_sh_and_only_mentions_nerf_pe(real_detections):
    doc, detections = real_detections["gh_nerf"]
    found = by_card(detections)
    assert found["integrated_positional_encoding"].used and found["spherical_harmonics"].used
    assert found["positional_encoding"].status == "mentioned_only"  # only in "2 Related Works / 2.1 NeRF"
    assert_quotes_found(doc, detections)


def test_bionerf_related_work_is_not_used(real_detections):
    doc, detections = real_detections["bionerf"]
    found = by_card(detections)
    assert found["rgb_l2"].used  # "L = MSE(...)", "mean squared error"
    for card in ("proposal_networks", "integrated_positional_encoding", "spherical_harmonics", "camera_optimizer"):
        assert found[card].status == "mentioned_only", card
    assert not {"tensorf_vm", "nerfacto", "hash_grid"} & set(used_cards(detections))  # baselines, not used
    assert_quotes_found(doc, detections)


def test_seathru_appendix_detects_no_technique(real_detections):
    doc, detections = real_detections["seathru"]
    # its text alone names no technique in use: what is used rests on its own equations (read from the PDF's text
    # layer: the discretised volume rendering it derives)
    latex = {e.latex for e in doc.equations}
    for d in detections:
        if d.used:
            assert any(e.kind == "equation" and e.quote in latex for e in d.evidence), d.card


def roles_by_title(tmp_path, sections: dict[str, str]) -> dict[str, str]:
    """The role of every section of a paper of ``sections`` (heading -> body), by its title."""
    from nerfify_ns.knowledge.sentences import section_roles

    doc = write_paper(tmp_path, sections)
    roles = section_roles(doc)
    return {s.title: roles[i] for i, s in enumerate(doc.sections)}


def test_a_subsection_of_the_experiments_named_after_the_method_reports_results(tmp_path):
    """"4.1 Rendering" under "4 Experiments" is results, not the method; "4.3 Implementation details" is the
    method's details wherever it is."""
    roles = roles_by_title(tmp_path, {"3 Method": "We render with a proposal sampler.",
                                      "4 Experiments": "We evaluate on two datasets.",
                                      "4.1 Rendering": "Our renders are sharper than the baselines'.",
                                      "4.2 Feature Model": "Lifted features improve occupancy prediction.",
                                      "4.3 Implementation Details": "We train for 20k iterations."})
    assert roles["Method"] == "method" and roles["Experiments"] == "experiments"
    assert roles["Rendering"] == "experiments" and roles["Feature Model"] == "experiments"
    assert roles["Implementation Details"] == "method"


def test_a_capture_rig_is_no_part_of_the_method_and_a_lost_heading_adopts_no_parent(tmp_path):
    """How the data was captured (a rig, its process) and a viewer are the system around the method; "4.1" after
    "3.2", its heading "4" lost by the extraction, is not a subsection of "3"."""
    roles = roles_by_title(tmp_path, {"3 The Capture Rig": "Our rig holds 22 cameras.",
                                      "3.1 Capture Rig Design": "The cameras are mounted on a pole.",
                                      "3.2 Capture Process": "We walk the rig through the space.",
                                      "4.1 Perceptual Colour Space": "We train in a perceptual colour space.",
                                      "4.2 Level of Detail": "We mask grid levels by the sample footprint.",
                                      "5 Real-Time Rendering": "Our renderer runs on 20 GPUs."})
    assert {roles[t] for t in ("The Capture Rig", "Capture Rig Design", "Capture Process")} == {"experiments"}
    assert roles["Perceptual Colour Space"] == "method" and roles["Level of Detail"] == "method"
    assert roles["Real-Time Rendering"] == "experiments"


def test_a_metric_named_where_results_are_measured_is_not_a_loss_in_use(tmp_path):
    """"We also compute the mean absolute error (MAE) of the intensities" measures results, in the method's
    details as much as in the experiments: the L1 loss it names is not the paper's loss. The same words as the
    objective the paper minimises are a use."""
    from nerfify_ns.knowledge.sentences import read_sentence

    assert read_sentence("We also compute the mean absolute error (MAE) of intensities in range images.",
                         "method").metric
    assert read_sentence("We report PSNR, SSIM and LPIPS on the test views.", "method").metric
    assert not read_sentence("We minimise the mean absolute error of the colours.", "method").metric
    assert not read_sentence("Our loss is the mean absolute error between rendered and true colours.", "method").metric

    def l1_used(sentence: str) -> bool:
        doc = write_paper(tmp_path, {"3 Method": "We render each ray with volume rendering.",
                                     "4 Experimental Setup": sentence})
        return "rgb_l1" in used_cards(detect_techniques(doc))

    assert not l1_used("We also compute the mean absolute error (MAE) for intensity in projected range images.")
    assert l1_used("We train with an L1 loss, the mean absolute error between rendered and true pixel colours.")


def test_a_table_flattened_into_a_method_section_names_compared_methods_not_parts(tmp_path):
    """An extraction that put a results table's rows inside "3.6 Total Loss": the methods in its rows are compared,
    not used."""
    row = ("Method PSNR SSIM LPIPS Instant-NGP [30] 18.21 0.52 0.41 17.90 0.50 0.44 TensoRF [10] 17.32 0.51 0.42 "
           "16.40 0.47 0.45 Ours 19.02 0.56 0.37 18.77 0.55 0.38")
    doc = write_paper(tmp_path, {"3 Method": "We render each ray with volume rendering.", "3.6 Total Loss": row})
    used = used_cards(detect_techniques(doc))
    assert "hash_grid" not in used and "tensorf_vm" not in used


def test_unnumbered_sections_after_the_experiments_report_results(tmp_path):
    """Headings without numbers (all at one level): a section after "Experiments and Results" with no role of its
    own ("Dehazing Scene Reconstruction") reports results; "Implementation Details" is the method's wherever it is."""
    roles = roles_by_title(tmp_path, {"Method": "We render with a medium.", "Scattering Model": "We model the medium.",
                                      "Experiments and Results": "We evaluate on two datasets.",
                                      "Dehazing Scene Reconstruction": "Our renders are clearer than the baselines'.",
                                      "Implementation Details": "We train for 20k iterations.",
                                      "Conclusion": "We conclude."})
    assert roles["Scattering Model"] == "method" and roles["Dehazing Scene Reconstruction"] == "experiments"
    assert roles["Implementation Details"] == "method" and roles["Conclusion"] == "conclusion"
