"""Hyperparameter extraction, one test per pattern family."""

from __future__ import annotations

import pytest

from nerfify_ns.paper import Location, extract_from_sentence, parse_number
from nerfify_ns.paper.hyperparams import split_sentences


@pytest.mark.parametrize("text,value", [
    ("5 × 10^-4", 5e-4), ("5×10−4", 5e-4), ("5e-4", 5e-4), ("2^19", 524288), ("4096", 4096), ("300k", 300000),
    ("1,000", 1000), ("0.01", 0.01), ("10−7", 1e-7), ("100–300k", [100000, 300000]), ("64-128", [64, 128]),
])
def test_parse_number(text, value):
    assert parse_number(text) == (pytest.approx(value) if isinstance(value, float) else value)


def found(sentence):
    return {(h.name, h.qualifier): h for h in extract_from_sentence(sentence, Location(line=3), "5 Method")}


def test_scientific_learning_rate_and_decay():
    hp = found("We use Adam with a learning rate that begins at $5\\times 10^{-4}$ and decays exponentially "
               "to 5 × 10−5 over the course of optimization.")
    assert hp[("learning_rate", "")].value == pytest.approx(5e-4)
    assert hp[("learning_rate_final", "")].value == pytest.approx(5e-5)
    assert hp[("learning_rate", "")].sentence.startswith("We use Adam")
    assert hp[("learning_rate", "")].loc.line == 3 and hp[("learning_rate", "")].section == "5 Method"


def test_e_notation_and_pdf_spacing():
    assert found("a learning rate of 5e-4")[("learning_rate", "")].value == pytest.approx(5e-4)
    assert found("a learning rate of 5e −4 during 400k updates")[("num_iterations", "")].value == 400000


def test_rays_batch():
    h = found("We use 4096 rays per batch.")[("batch_size", "")]
    assert h.value == 4096 and h.unit == "rays"
    assert found("a batch size of 1024 rays")[("batch_size", "")].value == 1024


def test_coarse_and_fine_samples():
    hp = found("We use 64 coarse samples and 128 fine samples per ray.")
    assert hp[("num_coarse_samples", "")].value == 64 and hp[("num_fine_samples", "")].value == 128
    hp = found("each sampled at $N_{c}=64$ coordinates in the coarse volume and $N_{f}=128$ additional coordinates")
    assert hp[("num_coarse_samples", "")].value == 64 and hp[("num_fine_samples", "")].value == 128
    assert found("64 coarse samples and 128 fine")[("num_fine_samples", "")].value == 128


def test_hash_encoding():
    hp = found("The hash table size is T = 2^19 with L = 16 levels.")
    assert hp[("log2_hashmap_size", "")].value == 19 and hp[("hash_table_size", "")].value == 2 ** 19
    assert hp[("num_levels", "")].value == 16 and ("num_frequencies", "") not in hp


def test_lambda_and_loss_weights():
    assert found("we set λ = 0.01 in all experiments")[("lambda", "")].value == 0.01
    assert found("with $\\lambda_{\\text{dist}} = 0.002$")[("lambda_dist", "")].value == 0.002
    assert found("the distortion loss weight is 0.002")[("lambda_distortion", "")].value == 0.002


def test_iterations_and_ranges():
    assert found("we train for 300k iterations")[("num_iterations", "")].value == 300000
    assert found("around 100–300k iterations to converge")[("num_iterations", "")].value == [100000, 300000]


def test_frequencies_with_qualifier():
    hp = found("we set $L=10$ for $\\gamma(\\mathbf{x})$ and $L=4$ for $\\gamma(\\mathbf{d})$.")
    assert hp[("num_frequencies", "position")].value == 10 and hp[("num_frequencies", "direction")].value == 4
    assert not found("ℓ=0 m=−ℓ where")  # an index, not L


def test_adam_and_near_far():
    hp = found("default values of $\\beta_{1}=0.9$, $\\beta_{2}=0.999$, and $\\epsilon=10^{-7}$; near = 2, far = 6")
    assert hp[("adam_beta1", "")].value == 0.9 and hp[("adam_eps", "")].value == pytest.approx(1e-7)
    assert hp[("near", "")].value == 2 and hp[("far", "")].value == 6
    assert ("near", "") not in found("nearly 5 of them")


def test_no_false_positive_in_plain_prose():
    assert found("Neural radiance fields represent scenes as continuous functions.") == {}


def test_sentence_split_keeps_abbreviations():
    parts = split_sentences("See Fig. 3 and Eq. 2 by Mildenhall et al. for details. "
                            "We then train. A. B. Smith wrote it.")
    assert parts == ["See Fig. 3 and Eq. 2 by Mildenhall et al. for details.", "We then train.",
                     "A. B. Smith wrote it."]
