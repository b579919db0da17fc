"""The suite file of ``ns-nerfify bench``: papers, scenes, references, reported metrics, novelty items, budgets.

The format is documented in ``docs/bench.md`` (keep the two in step). :func:`load_suite` reads a YAML file into
typed dataclasses and refuses anything malformed with one :class:`SuiteError` line naming the file, the key's path
(``papers[2].novelty[0].kind``) and what is expected. Paths are relative to the suite file. What is checked here is
the file itself; whether a paper's input exists, a reference method is installed or a plan composes is the business
of the task that uses it (a per-row failure in the tables, the rest of the suite still runs). A novelty check's
file must exist inside the suite folder (it is part of the suite).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.budget import BudgetError, check_count, check_seconds
from nerfify_ns.errors import NerfifyError

KINDS = ("equation", "loss", "architecture", "sampler", "schedule", "hyperparameter")
"""The kinds of novelty item (the paper's Table 4)."""
FAMILIES = ("static", "dynamic", "splatting", "surface", "not-training")
"""What a paper's method is: a static-scene radiance field, a dynamic one (time, per-frame codes, deformation), explicit
primitives such as 3D Gaussians, surface reconstruction, or not a view-synthesis training method at all (it uses
trained fields: registration, robotics, editing)."""
NEW_PRODUCTIONS = ("FieldWrapper", "PixelSampler", "ScheduleHook", "Primitive")
"""Productions an item may change besides the grammar's nonterminals (``nerfify_ns/registry/productions.yaml``):
a wrapper around the field (deformation into a canonical space, time conditioning, per-frame or per-camera codes,
several fields blended), the datamanager's pixel/ray sampler, a training-schedule callback (curriculum, annealing,
freezing), and explicit primitives (3D Gaussians: the grammar cannot build them)."""
NOT_TRAINING = "not-training"
"""The family whose parts change no production of the grammar (an item of such a paper may have no production)."""
MAX_PHRASE = 160
METRICS = ("psnr", "ssim", "lpips")
ID = re.compile(r"^[a-z0-9][a-z0-9_.-]{0,63}$")
MAX_BYTES = 1 << 20
MAX_NODES = 200_000
"""Nodes a suite file may expand to (aliases counted as what they stand for)."""
MAX_RUNS = 5000
"""(paper, scene, seed) runs of one suite; each is two tasks or more (reference, pipeline, ablations)."""


class SuiteError(NerfifyError):
    """A suite file that cannot be used (one line: the file, the key's path, what is wrong and what is expected)."""


@dataclass(frozen=True)
class BenchBudget:
    """How much each task computes (both sides of a comparison get the same)."""

    iterations: int = 30
    """Training iterations of the generated plugin and of the reference."""
    every: int = 15
    """Checkpoint cadence of the error-against-time curves (each checkpoint is rendered and scored)."""
    rays: int = 256
    """Training rays per batch, both sides."""
    smoke_iterations: int | None = None
    """Iterations of the ladder's smoke rung (None: the base's own)."""
    resolution: int = 32
    """Image size of a procedural scene (pixels)."""
    n_train: int = 12
    """Training views of a procedural scene."""
    n_test: int = 2
    """Held-out views of a procedural scene (every checkpoint renders them all)."""
    timeout: float = 1800.0
    """Time limit of one training or evaluation process, seconds."""
    patch_rounds: int = 0
    """Rounds of the visual-feedback patch loop in the full configuration (the ablation no-visual-feedback turns
    them off)."""
    check_timeout: float = 300.0
    """Time limit of one novelty check (sandboxed), seconds."""
    cpus: float = 1.0
    """CPU cores a task declares (Ray) and pins its threads to."""
    gpus: float = 0.0
    """GPUs a task declares (Ray)."""

    def check(self, where: str) -> None:
        try:
            for name in ("iterations", "every", "rays", "resolution", "n_train", "n_test"):
                check_count(f"{where}.{name}", getattr(self, name))
            if self.smoke_iterations is not None:
                check_count(f"{where}.smoke_iterations", self.smoke_iterations)
            check_count(f"{where}.patch_rounds", self.patch_rounds, 0)
            check_seconds(f"{where}.timeout", self.timeout)
            check_seconds(f"{where}.check_timeout", self.check_timeout)
            check_seconds(f"{where}.cpus", self.cpus)
            if isinstance(self.gpus, bool) or not isinstance(self.gpus, int | float) or self.gpus < 0:
                raise BudgetError(f"{where}.gpus must be a number >= 0, got {self.gpus!r}")
        except BudgetError as exc:
            raise SuiteError(str(exc)) from None


@dataclass(frozen=True)
class Reference:
    """What the generated plugin is compared against."""

    method: str | None = None
    """A Nerfstudio built-in method or an installed plugin's method name (trained with ``ns-train``, its method
    discovery limited to that method's own entry point)."""
    plan: Path | None = None
    """A plan YAML (composed and trained as our plugin)."""
    note: str = ""
    """Shown under the table (e.g. "the base's built-in: the paper's own code does not install here")."""

    @property
    def label(self) -> str:
        return self.method if self.method is not None else f"plan {self.plan.name}"


@dataclass(frozen=True)
class NoveltyItem:
    """One novel element of a paper, scored C (correct), I (incomplete), M (missing); W from its values."""

    id: str
    kind: str
    weight: float
    where: str
    """Where in the paper ("Sec. 3.2, Eqs. 1-9"); equation numbers in it link the item to compiled components."""
    plan: tuple[str, ...] = ()
    """Plan paths (``model.sampler.hierarchical``) whose presence, with evidence, shows the item in the plan."""
    values: dict[str, Any] = field(default_factory=dict)
    """The paper's values, plan path -> number (within 10% counts for W), text or list."""
    check: tuple[Path, str] | None = None
    """A reference function (file in the suite folder, function name) run on the generated component."""
    production: str = ""
    """The grammar production the part changes (``RGBHead``, ``FieldWrapper``, ...; see :data:`NEW_PRODUCTIONS`):
    where a hole for a novel part is expected. Required in a paper with a family, except a ``not-training`` one (its
    parts are not parts of a radiance-field method: they are read as contributions, never expected as holes)."""
    card: str | None = None
    """The knowledge card (``nerfify_ns/knowledge/cards/<name>.yaml``) of a technique the paper borrows: the part is
    known, expected in the plan at ``plan`` paths, and never a hole."""
    known_from: str = ""
    """Where a part no card covers comes from when it is not the paper's own (``3D-GS [19]``, ``vanilla-nerf's
    schedule``): not a novel part, so no hole is required for it; a hole for it is not spurious either (nothing in
    the knowledge base builds it)."""
    phrases: tuple[str, ...] = ()
    """2-4 short distinctive phrases copied from the paper's text about the part (a hole's quoted sentences are
    matched to the item by them)."""

    @property
    def novel(self) -> bool:
        """The paper's own part: no card, not known from elsewhere, and a part rather than a setting (a
        ``hyperparameter`` item is a value of some part). It is expected as a hole (or a compiled component) at
        ``production``; one without a production (a ``not-training`` paper's) is a contribution, never a hole."""
        return self.card is None and not self.known_from and self.kind != "hyperparameter"

    @property
    def equations(self) -> tuple[str, ...]:
        """Equation numbers named in ``where`` ("Eqs. 1-3, 7" -> 1, 2, 3, 7)."""
        return equation_numbers(self.where)


@dataclass(frozen=True)
class PaperEntry:
    id: str
    input: Path
    scenes: tuple[str, ...]
    reference: Reference
    novelty: tuple[NoveltyItem, ...]
    reported: dict[str, Any] = field(default_factory=dict)
    budget: BenchBudget = BenchBudget()
    seeds: tuple[int, ...] = (0,)
    family: str = ""
    """One of :data:`FAMILIES` ("" in a suite written before families: then items need no production or phrases)."""

    def fingerprint(self) -> str:
        """A digest of everything a task of this paper depends on (a changed entry is not taken as done)."""
        data = json.dumps(asdict(self), sort_keys=True, default=str)
        files = [self.input, *(i.check[0] for i in self.novelty if i.check), *([self.reference.plan] if
                                                                                self.reference.plan else [])]
        digest = hashlib.sha256(data.encode())
        for f in files:
            digest.update(Path(f).read_bytes() if Path(f).is_file() else b"-")
        return digest.hexdigest()[:16]


@dataclass(frozen=True)
class Suite:
    name: str
    path: Path
    papers: tuple[PaperEntry, ...]
    description: str = ""

    @property
    def folder(self) -> Path:
        return self.path.parent

    def paper(self, paper_id: str) -> PaperEntry:
        return next(p for p in self.papers if p.id == paper_id)

    def scene_path(self, scene: str) -> Path | None:
        """A dataset folder for ``scene`` when it names one (relative to the suite), else None (procedural)."""
        return resolve_scene(self.folder, scene)


def equation_numbers(where: str) -> tuple[str, ...]:
    """The equation numbers a "where" names: ``Eq. 7``, ``Eqs. 1-9``, ``Eqs. (3), (4) and 10``, ``Eq. A.2``."""
    out: list[str] = []
    for m in re.finditer(r"\bEq(?:uation)?s?\.?\s*((?:\(?[A-Z]?\.?\d+(?:\.\d+)?\)?\s*(?:[-–,]|and|&)?\s*)+)", where):
        for part in re.finditer(r"\(?([A-Z]?\.?\d+(?:\.\d+)?)\)?(?:\s*[-–]\s*\(?(\d+)\)?)?", m.group(1)):
            first, last = part.group(1), part.group(2)
            if last and first.isdigit():
                out += [str(n) for n in range(int(first), int(last) + 1)]
            else:
                out.append(first)
    return tuple(dict.fromkeys(out))


def productions() -> tuple[str, ...]:
    """The productions an item may name: the grammar's nonterminals and :data:`NEW_PRODUCTIONS`."""
    from importlib import resources

    try:
        data = yaml.safe_load(resources.files("nerfify_ns.registry").joinpath("productions.yaml").read_text())
        names = tuple((data or {}).get("nonterminals") or ())
    except (OSError, yaml.YAMLError, AttributeError):
        names = ()
    return tuple(dict.fromkeys((*names, *NEW_PRODUCTIONS)))


def card_names() -> tuple[str, ...]:
    """The knowledge base's card names (a card's file stem is its name)."""
    from nerfify_ns.knowledge.cards import CARDS_DIR

    return tuple(sorted(p.stem for p in CARDS_DIR.glob("*.yaml")))


def named_check(folder: Path, paper_id: str, item_id: str) -> tuple[Path, str] | None:
    """The check of an item the suite names none for, by name: ``checks/<paper id>.py`` in the suite folder, its
    function named as the item (``-`` read as ``_``), found without running the file; None when there is none."""
    import ast

    path = Path(folder) / "checks" / f"{paper_id}.py"
    func = item_id.replace("-", "_")
    if not path.is_file() or not func.isidentifier():
        return None
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (SyntaxError, UnicodeDecodeError, OSError):
        return None
    names = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    return (path.resolve(), func) if func in names else None


def resolve_scene(folder: Path, scene: str) -> Path | None:
    if "/" in scene or scene.startswith("."):
        return (folder / scene).resolve()
    return None


# ------------------------------------------------------------------------------------------ reading
class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        self._productions: tuple[str, ...] | None = None
        self._cards: tuple[str, ...] | None = None

    def fail(self, where: str, message: str) -> SuiteError:
        return SuiteError(f"{self.path.name}: {where}: {message}")

    def mapping(self, value: Any, where: str, required: tuple[str, ...], optional: tuple[str, ...]) -> dict:
        if not isinstance(value, dict):
            raise self.fail(where, f"expected a mapping with keys {', '.join(required + optional)}, got "
                                   f"{type(value).__name__}")
        unknown = [k for k in value if k not in required + optional]
        if unknown:
            raise self.fail(where, f"unknown key {unknown[0]!r} (allowed: {', '.join(required + optional)})")
        missing = [k for k in required if k not in value]
        if missing:
            raise self.fail(where, f"missing required key {missing[0]!r}")
        return value

    def text(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(where, f"expected non-empty text, got {value!r}")
        return value.strip()

    def ident(self, value: Any, where: str) -> str:
        text = self.text(value, where) if isinstance(value, str) else str(value)
        if not ID.match(text):
            raise self.fail(where, f"{text!r} is not an id (lower-case letters, digits, '_', '-', '.'; up to 64)")
        return text

    def number(self, value: Any, where: str, low: float, high: float) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
            raise self.fail(where, f"expected a number in [{low}, {high}], got {value!r}")
        return float(value)

    def budget(self, value: Any, where: str, base: BenchBudget) -> BenchBudget:
        names = tuple(f.name for f in fields(BenchBudget))
        data = self.mapping(value or {}, where, (), names)
        budget = replace(base, **data)
        budget.check(f"{self.path.name}: {where}")
        return budget

    def seeds(self, value: Any, where: str) -> tuple[int, ...]:
        if not isinstance(value, list) or not value or not all(
                isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2 ** 31 for s in value):
            raise self.fail(where, f"expected a non-empty list of seeds (whole numbers >= 0), got {value!r}")
        return tuple(dict.fromkeys(value))

    def reference(self, value: Any, where: str) -> Reference:
        if isinstance(value, str):
            return Reference(method=self.text(value, where))
        data = self.mapping(value, where, (), ("method", "plan", "note"))
        if ("method" in data) == ("plan" in data):
            raise self.fail(where, "give exactly one of 'method' (a Nerfstudio or installed method name) or 'plan'")
        note = str(data.get("note") or "")
        if "method" in data:
            return Reference(method=self.text(data["method"], f"{where}.method"), note=note)
        return Reference(plan=(self.path.parent / self.text(data["plan"], f"{where}.plan")).resolve(), note=note)

    def check(self, value: Any, where: str) -> tuple[Path, str]:
        text = self.text(value, where)
        file, _, func = text.partition(":")
        if not file.endswith(".py") or not func.isidentifier():
            raise self.fail(where, f"{text!r}: expected FILE.py:FUNCTION (a file in the suite folder)")
        path = (self.path.parent / file).resolve()
        if not path.is_relative_to(self.path.parent.resolve()):
            raise self.fail(where, f"{file!r} is outside the suite folder; checks belong to the suite")
        if not path.is_file():
            raise self.fail(where, f"check file {file!r} not found next to the suite")
        return path, func

    def production(self, value: Any, where: str) -> str:
        if self._productions is None:
            self._productions = productions()
        text = self.text(value, where)
        if text not in self._productions:
            raise self.fail(where, f"{text!r} is not a production (one of {', '.join(self._productions)})")
        return text

    def card(self, value: Any, where: str) -> str:
        if self._cards is None:
            self._cards = card_names()
        text = self.text(value, where)
        if text not in self._cards:
            raise self.fail(where, f"{text!r} is not a knowledge card (nerfify_ns/knowledge/cards: "
                                   f"{', '.join(self._cards)})")
        return text

    def phrases(self, value: Any, where: str) -> tuple[str, ...]:
        if not isinstance(value, list) or not 2 <= len(value) <= 4:
            raise self.fail(where, f"expected a list of 2-4 phrases from the paper, got {value!r}")
        out = tuple(self.text(v, f"{where}[{k}]") for k, v in enumerate(value))
        long = next((p for p in out if len(p) > MAX_PHRASE), None)
        if long is not None:
            raise self.fail(where, f"phrase {long[:40]!r}... is over {MAX_PHRASE} characters (a short phrase)")
        return out

    def item(self, value: Any, where: str, family: str = "") -> NoveltyItem:
        data = self.mapping(value, where, ("id", "kind", "weight", "where"),
                            ("plan", "values", "check", "production", "card", "known_from", "phrases"))
        kind = data["kind"]
        if kind not in KINDS:
            raise self.fail(f"{where}.kind", f"{kind!r} is not one of {', '.join(KINDS)}")
        plan = data.get("plan") or []
        plan = [plan] if isinstance(plan, str) else plan
        if not isinstance(plan, list) or not all(isinstance(p, str) and p for p in plan):
            raise self.fail(f"{where}.plan", "expected a plan path or a list of plan paths")
        values = data.get("values") or {}
        if not isinstance(values, dict) or not all(isinstance(k, str) for k in values):
            raise self.fail(f"{where}.values", "expected a mapping plan path -> the paper's value")
        for key, v in values.items():
            if not isinstance(v, int | float | str | list) or isinstance(v, bool):
                raise self.fail(f"{where}.values.{key}", f"expected a number, text or list, got {v!r}")
        if "card" in data and "known_from" in data:
            raise self.fail(where, "give at most one of 'card' (a knowledge card) or 'known_from' (a part no card "
                                   "covers)")
        if family:
            needed = ("phrases",) if family == NOT_TRAINING else ("production", "phrases")
            missing = next((k for k in needed if k not in data), None)
            if missing:
                raise self.fail(where, f"missing required key {missing!r} (the paper has a family)")
        return NoveltyItem(id=self.ident(data["id"], f"{where}.id"), kind=kind,
                           weight=self.number(data["weight"], f"{where}.weight", 0.0, 1.0),
                           where=self.text(data["where"], f"{where}.where"), plan=tuple(plan), values=dict(values),
                           check=self.check(data["check"], f"{where}.check") if data.get("check") else None,
                           production=self.production(data["production"], f"{where}.production")
                           if "production" in data else "",
                           card=self.card(data["card"], f"{where}.card") if "card" in data else None,
                           known_from=self.text(data["known_from"], f"{where}.known_from")
                           if "known_from" in data else "",
                           phrases=self.phrases(data["phrases"], f"{where}.phrases") if "phrases" in data else ())

    def paper(self, value: Any, where: str, budget: BenchBudget, seeds: tuple[int, ...]) -> PaperEntry:
        data = self.mapping(value, where, ("id", "input", "scenes", "reference", "novelty"),
                            ("reported", "budget", "seeds", "family"))
        pid = self.ident(data["id"], f"{where}.id")
        family = data.get("family", "")
        if "family" in data and family not in FAMILIES:
            raise self.fail(f"{where}.family", f"{family!r} is not one of {', '.join(FAMILIES)}")
        scenes = data["scenes"]
        scenes = [scenes] if isinstance(scenes, str) else scenes
        if not isinstance(scenes, list) or not scenes:
            raise self.fail(f"{where}.scenes", "expected a non-empty list of scenes (procedural names or folders)")
        scenes = [self.text(s, f"{where}.scenes[{k}]") for k, s in enumerate(scenes)]
        if not isinstance(data["novelty"], list):
            raise self.fail(f"{where}.novelty", "expected a list of novelty items")
        items = [self.item(v, f"{where}.novelty[{k}]", family) for k, v in enumerate(data["novelty"])]
        items = [i if i.check else replace(i, check=named_check(self.path.parent, pid, i.id)) for i in items]
        ids = [i.id for i in items]
        if len(set(ids)) != len(ids):
            raise self.fail(f"{where}.novelty", f"item id {next(i for i in ids if ids.count(i) > 1)!r} repeated")
        reported = data.get("reported") or {}
        reported = self.mapping(reported, f"{where}.reported", (), (*METRICS, "dataset", "note"))
        for m in METRICS:
            if m in reported and reported[m] is not None:
                self.number(reported[m], f"{where}.reported.{m}", 0.0, 100.0)
        return PaperEntry(id=pid, input=(self.path.parent / self.text(data["input"], f"{where}.input")).resolve(),
                          scenes=tuple(scenes), reference=self.reference(data["reference"], f"{where}.reference"),
                          novelty=tuple(items), reported=dict(reported),
                          budget=self.budget(data.get("budget"), f"{where}.budget", budget),
                          seeds=self.seeds(data["seeds"], f"{where}.seeds") if "seeds" in data else seeds,
                          family=family)


def load_suite(path: Path) -> Suite:
    """Read and check the suite at ``path`` (see the module docstring); :class:`SuiteError` names the problem."""
    from collections import Counter

    from nerfify_ns import safeio

    path = Path(path)
    if not path.is_file():
        raise SuiteError(f"suite {path} not found (a YAML file; see docs/bench.md)")
    try:  # bounded: size, depth, and the nodes its aliases expand to (an alias bomb stops while it is read)
        data = safeio.load_yaml(path, MAX_BYTES, what=path.name, max_nodes=MAX_NODES)
    except safeio.NotParsed as exc:
        raise SuiteError(f"{path.name}: not valid YAML ({str(exc).split('(', 1)[-1].rstrip(')')})") from None
    except safeio.ReadRefused as exc:
        raise SuiteError(f"suite {exc}") from None
    r = _Reader(path.resolve())
    data = r.mapping(data, "top level", ("papers",), ("name", "description", "budget", "seeds"))
    budget = r.budget(data.get("budget"), "budget", BenchBudget())
    seeds = r.seeds(data["seeds"], "seeds") if "seeds" in data else (0,)
    if not isinstance(data["papers"], list) or not data["papers"]:
        raise r.fail("papers", "expected a non-empty list of papers")
    papers, runs = [], 0
    for k, value in enumerate(data["papers"]):
        paper = r.paper(value, f"papers[{k}]", budget, seeds)
        runs += len(paper.scenes) * len(paper.seeds)
        if runs > MAX_RUNS:  # checked as it grows: 2 x 10^6 tasks in 94 KB are refused, not listed
            raise r.fail(f"papers[{k}]", f"the suite expands to more than {MAX_RUNS} runs (papers x scenes x seeds, "
                                         "each a reference and a pipeline run plus one per ablation); split it into "
                                         "several suites")
        papers.append(paper)
    counts = Counter(p.id for p in papers)
    repeated = next((i for i, n in counts.items() if n > 1), None)
    if repeated is not None:
        raise r.fail("papers", f"paper id {repeated!r} repeated")
    return Suite(name=str(data.get("name") or path.stem), path=path.resolve(), papers=tuple(papers),
                 description=str(data.get("description") or ""))
