"""Plan derivation: a paper (ingested, techniques detected, citations recovered) -> a plan the grammar accepts.

    doc = ingest(path)
    detections = detect_techniques(doc)
    graph = build_citation_graph(doc, detections)
    derived = derive_plan(doc, detections, graph)      # derived.plan validates; derived.holes lists gaps

1. The base is the reference plan (``method_configs/``) whose techniques best cover what the paper
   uses (detections, weighted by confidence) and what citation recovery took from cited work.
2. The detected terminals replace the base's where the grammar allows it (each substitution is
   checked; one the grammar refuses is reported in ``notes``, never forced).
3. The paper's hyperparameters replace the base's values: encoding frequencies, coarse/fine samples,
   learning rate (Adam, exponential decay to the paper's final rate when stated), ray batch size,
   iterations, hash table size, loss weights.
4. Every value carries evidence in ``plan["evidence"]`` (plan path -> quote with page/section);
   values kept from the base plan say so.
5. Paper-specific parts no card covers (its own equations) become ``plan["holes"]``: the production
   they would fill, its contract, the paper's text and equations, status "not implemented", and what
   stands in their place (the base's component, so the plan still trains).
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from typing import Any, Optional, Sequence

import yaml

from nerfify_ns.grammar import Grammar, check, load_grammar, validate
from nerfify_ns.knowledge.cards import Card, load_cards
from nerfify_ns.knowledge.citations import CitationGraph, build_citation_graph, find_spans, card_aliases, match_target
from nerfify_ns.knowledge.detect import Detection, detect_techniques, norm_latex
from nerfify_ns.knowledge.sentences import role_of_section, section_roles
from nerfify_ns.synthesis.resources import load_reference_plan

BASE_ORDER = ("vanilla-nerf", "mipnerf", "nerfacto", "instant-ngp", "tensorf", "kplanes-static")
GENERIC_CARDS = {"rgb_l2", "background_model", "mlp_backbone", "density_activation"}
FIELD = "model.field.MLPField"

# slot a card's terminal goes to (MLP fields), by terminal
TERMINAL_SLOTS = {
    "positional": f"{FIELD}.pos_encoding", "integrated_positional": f"{FIELD}.pos_encoding",
    "hash": f"{FIELD}.pos_encoding", "kplanes": f"{FIELD}.pos_encoding", "triplane": f"{FIELD}.pos_encoding",
    "sh": f"{FIELD}.dir_encoding", "frequency": f"{FIELD}.dir_encoding",
    "l2": "model.losses.rgb", "l1": "model.losses.rgb", "charbonnier": "model.losses.rgb",
    "distortion": "model.losses.distortion", "interlevel": "model.losses.interlevel",
    "plane_tv": "model.regularizers.plane_tv", "ray_entropy": "model.regularizers.ray_entropy",
    "density_sparsity": "model.regularizers.density_sparsity",
    "appearance_embedding": f"{FIELD}.appearance_embedding",
    "hierarchical": "model.sampler", "proposal": "model.sampler", "occupancy_grid": "model.sampler",
}
CHOICE_SLOTS = {f"{FIELD}.pos_encoding", f"{FIELD}.dir_encoding", "model.losses.rgb", "model.sampler"}

# what kind of part an uncovered equation is, from words in it and around it (first match wins)
HOLE_KINDS = (
    ("spatial_distortion", r"\bNDC\b|normali[sz]ed device|projective|ray space|contract|warp"),
    ("renderer", r"transmittance|composit|render|\bmedi(?:um|a)\b|scatter|backscatter|attenuat|\\int|∫|radiance along"),
    ("regularizer", r"regulari[sz]|penalt|smoothness|prior\b"),
    ("loss", r"\bloss\b|\\mathcal\{L\}|ℒ|\bMSE\b|objective|\bmin\b"),
    ("sampler", r"\bsampl|\bpdf\b|proposal|importance"),
    ("pos_encoding", r"encoding|\\gamma\(|γ\(|frequenc|fourier"),
    ("dir_encoding", r"spherical harmonic|view(?:ing)? direction"),
    ("backbone", r"."),
)
HOLE_SLOTS = {
    "spatial_distortion": (f"{FIELD}.spatial_distortion", "SpatialDistortion", "scene_contraction"),
    "renderer": ("model.renderer", "Model.renderer", "renderer"),
    "regularizer": ("model.regularizers", "Regularizers", None),
    "loss": ("model.losses.rgb", "RGBLoss", None),
    "sampler": ("model.sampler", "Sampler", None),
    "pos_encoding": (f"{FIELD}.pos_encoding", "PosEncoding", None),
    "dir_encoding": (f"{FIELD}.dir_encoding", "DirEncoding", None),
    "backbone": (f"{FIELD}.backbone", "MLPField.backbone", "mlp"),
    "rgb_head": (f"{FIELD}.rgb_head", "MLPField.rgb_head", "rgb_mlp"),
}
_MATHY = re.compile(r"\\(?:int|sum|frac|exp|label|sigma|mathbf|hat|left|right|prod)\b")


@dataclass
class Hole:
    """A paper-specific part no card covers: it is NOT implemented; the base's part stands in."""

    production: str
    slot: str
    contract: dict
    text: str
    equations: list[dict]
    status: str = "not implemented"
    stands_in: str = ""
    section: str = ""
    where: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class DerivedPlan:
    """The derived plan (``validate`` accepts it), its holes, the base chosen and why, and the evidence
    of every value (plan path -> {source: paper | citation | card | base, quote, section, page, line})."""

    plan: dict
    holes: list[dict]
    base: str
    base_reason: str
    evidence: dict
    detections: list[Detection] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    def paper_quotes(self) -> list[str]:
        return [e["quote"] for e in self.evidence.values() if e.get("quote")]

    def to_dict(self) -> dict:
        return {"plan": self.plan, "holes": self.holes, "base": self.base, "base_reason": self.base_reason,
                "evidence": self.evidence, "missing": self.missing,
                "detections": [d.to_dict() for d in self.detections]}


# ------------------------------------------------------------------------------------------ helpers
def _get(plan: dict, path: str) -> Any:
    node: Any = plan
    for key in path.split("."):
        if not isinstance(node, dict) or key not in node:
            return None
        node = node[key]
    return node


def _set(plan: dict, path: str, value: Any) -> None:
    keys = path.split(".")
    node = plan
    for key in keys[:-1]:
        node = node.setdefault(key, {})
    node[keys[-1]] = value


def _delete(plan: dict, path: str) -> None:
    keys = path.split(".")
    node = _get(plan, ".".join(keys[:-1])) if len(keys) > 1 else plan
    if isinstance(node, dict):
        node.pop(keys[-1], None)


def _where(page: Optional[int], line: Optional[int], section: str) -> str:
    loc = f"p.{page}" if page is not None else (f"l.{line}" if line is not None else "")
    return ", ".join(x for x in (loc, f"Sec. {section}" if section else "") if x)


def _short(text: str, limit: int = 240) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def slug(doc: Any) -> str:
    """A method name from the paper's title ("GH-NeRF: ..." -> "gh-nerf")."""
    title = (getattr(doc, "title", "") or "").strip()
    head = re.split(r"[:\u2013\u2014]| - ", title, maxsplit=1)[0].strip() if title else ""
    if not head or len(head) > 40:
        words = re.findall(r"[A-Za-z0-9]+", title)[:4]
        head = "-".join(words)
    name = re.sub(r"[^a-z0-9]+", "-", head.lower()).strip("-")
    if not name or not name[0].isalpha():
        name = f"paper-{name}" if name else "paper-method"
    name = name[:62].strip("-")
    return name if len(name) >= 2 else f"{name}-method"


@lru_cache(maxsize=16)
def _plan_cards(name: str) -> frozenset:
    g = load_grammar()
    d = validate(load_reference_plan(name), g)
    return frozenset(g.terminals[t].card for t in d.used.values() if g.terminals[t].card)


@lru_cache(maxsize=64)
def _card_extra(name: str) -> dict:
    """Fields of a card file beyond the Card dataclass (implements_equation, equation_slot)."""
    c = load_cards().get(name)
    if c is None or c.path is None:
        return {}
    return yaml.safe_load(c.path.read_text(encoding="utf-8")) or {}


# ------------------------------------------------------------------------------------------ derivation
class _Deriver:
    def __init__(self, doc: Any, detections: Sequence[Detection], graph: CitationGraph, grammar: Grammar):
        self.doc = doc
        self.g = grammar
        self.detections = list(detections)
        self.graph = graph
        self.res = graph.resolution if graph.resolution.needed else graph.resolve()
        self.cards = load_cards()
        self.evidence: dict[str, dict] = {}
        self.notes: list[str] = []
        self.used = {d.card: d for d in self.detections if d.used}
        self.roles = section_roles(doc)

    # ----------------------------------------------------------------- evidence
    def paper_evidence(self, path: str, quote: str, section: str, page, line, card: str = "",
                       source: str = "paper", what: str = "") -> None:
        self.evidence[path] = {"source": source, "quote": quote, "section": section, "page": page, "line": line,
                               "card": card, "what": what}

    def base_evidence(self, path: str, base: str) -> None:
        self.evidence.setdefault(path, {"source": "base", "quote": "", "section": "", "page": None, "line": None,
                                        "card": "", "what": f"from the base plan {base!r}, not stated in the paper"})

    # ----------------------------------------------------------------- candidates
    def candidates(self) -> dict[str, float]:
        """Cards the paper uses (confidence) or takes from cited work (less)."""
        weights: dict[str, float] = {}
        for name, d in self.used.items():
            weights[name] = max(weights.get(name, 0.0), d.confidence)
        for comp in self.res.taken:
            w = 0.6 if comp.relation in ("adopts", "follows", "detected", "requires") else 0.3
            weights[comp.card] = max(weights.get(comp.card, 0.0), w)
        return weights

    def choose_base(self) -> tuple[str, str]:
        cand = self.candidates()
        scores = []
        for name in BASE_ORDER:
            covered = self._plan_cards(name)
            score = sum(w for c, w in cand.items() if c in covered)
            extra = [c for c in covered if c not in cand and c not in GENERIC_CARDS]
            scores.append((score - 0.05 * len(extra), -BASE_ORDER.index(name), name, covered))
        scores.sort(reverse=True)
        best = scores[0]
        name, covered = best[2], best[3]
        if not cand:
            return name, (f"no technique of the paper was recovered; {name!r}, the plainest NeRF reference plan, "
                          "stands in for every part")
        hit = sorted(c for c in cand if c in covered)
        miss = sorted(c for c in cand if c not in covered)
        others = ", ".join(f"{s[2]} {s[0]:.2f}" for s in scores[1:4])
        return name, (f"{name!r} covers {len(hit)} of the {len(cand)} techniques found "
                      f"({', '.join(hit) or 'none'}){'; not covered: ' + ', '.join(miss) if miss else ''} "
                      f"(score {best[0]:.2f}; next: {others})")

    @staticmethod
    def _plan_cards(name: str) -> frozenset:
        return _plan_cards(name)

    # ----------------------------------------------------------------- substitutions
    def _card_quote(self, card: str) -> Optional[tuple[str, str, Any, Any, str]]:
        d = self.used.get(card)
        if d is not None:
            e = d.best()
            if e is not None:
                return e.quote, e.section, e.page, e.line, "paper"
        for comp in self.res.taken:
            if comp.card == card and comp.quote:
                return comp.quote, comp.section, comp.page, comp.line, "citation"
        return None

    def substitute(self, plan: dict) -> None:
        ordered = list(self.used) + [c.card for c in self.res.taken if c.card not in self.used]
        for card_name in dict.fromkeys(ordered):
            c = self.cards.get(card_name)
            if c is None:
                continue
            for terminal in c.terminals:
                slot = TERMINAL_SLOTS.get(terminal)
                if slot is None or terminal not in self.g.terminals:
                    continue
                if _get(plan, "model.field.MLPField") is None and slot.startswith(FIELD):
                    continue
                if terminal in ("frequency",) and _get(plan, f"{FIELD}.dir_encoding.sh") is not None:
                    continue
                self._try_terminal(plan, c, terminal, slot)

    def _try_terminal(self, plan: dict, c: Card, terminal: str, slot: str) -> None:
        current = _get(plan, slot)
        if slot in CHOICE_SLOTS:
            if isinstance(current, dict) and terminal in current:
                self._record_card(slot, c)
                return
            new_value = {terminal: self._params(c, terminal)}
        else:
            if current is not None:
                self._record_card(slot, c)
                return
            new_value = self._params(c, terminal)
        if slot in CHOICE_SLOTS and isinstance(current, dict):
            other = next(iter(current))
            if other in self.g.terminals and self.g.terminals[other].card in self.used and c.name not in self.used:
                return  # the paper's own choice beats a component recovered from citations
        trial = copy.deepcopy(plan)
        _set(trial, slot, new_value)
        problems = check(trial, self.g)
        if problems:
            self.notes.append(f"{c.name} ({terminal}) was found in the paper but is not used at {slot}: "
                              f"{problems[0].message} (the base's part stays)")
            return
        _set(plan, slot, new_value)
        self._record_card(slot, c)

    def _params(self, c: Card, terminal: str) -> dict:
        term = self.g.terminals[terminal]
        return {k: v for k, v in c.params_for(terminal).items() if k in term.params}

    def _record_card(self, slot: str, c: Card) -> None:
        q = self._card_quote(c.name)
        if q:
            quote, section, page, line, source = q
            self.paper_evidence(slot, quote, section, page, line, c.name, source,
                                f"{c.title} ({c.paper.title}, {c.equation.ref or 'card'})")
        else:
            self.evidence[slot] = {"source": "card", "quote": "", "section": "", "page": None, "line": None,
                                   "card": c.name, "what": f"{c.title}: recovered from cited work via the "
                                                           f"knowledge base ({c.paper.title})"}

    # ----------------------------------------------------------------- hyperparameters
    def _hp(self, name: str, qualifier: Optional[str] = None) -> Optional[Any]:
        """The paper's statement of hyperparameter ``name``: method sections first, then reading order."""
        rank = {"method": 0, "abstract": 1, "title": 1, "experiments": 2, "conclusion": 3}
        found = []
        for i, h in enumerate(getattr(self.doc, "hyperparameters", [])):
            if h.name != name or (qualifier is not None and h.qualifier != qualifier):
                continue
            role = role_of_section(self.doc, h.section)
            if role in ("prior", "ignore"):
                continue
            found.append((rank.get(role, 2), i, h))
        found.sort(key=lambda x: (x[0], x[1]))
        return found[0][2] if found else None

    def _apply(self, plan: dict, path: str, value: Any, h: Any, what: str) -> bool:
        trial = copy.deepcopy(plan)
        _set(trial, path, value)
        problems = check(trial, self.g)
        if problems:
            self.notes.append(f"the paper's {what} ({h.raw or h.value}) does not fit {path}: {problems[0].message}")
            return False
        _set(plan, path, value)
        self.paper_evidence(path, h.sentence, h.section, getattr(h.loc, "page", None), getattr(h.loc, "line", None),
                            "", "paper", what)
        return True

    def hyperparameters(self, plan: dict, holes_slots: set[str]) -> None:
        pos = _get(plan, f"{FIELD}.pos_encoding") or {}
        pos_t = next(iter(pos), None)
        # positional encoding frequencies
        for qual, slot, kinds in (("position", f"{FIELD}.pos_encoding", ("positional", "integrated_positional")),
                                  ("direction", f"{FIELD}.dir_encoding", ("frequency",))):
            enc = _get(plan, slot) or {}
            t = next(iter(enc), None)
            if t not in kinds:
                continue
            h = self._hp("num_frequencies", qual) or (self._hp("num_frequencies", "") if qual == "position" else None)
            if h is None or not isinstance(h.value, int):
                continue
            params = dict(enc[t])
            if params.get("num_frequencies") != h.value:
                params["num_frequencies"] = h.value
                params["max_freq_exp"] = float(max(h.value - 1, 1)) + float(params.get("min_freq_exp", 0.0))
            self._apply(plan, f"{slot}.{t}", params, h, f"number of frequencies L = {h.value} ({qual})")
        # hierarchical sampling
        if _get(plan, "model.sampler.hierarchical") is not None:
            for hp_name, param in (("num_coarse_samples", "num_coarse_samples"),
                                   ("num_fine_samples", "num_importance_samples")):
                h = self._hp(hp_name)
                if h is not None and isinstance(h.value, int):
                    self._apply(plan, f"model.sampler.hierarchical.{param}", h.value, h, f"{hp_name} = {h.value}")
            h = self._hp("lambda")
            if h is not None and re.search(r"coarse", h.sentence, re.IGNORECASE) and isinstance(h.value, (int, float)):
                self._apply(plan, "model.sampler.hierarchical.coarse_loss_weight", float(h.value), h,
                            f"coarse loss weight lambda = {h.value}")
        # hash grid
        if pos_t == "hash":
            h = self._hp("log2_hashmap_size")
            if h is None and (h2 := self._hp("hash_table_size")) is not None and isinstance(h2.value, (int, float)) \
                    and h2.value > 0:
                log2 = math.log2(h2.value)
                if log2.is_integer():
                    h2v = int(log2)
                    self._apply(plan, f"{FIELD}.pos_encoding.hash.log2_hashmap_size", h2v, h2, f"hash table size 2^{h2v}")
            elif h is not None:
                self._apply(plan, f"{FIELD}.pos_encoding.hash.log2_hashmap_size", int(h.value), h,
                            f"hash table size 2^{h.value}")
            for hp_name, param in (("num_levels", "num_levels"), ("features_per_level", "features_per_level"),
                                   ("min_resolution", "min_res"), ("max_resolution", "max_res")):
                h = self._hp(hp_name)
                if h is not None and isinstance(h.value, int):
                    self._apply(plan, f"{FIELD}.pos_encoding.hash.{param}", h.value, h, f"{hp_name} = {h.value}")
        # backbone width and depth (only when the paper's MLP is the plan's: not a hole)
        backbone = f"{FIELD}.backbone"
        if "mlp_backbone" in self.used and backbone not in holes_slots and _get(plan, backbone) is not None:
            h_layers, h_width = self._hp("num_layers"), self._hp("hidden_dim")
            if h_layers and h_width and h_layers.sentence == h_width.sentence:
                params = dict(_get(plan, backbone))
                params.update(num_layers=h_layers.value, layer_width=h_width.value)
                if params.get("skip_connections") and max(params["skip_connections"]) >= h_layers.value:
                    params["skip_connections"] = []
                self._apply(plan, backbone, params, h_layers, f"{h_layers.value} layers of {h_width.value} units")
        # loss weights
        for hp_name, path in (("lambda_dist", "model.losses.distortion.weight"),
                              ("lambda_distortion", "model.losses.distortion.weight"),
                              ("lambda_prop", "model.losses.interlevel.weight"),
                              ("lambda_interlevel", "model.losses.interlevel.weight"),
                              ("lambda_tv", "model.regularizers.plane_tv.weight")):
            h = self._hp(hp_name)
            if h is not None and _get(plan, path.rsplit(".", 1)[0]) is not None and isinstance(h.value, (int, float)):
                self._apply(plan, path, float(h.value), h, f"{hp_name} = {h.value}")
        # ray batch
        h = self._hp("batch_size")
        if h is not None and isinstance(h.value, int) and (h.unit or "rays") in ("rays", "pixels"):
            self._apply(plan, "datamanager.train_num_rays_per_batch", h.value, h, f"batch of {h.value} {h.unit or 'rays'}")
        # iterations
        h = self._hp("num_iterations")
        iterations = None
        if h is not None:
            value = max(h.value) if isinstance(h.value, list) else h.value
            if isinstance(value, (int, float)) and value >= 1:
                iterations = int(value)
                if self._apply(plan, "trainer.max_num_iterations", iterations, h, f"{iterations} iterations"):
                    if isinstance(h.value, list):
                        self.notes.append(f"the paper gives a range of iterations ({h.raw}); the plan trains for "
                                          f"the upper end, {iterations}")
        elif (e := self._hp("num_epochs")) is not None:
            self.notes.append(f"the paper states {e.raw} (epochs, not iterations); the base's iteration count is kept")
        # optimiser and schedule
        self.optimizer(plan, iterations)

    def optimizer(self, plan: dict, iterations: Optional[int]) -> None:
        h = self._hp("learning_rate")
        final = self._hp("learning_rate_final")
        eps = self._hp("adam_eps")
        if h is None or not isinstance(h.value, (int, float)):
            return
        groups = [g for g in (plan.get("optimizers") or {}) if g != "camera_opt"]
        sentence = h.sentence.lower()
        for group in groups:
            current = plan["optimizers"][group]
            kind = next(iter(current["optimizer"]))
            if re.search(r"\bradam\b", sentence):
                kind = "radam"
            elif re.search(r"\badam\b", sentence):
                kind = "adam"
            params = {"lr": float(h.value)}
            if kind == "adam":
                params["eps"] = float(eps.value) if eps is not None and eps.sentence == h.sentence else \
                    float(current["optimizer"].get(kind, {}).get("eps", 1e-15) if kind in current["optimizer"] else 1e-15)
            elif "eps" in current["optimizer"].get(kind, {}):
                params["eps"] = current["optimizer"][kind]["eps"]
            self._apply(plan, f"optimizers.{group}.optimizer", {kind: params}, h,
                        f"{kind} with learning rate {h.value}")
            if final is not None and isinstance(final.value, (int, float)) and final.value < h.value:
                steps = iterations or int(_get(plan, "trainer.max_num_iterations") or 200000)
                kind_s = "exponential_decay"
                if not re.search(r"exponential", final.sentence, re.IGNORECASE):
                    self.notes.append("the paper decays the learning rate to its final value without saying how; "
                                      "the plan decays it exponentially")
                self._apply(plan, f"optimizers.{group}.scheduler", {kind_s: {"lr_final": float(final.value),
                                                                            "max_steps": steps}}, final,
                            f"exponential decay of the learning rate to {final.value} over {steps} steps")

    # ----------------------------------------------------------------- holes
    def holes(self, plan: dict) -> list[Hole]:
        holes: list[Hole] = []
        taken = set(self.used) | {c.card for c in self.res.taken}
        doc = self.doc
        paragraphs = []  # (order, section, text, loc)
        for i, s in enumerate(doc.sections):
            for p in s.paragraphs:
                paragraphs.append((getattr(p.loc, "order", 0) or 0, s.heading, p.text, p.loc, self.roles[i]))
        equations = [e for e in getattr(doc, "equations", [])
                     if role_of_section(doc, e.section) == "method" and (e.latex.strip() or e.text.strip())]
        groups: dict[tuple[str, str], dict] = {}
        previous: Optional[tuple[str, str]] = None  # (section, kind) of the last uncovered equation
        for e in equations:
            context = self._eq_context(e, paragraphs)
            if self._covered(e, context, taken):
                previous = None
                continue
            kind = self._kind(f"{e.latex} {e.text}", strict=True)
            if kind is None:
                kind = previous[1] if previous and previous[0] == e.section else \
                    self._kind(" ".join([*context, e.section]))
            previous = (e.section, kind)
            key = (e.section, kind)
            grp = groups.setdefault(key, {"equations": [], "text": [], "section": e.section, "loc": e.loc})
            grp["equations"].append({"number": e.number, "latex": e.latex, "text": e.text,
                                     "where": _where(getattr(e.loc, "page", None), getattr(e.loc, "line", None),
                                                     e.section)})
            for t in context:
                if t not in grp["text"]:
                    grp["text"].append(t)
        if not equations:  # equations the converter left in the running text (e.g. an appendix PDF)
            by_section: dict[str, list] = {}
            for order, section, text, loc, role in paragraphs:
                if role == "method" and len(_MATHY.findall(text)) >= 2:
                    by_section.setdefault(section, []).append((text, loc))
            for section, items in by_section.items():
                whole = " ".join(t for _o, s_, t, _l, _r in paragraphs if s_ == section)
                kind = self._kind(whole + " " + section)
                grp = groups.setdefault((section, kind), {"equations": [], "text": [], "section": section,
                                                          "loc": items[0][1]})
                for text, loc in items:
                    label = re.search(r"\\label\s*\{\s*([^}]*)\}", text)
                    grp["equations"].append({"number": "", "latex": text.strip(), "text": "",
                                             "label": re.sub(r"\s+", "", label.group(1)) if label else "",
                                             "where": _where(getattr(loc, "page", None), getattr(loc, "line", None),
                                                             section)})
            for (section, kind), grp in groups.items():
                m = re.search(r"Eqs?\.?\s*\(?(\d+)\)?(?:\s*[-\u2013]\s*\(?(\d+)\)?)?", section)
                if m:
                    lo, hi = int(m.group(1)), int(m.group(2) or m.group(1))
                    grp["numbers"] = [str(n) for n in range(lo, hi + 1)] if hi - lo < 20 else [m.group(1)]
                grp["text"] = [t for _o, s, t, _l, _r in paragraphs if s == section and len(_MATHY.findall(t)) < 2]
        for (section, kind), grp in groups.items():
            holes.append(self._hole(plan, kind, grp))
        # a card found in the paper whose equation the grammar's terminal does not implement
        for name in self.used:
            extra = _card_extra(name)
            if extra.get("implements_equation") is False and extra.get("equation_slot"):
                d = self.used[name]
                eqs = [e for e in equations if any(ev.kind == "equation" and ev.quote in (e.latex.strip(), e.text.strip())
                                                   for ev in d.evidence)]
                eqs += [e for e in equations if e not in eqs and self._eq_mentions(e, paragraphs, name)]
                c = self.cards[name]
                slot = extra["equation_slot"]
                kind = next((k for k, v in HOLE_SLOTS.items() if v[0] == slot), "backbone")
                best = d.best()
                grp = {"equations": [{"number": e.number, "latex": e.latex, "text": e.text,
                                      "where": _where(getattr(e.loc, "page", None), getattr(e.loc, "line", None),
                                                      e.section)} for e in eqs],
                       "text": [best.quote] if best else [], "section": best.section if best else "",
                       "loc": None, "why": f"{c.title}: {c.equation.text}; the grammar's "
                                           f"{'/'.join(c.terminals)} terminal does not compute it"}
                holes.append(self._hole(plan, kind, grp))
        return holes

    def _eq_context(self, e: Any, paragraphs: list) -> list[str]:
        """The two meaningful paragraphs before an equation (nearest first) and the one after it."""
        order = getattr(e.loc, "order", 0) or 0
        meaningful = [p for p in paragraphs if p[1] == e.section and len(re.findall(r"[A-Za-z]", p[2])) >= 25]
        before = sorted((p for p in meaningful if p[0] < order), key=lambda p: -p[0])[:2]
        after = sorted((p for p in meaningful if p[0] > order), key=lambda p: p[0])[:1]
        return [p[2] for p in before] + [p[2] for p in after]

    def _eq_mentions(self, e: Any, paragraphs: list, card: str) -> bool:
        return any(any(v == card for _, _, (v, _a) in find_spans(t, card_aliases())) for t in self._eq_context(e, paragraphs)[:1])

    def _covered(self, e: Any, context: list[str], taken: set[str]) -> bool:
        """Whether a card the plan uses covers equation ``e`` (its fragments, or its name in the
        equation or in the paragraphs introducing it)."""
        latex, text = norm_latex(e.latex), norm_latex(e.text)
        for c in self.cards.values():
            if c.name not in taken:
                continue
            for frag in c.signals.equations:
                nf = norm_latex(frag)
                if len(nf) >= 4 and ((latex and nf in latex) or ("\\" not in frag and text and nf.lower() in text.lower())):
                    return True
        if find_spans(e.text or "", card_aliases()):
            return True
        near = context[0] if context else ""
        for _, _, (name, _alias) in find_spans(near, card_aliases()):
            if name in taken:
                return True
        low = near.lower()
        for name in taken:
            c = self.cards.get(name)
            if c and any(ph in low for ph in c.signals.phrases):
                return True
        return False

    @staticmethod
    def _kind(text: str, strict: bool = False) -> Optional[str]:
        for kind, pattern in HOLE_KINDS:
            if strict and kind == "backbone":
                return None
            if re.search(pattern, text, re.IGNORECASE if kind != "loss" or not strict else 0):
                return kind
        return "backbone"

    def _hole(self, plan: dict, kind: str, grp: dict) -> Hole:
        slot, production, fallback = HOLE_SLOTS[kind]
        current = _get(plan, slot)
        terminal = None
        if isinstance(current, dict) and slot in CHOICE_SLOTS | {f"{FIELD}.spatial_distortion"}:
            terminal = next(iter(current), None)
        elif current is not None:
            terminal = slot.rsplit(".", 1)[-1]
            terminal = {"backbone": "mlp", "rgb_head": "rgb_mlp", "renderer": "renderer"}.get(terminal, terminal)
        if terminal is None and slot == "model.losses.rgb":
            terminal = next(iter(_get(plan, slot) or {"l2": {}}))
        term = self.g.terminals.get(terminal or fallback or "")
        contract = dict(term.contract) if term is not None else {}
        if term is not None and not contract:
            contract = {"doc": term.doc}
        if current is None:
            stands_in = f"nothing: the plan has no {slot} (the base's behaviour without it)"
        else:
            stands_in = f"{terminal} ({term.doc if term else ''}) from the base plan, with {current!r}"
        text = " ".join(_short(t, 600) for t in grp["text"][:4])
        if grp.get("why"):
            text = f"{grp['why']}. Paper: {text}"
        equations = grp["equations"]
        if grp.get("numbers"):
            equations = [{"number": n, "latex": "", "text": "", "where": grp["section"]} for n in grp["numbers"]] + equations
        loc = grp.get("loc")
        return Hole(production=production, slot=slot, contract=_plainify(contract), text=text,
                    equations=[{k: _short(str(v), 400) for k, v in eq.items()} for eq in equations],
                    status="not implemented", stands_in=stands_in, section=grp["section"],
                    where=_where(getattr(loc, "page", None), getattr(loc, "line", None), grp["section"]))


def _plainify(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _plainify(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plainify(v) for v in obj]
    return obj


def derive_plan(doc: Any, detections: Optional[Sequence[Detection]] = None,
                graph: Optional[CitationGraph] = None, grammar: Optional[Grammar] = None) -> DerivedPlan:
    """The plan of ``doc`` (see the module docstring); ``validate(result.plan)`` accepts it."""
    g = grammar or load_grammar()
    detections = list(detect_techniques(doc) if detections is None else detections)
    graph = graph if graph is not None else build_citation_graph(doc, detections)
    d = _Deriver(doc, detections, graph, g)
    base, reason = d.choose_base()
    plan = copy.deepcopy(load_reference_plan(base))
    for key in ("evidence", "notes", "holes", "pruned"):
        plan.pop(key, None)
    known = match_target(doc)
    title = (getattr(doc, "title", "") or "").strip()
    plan["method"] = slug(doc)
    plan["paper"] = {"title": title or None, "year": known.year if known else None,
                     "arxiv": known.arxiv if known else None}
    d.substitute(plan)
    holes = d.holes(plan)
    d.hyperparameters(plan, {h.slot for h in holes})
    # every slot the paper did not set keeps the base's value, and says so
    derivation = validate(plan, g)
    for path in derivation.used:
        slot = path.rsplit(".", 1)[0] if path.count(".") >= 2 and path.split(".")[-2] not in ("losses", "regularizers") \
            else path
        if slot in ("base",):
            continue
        if not any(k == slot or k.startswith(slot + ".") or slot.startswith(k + ".") for k in d.evidence):
            d.base_evidence(slot, base)
    d.base_evidence("base", base)
    missing = list(d.res.missing)
    plan["description"] = (f"{title or plan['method']}: derived from the paper by nerfify (base {base}; "
                           f"{len(holes)} part(s) of the paper not implemented).")
    plan["holes"] = [h.to_dict() for h in holes]
    notes = list(d.notes)
    if missing:
        notes.append("not recovered from the paper or its citations (the base's parts stand in): "
                     + ", ".join(missing))
    notes.append(f"base: {reason}")
    plan["notes"] = notes
    plan["evidence"] = {path: _evidence_line(e) for path, e in sorted(d.evidence.items())}
    validate(plan, g)
    return DerivedPlan(plan=plan, holes=plan["holes"], base=base, base_reason=reason, evidence=d.evidence,
                       detections=detections, missing=missing)


def _evidence_line(e: dict) -> str:
    if e["source"] == "base":
        return e["what"]
    if not e.get("quote"):
        return e.get("what", "")
    where = _where(e.get("page"), e.get("line"), e.get("section", ""))
    label = {"paper": "", "citation": "citation: "}.get(e["source"], "")
    return f"{label}{where}: \"{_short(e['quote'])}\"" + (f" ({e['what']})" if e.get("what") else "")


def plan_from_paper(doc: Any) -> DerivedPlan:
    """Detect, recover citations and derive, in one call."""
    detections = detect_techniques(doc)
    return derive_plan(doc, detections, build_citation_graph(doc, detections))
