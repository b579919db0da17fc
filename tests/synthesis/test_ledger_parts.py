"""The ledger's general mechanisms for where a paper's new parts are and where they land, each on a paper fragment
of our own: a network component added by a first-person "we use" sentence, a second field beside the object field
(the field's outputs written with several labels), a loss part whose terms do different things, and the words of
the paper's family counting little for where a part lands."""

from pathlib import Path

from nerfify_ns.knowledge.kb import KnowledgeBase
from nerfify_ns.paper import ingest
from nerfify_ns.synthesis.ledger import read_ledger

KB = KnowledgeBase.default()


def _ledger(tmp_path: Path, text: str, family: str = ""):
    paper = tmp_path / "paper.md"
    paper.write_text(text)
    return read_ledger(ingest(paper), KB, family=family)


def _new(ledger) -> list[tuple[str, str]]:
    return [(p.heading, p.production) for p in ledger.new]


COMPONENT = """# DimNeRF: Radiance Fields for Dim Rooms

## Abstract

DimNeRF renders rooms lit by a single lamp. A radiance field is fitted to photographs of the room.

## 1 Introduction

Neural radiance fields model a scene as a field of density and colour rendered by volume rendering.

## 3 Method

### 3.1 Field

The field maps an encoded position to a density and a feature vector, and the feature vector with the viewing
direction to a colour. To keep the activations of dim rooms in range, we apply batch normalization after every
hidden layer of the density network. The colour network has one hidden layer.

### 3.2 Rendering

Colours are composited along each ray with the usual volume rendering weights.

## 4 Experiments

We compare with NeRF on ten rooms.
"""


def test_a_network_component_the_paper_adds_is_a_part_of_its_own(tmp_path: Path):
    ledger = _ledger(tmp_path, COMPONENT)
    assert ("batch normalization", "Backbone") in _new(ledger), _new(ledger)
    part = next(p for p in ledger.new if p.heading == "batch normalization")
    assert part.sentences[0].startswith("To keep the activations")


def test_a_component_taken_from_earlier_work_is_not_a_part(tmp_path: Path):
    borrowed = COMPONENT.replace("we apply batch normalization after", "we apply batch normalization as in [4] after")
    assert borrowed != COMPONENT
    assert not any(p.heading == "batch normalization" for p in _ledger(tmp_path, borrowed).new)


SEVERAL = """# HazeField: Radiance Fields Through Haze

## Problem Setup

Each ray crosses an opaque object and a homogeneous haze.

## Rendering Through Haze

The object and the haze add their light along the ray:
$$
C_r=\\int_{t_n}^{t_f}T(t)\\big(\\sigma^{\\mathrm{obj}}(t)\\mathbf c^{\\mathrm{obj}}(t)
+\\sigma^{\\mathrm{haze}}\\mathbf c^{\\mathrm{haze}}\\big)dt
$$

## Networks

* **Object network:** $\\sigma^{\\mathrm{obj}}$ and $\\mathbf c^{\\mathrm{obj}}$ from position and view.
* **Haze network (view only):** an MLP with 4 layers of 128 units predicting $\\mathbf c^{\\mathrm{haze}}$ and
  $\\sigma^{\\mathrm{haze}}$ from the viewing direction alone.
"""


def test_a_network_making_one_of_several_labelled_fields_is_a_field_of_its_own(tmp_path: Path):
    ledger = _ledger(tmp_path, SEVERAL)
    assert ("Networks", "FieldWrapper") in _new(ledger), _new(ledger)
    part = next(p for p in ledger.new if p.heading == "Networks")
    assert "haze" in str(part.production_scores["FieldWrapper"])


def test_one_field_with_one_label_stays_a_backbone(tmp_path: Path):
    # the same network section in a paper whose field has one set of outputs: a backbone, not a second field
    single = SEVERAL.replace("\\mathrm{haze}", "\\mathrm{obj}").replace("Haze network (view only)", "Object MLP")
    ledger = _ledger(tmp_path, single)
    assert ("Networks", "Backbone") in _new(ledger), _new(ledger)


def test_a_colour_split_in_two_with_one_density_is_not_several_fields(tmp_path: Path):
    # diffuse and specular colours of one field (one density): the network is the field's own, not a second field
    split = SEVERAL.replace("\\sigma^{\\mathrm{haze}}", "\\sigma").replace("\\sigma^{\\mathrm{obj}}", "\\sigma")
    split = split.replace("\\mathrm{haze}", "\\mathrm{spec}").replace("\\mathrm{obj}", "\\mathrm{diff}")
    assert "haze}" not in split and "obj}" not in split
    assert ("Networks", "FieldWrapper") not in _new(_ledger(tmp_path, split))


LOSSES = """# OpaqueNeRF: Radiance Fields with Opaque Surfaces

## Rendering

Colours are composited along each ray with the usual volume rendering weights $w_i$.

## Losses

* **Reconstruction:**
  $$
  \\mathcal L_{\\mathrm{rgb}}=\\sum_{\\mathbf r}\\left(\\frac{\\hat C_r-C_r}{\\hat C_r+\\epsilon}\\right)^2
  $$
* **Binary opacity prior on the accumulated weights (a beta distribution):**
  $$
  \\mathcal L_{\\mathrm{op}}=\\sum_{\\mathbf r}\\log(A(\\mathbf r))+\\log(1-A(\\mathbf r))
  $$
* **Total:**
  $$
  \\mathcal L=\\mathcal L_{\\mathrm{rgb}}+\\lambda\\,\\mathcal L_{\\mathrm{op}},\\quad \\lambda=0.01
  $$
"""


def test_a_loss_part_splits_into_the_reconstruction_and_a_term_of_its_own(tmp_path: Path):
    # a relative squared error (no card has it) and a prior on the accumulated weights: two parts, two productions
    ledger = _ledger(tmp_path, LOSSES)
    new = _new(ledger)
    assert ("Losses", "RGBLoss") in new, new
    prior = [p for p in ledger.new if p.production == "Regularizers"]
    assert len(prior) == 1 and prior[0].heading.startswith("Binary opacity prior"), new
    assert [e["latex"].split("=")[0] for e in prior[0].equations] == ["\\mathcal{L}_{\\mathrm{op}}"]
    rgb = next(p for p in ledger.new if p.heading == "Losses")
    # the weighted sum of the terms is not a term: it stays with the reconstruction part
    assert len(rgb.equations) == 2 and "lambda" in rgb.equations[1]["latex"]


def test_a_loss_part_with_one_kind_of_term_is_not_split(tmp_path: Path):
    # both terms compare the rendered colour with the observed one: one reconstruction part
    prior = "\\log(A(\\mathbf r))+\\log(1-A(\\mathbf r))"
    one = LOSSES.replace(prior, "\\lvert\\hat C_r-C_r\\rvert")
    assert one != LOSSES
    assert [p.production for p in _ledger(tmp_path, one).new if p.section == "Losses"] == ["RGBLoss"]


def test_a_set_of_valid_rays_beside_the_loss_is_not_a_loss_term(tmp_path: Path):
    # "R_C = {r | ...}": the rays the loss is taken over, in set-builder notation, not a regulariser of its own
    rays = LOSSES.replace("\\log(A(\\mathbf r))+\\log(1-A(\\mathbf r))", "").replace(
        "\\mathcal L_{\\mathrm{op}}=\\sum_{\\mathbf r}",
        "\\mathcal R_{C}=\\{\\mathbf r \\mid A(\\mathbf r) \\geq 0.5\\}")
    assert "\\mathcal R_{C}=\\{" in rays
    assert [p.production for p in _ledger(tmp_path, rays).new if p.section == "Losses"] == ["RGBLoss"]


def test_a_cards_reconstruction_loss_beside_a_new_term_leaves_only_the_term(tmp_path: Path):
    # the reconstruction term is the L2 card's: the part is known, its prior a part of its own
    l2 = LOSSES.replace("\\left(\\frac{\\hat C_r-C_r}{\\hat C_r+\\epsilon}\\right)^2",
                        "\\lVert\\hat C_r-C_r\\rVert^2")
    assert l2 != LOSSES
    ledger = _ledger(tmp_path, l2)
    losses = next(p for p in ledger.parts if p.heading == "Losses")
    assert losses.status == "known" and losses.covered_by == ["rgb_l2"], losses.why
    assert [p.production for p in ledger.new if p.section == "Losses"] == ["Regularizers"]


STREAM = """# FlowGrid: A Dynamic Scene Representation

## Problem Setup

A dynamic scene is captured by several cameras over time.

## Shifting Feature Channels

The hash table and voxel grid hold explicit features. Each time step adds two channels to every entry, and the
features of a time between two frames are interpolated from the two frames; the channels of earlier times are
dropped as time advances, so the representation stays temporal and compact.
"""


def test_the_words_of_the_papers_family_count_little_for_where_a_part_lands(tmp_path: Path):
    # read as a static paper, the time words pull the part to the time wrappers; in a dynamic paper every part
    # speaks of time, and the part is what it changes: the feature grid (PosEncoding)
    assert _new(_ledger(tmp_path, STREAM, family="dynamic")) == [("Shifting Feature Channels", "PosEncoding")]
    scores = _ledger(tmp_path, STREAM).new[0].production_scores
    assert scores["FieldWrapper"] > _ledger(tmp_path, STREAM, family="dynamic").new[0].production_scores.get(
        "FieldWrapper", 0)


DEPTH_LOSS = """# KeyNeRF: Radiance Fields Supervised by Keypoints

## Abstract

KeyNeRF fits a radiance field to a few photographs and the keypoints structure from motion returns with them.

## 1 Introduction

Radiance fields need many views. Structure from motion returns sparse keypoints with the camera poses. We learn
the plenoptic function by our novel radiance field that conditions on keypoints.

## 3 Method

### 3.1 Keypoint Depth

We add a loss that pulls the expected termination depth of each ray towards the depth of the keypoint seen
through its pixel, weighted by the keypoint's reprojection error, so that few views suffice.

### 3.2 Loss Function

The radiance field that conditions on keypoints is trained by minimizing the ℓ2-loss between the rendered colours
and the observed colours of the rays of a batch; we learn it with plain gradient descent.
"""


def test_a_loss_on_another_quantity_than_colour_is_a_regulariser(tmp_path: Path):
    # "loss" says that a part is a loss, not which: a term added on depth is a term beside the photometric loss
    ledger = _ledger(tmp_path, DEPTH_LOSS)
    assert ("Keypoint Depth", "Regularizers") in _new(ledger), _new(ledger)


def test_a_loss_function_section_is_not_linked_to_a_claim_by_the_word_function(tmp_path: Path):
    # "Loss Function" shares only "function" with the claim about the plenoptic function: no link, and the
    # section (the l2 loss, written with a script l) is no new part
    ledger = _ledger(tmp_path, DEPTH_LOSS)
    part = next(p for p in ledger.parts if p.heading == "Loss Function")
    assert part.status != "new", (part.status, part.why)


CURRICULUM = """# TickNeRF: Radiance Fields of Moving Scenes

## Abstract

TickNeRF renders a moving scene at any time from a monocular video.

## 1 Introduction

Dynamic scenes change over time.

## 3 Method

A deformation network maps each point and time into a canonical space queried by a static field.

## 4 Implementation Details

We train for 200k iterations with a batch of 4096 rays. To ease training, we apply a curriculum learning strategy
where we incrementally add images with higher time stamps. We use the Adam optimizer.
"""


def test_a_curriculum_stated_in_the_details_is_a_schedule_hook_unless_it_cites(tmp_path: Path):
    ledger = _ledger(tmp_path, CURRICULUM, family="dynamic")
    phases = [p for p in ledger.new if p.production == "ScheduleHook"]
    assert len(phases) == 1 and "curriculum" in phases[0].sentences[0], _new(ledger)
    cited = CURRICULUM.replace("we apply a curriculum", "following [4], we apply a curriculum")
    assert not [p for p in _ledger(tmp_path, cited, family="dynamic").new if p.production == "ScheduleHook"]


RESTATED = """# WarpNeRF: Radiance Fields of Bending Objects

## Abstract

WarpNeRF renders objects that bend, from a monocular video.

## 1 Introduction

We propose a bending field that maps every point into a rest pose queried by a static radiance field.

## 3 Method

### 3.1 Bending Field

We propose a bending network that maps a point and a time to an offset into the rest pose.

### 3.2 Rendering

We now adapt NeRF volume rendering to the bent rays. The colour of a pixel at time t is then

$$\hat{C}(\mathbf{p}, t) = \sum_{n=1}^{N} w_n(t) \, \mathbf{c}(\mathbf{p}_n + \Delta_n(t)) \tag{3}$$

where w are the weights along the bent ray.

## 4 Experiments

We compare with D-NeRF on ten scenes.
"""


def test_a_part_that_opens_with_the_earlier_work_it_takes_restates_it(tmp_path: Path):
    # no claim links to the rendering part and its opening sentence says it adapts NeRF's: a restatement, not a new
    # part, although no card has its equation (the bending field stays new); opened otherwise, it is new
    ledger = _ledger(tmp_path, RESTATED, family="dynamic")
    rendering = next(p for p in ledger.parts if p.heading == "Rendering")
    assert rendering.status == "unclaimed" and "restates earlier work" in rendering.why, (rendering.status,
                                                                                         rendering.why)
    assert any(p.heading == "Bending Field" for p in ledger.new), _new(ledger)
    own = RESTATED.replace("We now adapt NeRF volume rendering to the bent rays.",
                           "We render the bent rays with a new compositing rule.")
    rendering = next(p for p in _ledger(tmp_path, own, family="dynamic").parts if p.heading == "Rendering")
    assert rendering.status == "new", (rendering.status, rendering.why)


def test_holding_a_value_for_some_iterations_then_easing_it_in_is_a_training_phase(tmp_path: Path):
    start = CURRICULUM.index("To ease training")
    end = CURRICULUM.index("time stamps.") + len("time stamps.")
    held = (CURRICULUM[:start] + "We fix the window of the time encoding at zero for 1000 iterations and then "
            "linearly ease in its frequencies." + CURRICULUM[end:])
    phases = [p for p in _ledger(tmp_path, held, family="dynamic").new if p.production == "ScheduleHook"]
    assert len(phases) == 1 and "linearly ease in" in phases[0].sentences[0], _new(_ledger(tmp_path, held))


DELAYED = """# AmbiNeRF: Radiance Fields with Ambient Coordinates

## Abstract

AmbiNeRF renders scenes whose topology changes over time.

## 1 Introduction

We propose ambient coordinates beside the three spatial ones.

## 3 Method

### 3.1 Ambient Coordinates

We propose to embed the template in higher dimensions with ambient coordinates predicted per point.

Delayed use of Ambient Dimensions. We keep the ambient coordinates off at first and ease in their frequencies
after a number of iterations, so that motion is first explained by the positions.

## 4 Experiments

We evaluate on twelve scenes.
"""


DECAYED = """# SparseSplats: Few-View Gaussians

## Abstract

SparseSplats fits Gaussians to three views.

## 1 Introduction

We propose to decay the opacity of the Gaussians during training.

## 3 Method

### 3.1 Opacity Decay Strategy

We propose to decay the opacity of every Gaussian during optimization: every 50 iterations its opacity is
multiplied by a factor below one, so that Gaussians far from the surface fade out.

## 4 Experiments

We evaluate on LLFF.
"""


def test_a_part_that_delays_or_eases_something_in_is_a_schedule_hook(tmp_path: Path):
    ledger = _ledger(tmp_path, DELAYED, family="dynamic")
    assert ("Delayed use of Ambient Dimensions", "ScheduleHook") in _new(ledger), _new(ledger)
    ledger = _ledger(tmp_path, DECAYED, family="splatting")  # a value decayed over the steps of training
    assert ("Opacity Decay Strategy", "ScheduleHook") in _new(ledger), _new(ledger)


TOPIC = """# HazeField: Radiance Fields in Scattering Media

## Abstract

We propose HazeField, a radiance field for scenes in scattering media, with a pseudo-label guided decoupling.

## 1 Introduction

Scattering media attenuate light. Existing methods fail in hazy scenes.

## 3 Method

### 3.1 Medium Rendering

We render the object and the scattering medium separately: the medium's backscatter and attenuation are composited
with the object's colour along each ray.

### 3.2 Pseudo-Label Guided Decoupling

We propose to guide the early training with pseudo-labels. Pseudo ground truth images of the scene without the
scattering medium are produced by a dehazing network, and the object's colour rendered without the medium is
supervised by minimizing the mean squared error (MSE) to these pseudo-labels during the first iterations, which
decouples the object densities from the scattering medium.
"""


def test_the_papers_topic_in_every_part_does_not_decide_where_one_lands(tmp_path: Path):
    """The title's subject (a scattering medium) is in every part's text: a part about supervising with
    pseudo-labels is a loss term, not the renderer, even though its sentences and the paper's claims mention the
    medium (with them counted it scored Renderer 16.4 against RGBLoss 3.8)."""
    new = dict(_new(_ledger(tmp_path, TOPIC)))
    assert new["Pseudo-Label Guided Decoupling"] in ("Regularizers", "RGBLoss")


DETAILS = """# TwinSplats: Two Fields Agree

## Abstract

We propose to train two radiance fields that regularise each other from sparse views.

## 1 Introduction

We propose to sample pseudo views between the training views and to make two fields agree on them.

## 4 Method

### 4.1 Co-training

We propose to train two radiance fields at once and to penalise their disagreement on pseudo views.

### 4.2 Implementation Details

Datasets. We propose to evaluate on LLFF and on DTU with three training views each.

Evaluation Metrics. We propose to report PSNR, SSIM and LPIPS of both radiance fields on held-out views.

Pseudo-view Sampling. We propose to sample pseudo views by interpolating between the two nearest training cameras.

## 5 Experiments

Both fields improve.
"""


def test_a_run_in_paragraph_that_reports_on_the_experiments_is_no_part(tmp_path: Path):
    """"Datasets." and "Evaluation Metrics." in the method's details describe the experiments, not a part of the
    method, whatever they claim; "Pseudo-view Sampling." beside them is a part."""
    headings = [h for h, _ in _new(_ledger(tmp_path, DETAILS, family="splatting"))]
    assert "Pseudo-view Sampling" in headings and "Co-training" in headings, headings
    assert "Datasets" not in headings and "Evaluation Metrics" not in headings, headings


HDR = """# BrightField: Radiance Fields of Bright Rooms

## Abstract

We propose BrightField for rooms with bright lamps and dark corners, rendered in real-time.

## 1 Introduction

We introduce a perceptual colour space for high dynamic range radiance.

## 3 Method

### 3.1 Modeling of High Dynamic Range

We introduce a perceptual colour space for high dynamic range radiance: the field predicts colours in it and
the loss compares them there. Our renders are shown in real-time at the training time's quality; the dynamic range
of the captures spans twenty stops of exposure.

## 4 Experiments

We evaluate on six rooms.
"""


def test_a_dynamic_range_and_real_time_say_nothing_of_time(tmp_path: Path):
    """"High dynamic range", "real-time" and "training time" in a static paper name no time-conditioned field."""
    new = _new(_ledger(tmp_path, HDR, family="static"))
    assert new and all(production != "FieldWrapper" for _, production in new), new
