"""Reading any real paper never ends a run: the dry run of the real CLI over every paper of ../shared/papers and the
examples (exit 0, 1 or 2, no traceback, bounded time and memory), MinerU-style numbers (spaced digits, whose
unjoined digits would fold into a division by zero), and a fuzz of the reader with fragments cut at random (fixed
seed) from those papers:
paper ingestion, hyperparameters, notation, equation parsing and the compiler's parts, where only the project's
own errors (PaperError) and ParseFailures may come out. Only robustness is asserted, never which holes a paper
gets (the planner changes)."""

from __future__ import annotations

import random
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nerfify_ns.equations import Equation, ParseFailure, parse_equations, parse_expression
from nerfify_ns.equations.confidence import latex_issues
from nerfify_ns.equations.normalize import normalize_latex
from nerfify_ns.errors import NerfifyError
from nerfify_ns.paper import ingest
from nerfify_ns.paper.hyperparams import extract_from_sentence, split_sentences

REPO = Path(__file__).resolve().parents[2]
SHARED_PAPERS = REPO.parent / "shared" / "papers"
EXAMPLES = sorted((REPO / "examples").glob("*.md"))
CLI = Path(sys.executable).parent / "ns-nerfify"
ADDRESS_SPACE = 6 << 30
DRY_RUN_SECONDS = 120
HEAD = ("# A Radiance Field\n\n## Abstract\n\nWe present a neural radiance field with volume rendering of the rays "
        "for the view synthesis of a scene.\n\n## 3 Method\n\n")
MINERU = HEAD + (
    "We train with a learning rate of $1 \\times 1 0 ^ { - 2 }$ and a batch of $5 1 2$ rays, decaying to "
    "$0 . 0 0 1$; the weight decay is $1 0 ^ { - 4 }$ and the loss weight $\\lambda = 0 ^ { - 2 }$.\n\n"
    "$$\n\\hat { C } ( \\mathbf { r } ) = \\sum _ { i = 1 } ^ { N } T _ { i } \\alpha _ { i } \\mathbf { c } _ { i } "
    "+ 1 \\times 1 0 ^ { - 2 } \\tag { 1 }\n$$\n")


def shared_papers() -> list[Path]:
    if not SHARED_PAPERS.is_dir():
        return []
    return sorted(p for p in SHARED_PAPERS.glob("*/*") if p.suffix in (".pdf", ".md") and p.name != "SOURCE.md")


def _limit() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))


def dry_run(paper: Path, cwd: Path) -> subprocess.CompletedProcess:
    if not CLI.is_file():
        pytest.skip(f"{CLI} not installed (scripts/setup.sh installs the ns-nerfify entry point)")
    start = time.perf_counter()
    proc = subprocess.run([str(CLI), str(paper), "--dry-run"], capture_output=True, text=True, cwd=cwd,
                          timeout=DRY_RUN_SECONDS, preexec_fn=_limit)
    elapsed = time.perf_counter() - start
    assert proc.returncode in (0, 1, 2), f"{paper.name}: exit {proc.returncode}\n{proc.stderr[-2000:]}"
    assert "Traceback" not in proc.stdout and "Traceback" not in proc.stderr, \
        f"{paper.name}:\n{(proc.stderr or proc.stdout)[-3000:]}"
    assert elapsed < DRY_RUN_SECONDS
    return proc


# ------------------------------------------------------------------------------------ MinerU's numbers
def test_mineru_numbers_are_read_and_never_end_a_run(tmp_path):
    """MinerU's ``$1 \\times 1 0 ^ { - 2 }$`` is read as 0.01 (its digits joined before the constant is folded:
    1 x 0^{-2} would divide by zero), and a paper's own 0^{-2} is one unread value, not a traceback."""
    from nerfify_ns.synthesis.novel.notation import PaperWords, mentions

    paper = tmp_path / "mineru.md"
    paper.write_text(MINERU)
    doc = ingest(paper)
    values = {h.name: h.value for h in doc.hyperparameters}
    assert values["learning_rate"] == pytest.approx(0.01) and values["batch_size"] == 512
    assert values.get("learning_rate_final") == pytest.approx(0.001)
    words = PaperWords.read(doc)
    assert words.sentences and not words.unread
    assert mentions(r"a weight of $\lambda = 0 ^ { - 2 }$ on $x_{1}$") is not None
    (eq,) = doc.equations
    assert isinstance(parse_equations(eq.latex)[0], Equation)


def test_the_mineru_paper_dry_run_has_no_traceback(tmp_path):
    paper = tmp_path / "mineru.md"
    paper.write_text(MINERU)
    proc = dry_run(paper, tmp_path)
    assert proc.returncode in (0, 1)
    assert "lr: 0.01" in proc.stdout


# ------------------------------------------------------------------------------------ the dry run
def _dry_run_cases() -> list:
    cases = [pytest.param(p, id=f"examples/{p.name}") for p in EXAMPLES]
    papers = shared_papers()
    if papers:
        cases += [pytest.param(p, id=f"shared/{p.parent.name}/{p.name}") for p in papers]
    else:
        cases.append(pytest.param(None, id="shared-papers-absent"))
    return cases


@pytest.mark.slow
@pytest.mark.parametrize("paper", _dry_run_cases())
def test_the_dry_run_of_every_paper_ends_cleanly(paper, tmp_path):
    """ns-nerfify PAPER --dry-run (the real CLI, a subprocess under a 6 GiB address-space limit and a 120 s
    timeout): exit 0, 1 or 2, never a traceback. A few seconds each on an idle machine."""
    if paper is None:
        pytest.skip(f"{SHARED_PAPERS} is absent: the real papers live outside the project (../shared/papers)")
    dry_run(paper, tmp_path)


# ------------------------------------------------------------------------------------ the fuzz
SEED = 0
FRAGMENTS = 300
INGESTED = 40
CALL_SECONDS = 10.0  # per call; each takes milliseconds on an idle machine


def _corpus() -> list[tuple[str, str]]:
    texts = [(p.name, p.read_text(encoding="utf-8", errors="replace")) for p in EXAMPLES]
    texts += [(p.name, p.read_text(encoding="utf-8", errors="replace")) for p in shared_papers() if p.suffix == ".md"]
    return texts


def _fragments(n: int, seed: int = SEED) -> list[tuple[str, str]]:
    rng = random.Random(seed)
    corpus = _corpus()
    out = []
    for _ in range(n):
        name, text = rng.choice(corpus)
        length = rng.choice((8, 40, 200, 800, 2500))
        start = rng.randrange(max(1, len(text) - length))
        out.append((f"{name}@{start}+{length}", text[start:start + length]))
    return out


def _math_fragments(n: int, seed: int = SEED) -> list[tuple[str, str]]:
    """Random substrings of the papers' math (display and inline): the equation reader's own input, cut
    anywhere (unbalanced groups, half commands, lone scripts)."""
    import re

    rng = random.Random(seed)
    spans = [(name, m.group(1) or m.group(2)) for name, text in _corpus()
             for m in re.finditer(r"\$\$(.{1,4000}?)\$\$|\$([^$]{1,400})\$", text, re.S) if m.group(1) or m.group(2)]
    out = []
    for _ in range(n):
        name, span = rng.choice(spans)
        a = rng.randrange(len(span))
        b = rng.randrange(a, len(span)) + 1
        latex = span[a:b] if rng.random() < 0.7 else span
        if rng.random() < 0.4:  # as MinerU writes it: a blank after every token (1 0 ^ { - 2 })
            latex = re.sub(r"(\\[A-Za-z]+|\S)", r"\1 ", latex)
        out.append((f"{name} math {a}:{b}", latex))
    return out


def _timed(label: str, fn, *args):
    start = time.perf_counter()
    result = fn(*args)
    assert time.perf_counter() - start < CALL_SECONDS, f"{label}: {fn.__name__} took too long"
    return result


def test_fuzz_the_readers_with_fragments_of_real_papers():
    """Equation parsing, the paper normaliser, hyperparameters and notation on fragments cut at random: nothing
    but results and ParseFailures comes out, each call bounded."""
    from nerfify_ns.synthesis.novel.notation import mentions

    fragments = _fragments(FRAGMENTS)
    assert len(fragments) == FRAGMENTS
    read = 0
    for label, text in fragments:
        for latex in (text, text.strip("$ \n")[:600]):
            results = _timed(label, parse_equations, latex)
            assert results and all(isinstance(r, Equation | ParseFailure) for r in results), label
            read += sum(isinstance(r, Equation) for r in results)
            assert isinstance(_timed(label, parse_expression, latex), ParseFailure | object)
        assert isinstance(_timed(label, normalize_latex, text), str)
        assert isinstance(_timed(label, latex_issues, text), list)
        for sentence in _timed(label, split_sentences, text):
            assert isinstance(_timed(label, extract_from_sentence, sentence), list)
        assert isinstance(_timed(label, mentions, text), list)
    for label, latex in _math_fragments(FRAGMENTS):
        results = _timed(label, parse_equations, latex)
        assert results and all(isinstance(r, Equation | ParseFailure) for r in results), label
        read += sum(isinstance(r, Equation) for r in results)
        _timed(label, parse_expression, latex)
        assert isinstance(_timed(label, mentions, f"where ${latex}$ is the value"), list)
        assert isinstance(_timed(label, extract_from_sentence, f"a learning rate of ${latex}$"), list)
    assert read > 0  # the fragments hold readable equations too: the fuzz reaches the reader's depths


def test_fuzz_ingestion_notation_and_the_compiler_with_fragments_of_real_papers(tmp_path):
    """A markdown paper made of one fragment: ingested (a PaperError is an allowed answer), its notation read,
    its equations parsed as the compiler's items, and one part over all of them compiled (a recorded reason
    is an allowed answer, an exception is not)."""
    from nerfify_ns.synthesis.novel import implement_holes
    from nerfify_ns.synthesis.novel.implement import _parse, doc_items
    from nerfify_ns.synthesis.novel.notation import PaperWords
    from nerfify_ns.synthesis.resources import load_reference_plan

    base = load_reference_plan("vanilla-nerf")
    compiled = 0
    for k, (label, text) in enumerate(_fragments(INGESTED, seed=SEED + 1)):
        paper = tmp_path / f"fragment{k}.md"
        paper.write_text(HEAD + text + "\n")
        try:
            doc = _timed(label, ingest, paper)
        except NerfifyError:
            continue
        _timed(label, PaperWords.read, doc)
        items = doc_items(doc)
        for item in items:
            _timed(label, _parse, item)
            assert all(isinstance(p, Equation | ParseFailure) for p in item.parsed), label
        if items and compiled < 12:
            plan = dict(base)
            plan["holes"] = [{"production": production, "slot": slot, "section": items[0].section,
                              "equations": [{"number": it.number, "latex": it.latex} for it in items]}
                             for production, slot in (("Backbone", "model.field.MLPField.backbone"),
                                                      ("RGBHead", "model.field.MLPField.rgb_head"))]
            result = _timed(label, implement_holes, doc, plan)
            assert len(result.records) == 2 and all(r.reason for r in result.records), label
            compiled += 1
    assert compiled > 0


# ------------------------------------------------------------------------------------ the boundaries
def _gatenerf(tmp_path):
    sys.path.insert(0, str(REPO / "tests" / "synthesis"))
    from novel_papers import GATENERF

    paper = tmp_path / "gatenerf.md"
    paper.write_text(GATENERF)
    return ingest(paper)


def _two_parts() -> dict:
    from nerfify_ns.synthesis.resources import load_reference_plan

    plan = load_reference_plan("vanilla-nerf")
    plan["holes"] = [
        {"production": "Backbone", "slot": "model.field.MLPField.backbone", "section": "3.1 Gated embeddings",
         "equations": [{"number": n} for n in "123"]},
        {"production": "RGBHead", "slot": "model.field.MLPField.rgb_head", "section": "3.1 Gated embeddings",
         "equations": [{"number": "3"}]},
    ]
    return plan


def test_an_exception_inside_a_part_is_that_parts_reason_and_the_next_part_is_compiled(tmp_path, monkeypatch):
    from nerfify_ns.synthesis.novel import NOT_IMPLEMENTED, implement, implement_holes

    doc = _gatenerf(tmp_path)
    original = implement._implement_one

    def failing(work):
        if work.hole["production"] == "Backbone":
            raise RuntimeError("a compiler bug on this paper")
        return original(work)

    monkeypatch.setattr(implement, "_implement_one", failing)
    result = implement_holes(doc, _two_parts())
    backbone, rgb = result.records
    assert backbone.status == NOT_IMPLEMENTED
    assert backbone.reason == "could not compile the part: RuntimeError: a compiler bug on this paper"
    assert [e["number"] for e in backbone.equations] == ["1", "2", "3"]
    assert rgb.production == "RGBHead" and rgb.reason and "RuntimeError" not in rgb.reason
    hole = next(h for h in result.plan["holes"] if h["production"] == "Backbone")
    assert hole["status"] == NOT_IMPLEMENTED and "RuntimeError" in hole["reason"]


def test_an_exception_in_one_form_or_binding_is_recorded_and_the_part_goes_on(tmp_path, monkeypatch):
    from nerfify_ns.synthesis.novel import implement, implement_holes

    doc = _gatenerf(tmp_path)
    original = implement._Hole._bind

    def failing(self, key, sym, eq, corrected):
        if key.startswith("W"):
            raise KeyError("no such role")
        return original(self, key, sym, eq, corrected)

    monkeypatch.setattr(implement._Hole, "_bind", failing)
    plan = _two_parts()
    plan["holes"] = plan["holes"][:1]
    (record,) = implement_holes(doc, plan).records
    assert "could not be bound: KeyError: 'no such role'" in record.reason


def test_an_exception_in_one_sentence_or_equation_of_the_paper_is_recorded(tmp_path, monkeypatch):
    from nerfify_ns.paper import annotate, hyperparams
    from nerfify_ns.synthesis.novel import implement_holes
    from nerfify_ns.synthesis.novel.notation import PaperWords

    original_sentence, original_latex = hyperparams.extract_from_sentence, annotate.normalize_latex

    def sentence(text, loc=None, section=""):
        if "learning rate" in text:
            raise ValueError("an unreadable number")
        return original_sentence(text, loc, section)

    def latex(text, lost_backslashes=None):
        if r"\tanh" in text:
            raise RecursionError("maximum recursion depth exceeded")
        return original_latex(text, lost_backslashes)

    monkeypatch.setattr(hyperparams, "extract_from_sentence", sentence)
    monkeypatch.setattr(annotate, "normalize_latex", latex)
    doc = _gatenerf(tmp_path)
    assert any("hyperparameters of a sentence not read (ValueError: an unreadable number)" in w for w in doc.warnings)
    assert any(h.name == "hidden_dim" for h in doc.hyperparameters)  # the other sentences are read
    (memory,) = [e for e in doc.equations if e.number == "2"]
    assert any(n.startswith("not normalised (RecursionError") for n in memory.notes)
    assert r"\tanh" in memory.latex  # kept as written

    original_read = PaperWords._read_sentence

    def notation(self, text, where, notation):
        if "gate weight matrix" in text:
            raise TypeError("a symbol the table cannot take")
        return original_read(self, text, where, notation)

    monkeypatch.setattr(PaperWords, "_read_sentence", notation)
    words = PaperWords.read(doc)
    assert [reason for _, reason, _ in words.unread] == [
        "could not read the sentence's notation: TypeError: a symbol the table cannot take"]
    assert words.named  # the other sentences were read
    plan = _two_parts()
    plan["holes"] = plan["holes"][:1]
    notes = implement_holes(doc, plan).plan["notes"]
    assert any(n.startswith("notation: 1 sentence(s) or value(s) not read") for n in notes)


def test_the_check_records_an_exception_of_the_interpreter(monkeypatch):
    from nerfify_ns.equations import check, parse_equation

    def broken(*args, **kwargs):
        raise IndexError("an axis the interpreter lost")

    monkeypatch.setattr(check, "interpret", broken)
    report = check.check_lowering([parse_equation(r"y = x^2")], {"x": ("R",)}, {}, ["y"])
    assert not report.ok and report.reason == "interpreter: IndexError: an axis the interpreter lost"


@pytest.mark.slow
def test_a_paper_of_bombs_runs_to_its_plan_with_its_equations_drawn(tmp_path):
    """The real CLI up to the plan (the compiler's records and their images written) on a paper holding three
    nested 4096-term sums, a 10,000-term sum and 600 KB of nested braces: bounded like any paper, no traceback."""
    sys.path.insert(0, str(REPO / "tests" / "synthesis"))
    from novel_papers import GATENERF

    original = r"\mathbf{h}_{o} = [\mathbf{m} \odot \mathbf{h}_a, \mathbf{h}_b] \tag{3}"
    nested = (r"\mathbf{h}_{o} = \sum_{k=1}^{4096} \sum_{l=1}^{4096} \sum_{n=1}^{4096} [\mathbf{m} \odot "
              r"\mathbf{h}_a, \mathbf{h}_b] \tag{3}")
    terms = " + ".join(f"x_{{{i}}}" for i in range(1, 10_001))
    text = GATENERF.replace(original, nested).replace(
        "which feeds the density", f"$$\ny = {terms} \\tag{{4}}\n$$\n\n$$\ny = {'{' * 300_000}x{'}' * 300_000} "
                                   f"\\tag{{5}}\n$$\n\nwhich feeds the density")
    paper = tmp_path / "bombs.md"
    paper.write_text(text)
    if not CLI.is_file():
        pytest.skip(f"{CLI} not installed (scripts/setup.sh installs the ns-nerfify entry point)")
    out = tmp_path / "out"
    start = time.perf_counter()
    proc = subprocess.run([str(CLI), str(paper), "--until", "plan", "--out", str(out)], capture_output=True,
                          text=True, cwd=tmp_path, timeout=DRY_RUN_SECONDS, preexec_fn=_limit)
    assert proc.returncode in (0, 1), proc.stderr[-2000:]
    assert "Traceback" not in proc.stdout + proc.stderr
    assert time.perf_counter() - start < DRY_RUN_SECONDS
    assert (out / "plan.yaml").is_file() or (out / "report.html").is_file()
