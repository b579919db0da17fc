"""Flat PDF-text extractions (page-split or heading-less): numbered headings recovered only when their numbers
follow each other, page markers as locations, hyphenation undone, numbered flattened equations kept."""

from nerfify_ns.paper.pagesplit import is_page_split, page_split_blocks

TEXT = """

---

## Page 1

TimeField: Fast Dynamic Radiance Fields
Ann Author Ben Writer
1University of Somewhere2Another Lab
Abstract
We propose a time-conditioned radiance field that represents dy-
namic scenes with latent codes.
Lab Research.1. Introduction
Dynamic scenes are hard. We build on NeRF [1] and add a
deformation field that warps points into a canonical space.

---

## Page 2

2. Related Work
Prior work uses static fields.
3. Method
3.1. Deformation Field
The deformation maps a point and a time to an offset:
Δx = D(γ(x), γ(t)), (1)
5123. The emptiness voxel is not a heading.
3.2. Training
We train for 30k iterations.
4. Experiments
Results.
"""


def test_a_page_split_extraction_is_recognised():
    assert is_page_split(TEXT)
    assert not is_page_split("# Title\n\n## 1 Introduction\n\ntext\n")


def test_headings_title_abstract_and_equations_are_recovered():
    blocks = page_split_blocks(TEXT)
    headings = [(b.number, b.text) for b in blocks if b.kind == "heading"]
    assert headings == [("", "Abstract"), ("1", "Introduction"), ("2", "Related Work"), ("3", "Method"),
                        ("3.1", "Deformation Field"), ("3.2", "Training"), ("4", "Experiments")]
    assert blocks[0].kind == "title" and blocks[0].text == "TimeField: Fast Dynamic Radiance Fields"
    start = next(i for i, b in enumerate(blocks) if b.kind == "heading" and b.text == "Abstract")
    abstract = blocks[start + 1]
    assert "dynamic scenes" in abstract.text  # "dy-\nnamic" joined
    equations = [b for b in blocks if b.kind == "equation"]
    assert [(e.number, e.text) for e in equations] == [("1", "Δx = D(γ(x), γ(t))")]
    assert equations[0].loc.page == 2
    assert any("5123. The emptiness voxel" in b.text for b in blocks if b.kind == "para")


# pdftotext's layout for a conference template: a heading's number alone on its line and its title (in capitals)
# on the next, page numbers on lines of their own, each followed by the running header; a lone "#" left of a
# formula's bracket; a cross-reference's number at a line's end ("Sections 2 and 4.") before a capitalised line.
SPLIT = "\n".join(["Streamed Fields for Dynamic Scenes", "Ann Author1, Ben Writer2", "ABSTRACT",
                   "We stream feature channels over time.", "1", "INTRODUCTION",
                   "Dynamic scenes are hard to store.", "1", "Under review as a conference paper",
                   "More introduction text follows here.", "2", "METHOD",
                   "We describe the field in Sections 2 and 4.", "2", "Under review as a conference paper",
                   "2.1", "STREAMED CHANNELS", "Each entry stores F + k(T - 1) channels.", "#",
                   "A sliding window picks F channels at time t. Shown in Sections 2.1 and 3.",
                   "Beyond this the field is standard.", "3", "Under review as a conference paper",
                   "3", "EXPERIMENTS", "Results."] + ["Filler line of running text."] * 100)


def test_a_split_number_and_title_is_a_heading_and_page_numbers_are_not():
    assert is_page_split(SPLIT)  # a lone "#" is no markdown heading
    headings = [(b.number, b.text) for b in page_split_blocks(SPLIT) if b.kind == "heading"]
    assert headings == [("", "Abstract"), ("1", "INTRODUCTION"), ("2", "METHOD"), ("2.1", "STREAMED CHANNELS"),
                        ("3", "EXPERIMENTS")]


def test_an_equation_number_alone_on_its_line_takes_the_short_lines_above_it():
    text = "\n".join(["Streamed Fields", "Ann Author1, Ben Writer2", "1", "METHOD",
                      "We penalise the dynamic density so that the dynamic field is used only when",
                      "needed:", "Lσd = E(σd)", "(1)", "The weight of this term is small, and the flow reads",
                      "v = MLPv(Hv(x, t))", "x′ = x + v", "(2)", "Then the next paragraph starts here."]
                     + ["Filler line of running text."] * 100)
    equations = [(b.number, b.text) for b in page_split_blocks(text) if b.kind == "equation"]
    assert equations == [("1", "Lσd = E(σd)"), ("2", "v = MLPv(Hv(x, t)) x′ = x + v")]


def test_a_page_break_line_a_page_number_before_it_and_an_equation_with_its_full_stop():
    """"---Page Break---" is a page marker; the page's number before it is no heading's number for the next page's
    first line; a display equation set over short lines, ending in its full stop, is read above its number."""
    filler = ["Filler line of running text that is as long as the others in the column here."] * 60
    text = "\n".join(["Warped Views", "Ann Author", "1", "Introduction", *filler, "2", "Method",
                      "We render the right view and shift it to the left one by its disparity, as denoted by",
                      "4", "", "---Page Break---",
                      "Ishifted[i, j] = Ir[i - di, j - dj].", "(1)",
                      "Formally, we define the loss function as the mean over the pixels of the difference",
                      "Lconsis = 1", "N", "X", "i,j", "Il", "ij - Ishifted", "ij", ".", "(2)",
                      "To optimise it better we translate the camera to the left or the right each time.",
                      *filler])
    assert is_page_split(text)
    blocks = page_split_blocks(text)
    assert [(b.number, b.text) for b in blocks if b.kind == "heading"] == [("1", "Introduction"), ("2", "Method")]
    assert [(b.number, b.text) for b in blocks if b.kind == "equation"] == [
        ("1", "Ishifted[i, j] = Ir[i - di, j - dj]."), ("2", "Lconsis = 1 N X i,j Il ij - Ishifted ij .")]
    assert {b.loc.page for b in blocks if b.kind == "equation"} == {2}


def test_a_numbered_list_item_with_a_run_in_title_is_not_a_heading():
    # an introduction listing the problems "1. Parameterization. Unbounded scenes ..." before the paper's own
    # "1. Preliminaries": the items' numbers would otherwise take the sections' places
    listed = TEXT.replace("Dynamic scenes are hard. We build on NeRF [1] and add a",
                          "Dynamic scenes are hard for three reasons:\n"
                          "1. Motion. Points move between frames and the\n"
                          "2. Memory. Long videos need more memory than\n"
                          "3. Speed. Rendering each frame takes long. We add a")
    listed = listed.replace("Lab Research.1. Introduction\n", "")
    headings = [(b.number, b.text) for b in page_split_blocks(listed) if b.kind == "heading"]
    assert ("2", "Related Work") in headings and ("3", "Method") in headings, headings
    assert not any(t.startswith(("Motion", "Memory", "Speed")) for _, t in headings), headings


def test_a_run_in_heading_in_sentence_case_opens_a_paragraph_and_a_sentence_does_not():
    text = TEXT.replace("We train for 30k iterations.",
                        "We train for 30k iterations with a batch of rays drawn from\n"
                        "Delayed use of Ambient Dimensions. Motion can be encoded by\n"
                        "moving points. Results are shown in Table. We compare\n"
                        "We compare with NeRF. The baselines are strong.")
    paragraphs = [b.text for b in page_split_blocks(text) if b.kind == "para"]
    assert any(p.startswith("Delayed use of Ambient Dimensions.") for p in paragraphs), paragraphs
    assert not any(p.startswith(("Results are shown", "We compare with NeRF")) for p in paragraphs), paragraphs


# a converter's text with its sections in plain numbered headings, HTML page comments, a table's column heads that
# came out as markdown headings further on ("# Gaussians", "# 100K"), a sentence wrapped at a line that reads as an
# appendix heading ("A Gaussian" / "expands when ..."), and a page number alone before a table's caption
TABLE_HEADS = "\n".join(
    ["<!-- page 1 -->", "Textured Splats: Adaptive Sampling for Gaussians", "Ann Author1", "Abstract",
     "We allocate texture resolution by rendering error.", "1. Introduction", "Splatting is fast.",
     "2. Related Work", "Textured Gaussians exist.", "3. Method", "We warp texture coordinates.",
     "A Gaussian", "expands when its averaged gradient exceeds a threshold.", "<!-- page 2 -->", "7",
     "Table 3. Comparisons between warps.", "4. Experiments", "Results follow.", "# Gaussians", "# 100K",
     "0.775", "# 200K", "0.779"] + ["Filler line of running text."] * 100)


def test_plain_numbered_headings_before_a_tables_hash_lines_make_a_flat_extraction():
    assert is_page_split(TABLE_HEADS)
    blocks = page_split_blocks(TABLE_HEADS)
    assert blocks[0].kind == "title" and blocks[0].text == "Textured Splats: Adaptive Sampling for Gaussians"
    headings = [(b.number, b.text) for b in blocks if b.kind == "heading"]
    assert headings == [("", "Abstract"), ("1", "Introduction"), ("2", "Related Work"), ("3", "Method"),
                        ("4", "Experiments")]
    assert any("A Gaussian expands when" in b.text for b in blocks if b.kind == "para")
    assert not any("page" in b.text for b in blocks)  # the page comments are markers, not text
    # a markdown paper whose first heading comes before any numbered plain line stays markdown
    assert not is_page_split("# Title\n\n## 1 Introduction\n\n" + "text\n" * 120 + "1. Introduction\n")
