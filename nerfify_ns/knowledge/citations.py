"""Compositional citation recovery: what a paper takes from the works it cites, followed transitively.

    uses = find_citation_uses(doc, kb)                  # "we use the proposal network of [7]" ...
    graph = build_citation_graph(doc, detections, kb=kb)  # networkx graph + resolution of the productions
    graph.resolution.filled / .missing              # production -> component taken, and what is missing
    graph.to_json(); graph.draw("deps.png")

Sentences are matched against the patterns of ``citation_patterns.yaml`` (data, not code). A citation
target is a marker ([7], [3, 5], [barron2022mip]) or a known paper named by an alias. References are
matched to known papers (``papers.yaml``) by arXiv id, then normalised title. The graph's nodes are the
target paper, the cited papers, and the known papers reached through ``builds_on`` (papers.yaml);
edges are labelled with the relation and the components (cards) taken. Resolution stops when every
needed production is filled, and reports the rest as missing.

``kb`` is the ``KnowledgeBase`` (cards, papers, patterns) to read; None means the default one.
``doc`` is any object shaped like ``nerfify_ns.paper.Document`` (the knowledge package does not
import the paper package).
"""

from __future__ import annotations

import json
import re
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import networkx as nx

from nerfify_ns.knowledge.cards import Card
from nerfify_ns.knowledge.kb import AliasTable, KnowledgeBase, first_word
from nerfify_ns.knowledge.papers import PAPERS_FILE, KnownPaper, read_papers
from nerfify_ns.knowledge.patterns import PATTERNS_FILE, CitationPattern, PatternSet, read_patterns
from nerfify_ns.knowledge.sentences import sentences
from nerfify_ns.knowledge.text import longest_non_overlapping

__all__ = ["TARGET", "CitationPattern", "PatternSet", "CitationUse", "Component", "Resolution", "CitationGraph",
           "load_patterns", "builds_on", "productions_of", "match_reference", "match_target", "first_word",
           "card_aliases", "find_spans", "find_citation_uses", "build_citation_graph", "PAPERS_FILE", "PATTERNS_FILE"]

TARGET = "target"
_TOKEN = "\u27e6{}\u27e7"
_MARKER = re.compile(r"\[([^\[\]]{1,200})\]")
_APPENDIX = re.compile(r"\s*(?:[-:(]\s*)?(?:appendix|appendices|supplementary(?: material)?|"
                       r"supplemental(?: material)?)\)?\s*$", re.IGNORECASE)


# ------------------------------------------------------------------------------------------ data
def load_patterns(path: str | None = None) -> PatternSet:
    """The compositional citation patterns: the default knowledge base's, or those of the file ``path``."""
    return read_patterns(path) if path is not None else KnowledgeBase.default().patterns


def builds_on(path: str | None = None) -> dict[str, tuple[str, ...]]:
    """``builds_on`` of every known paper (papers.yaml): the known papers its method derives from."""
    if path is not None:
        return {k: p.builds_on for k, p in read_papers(path).items()}
    return KnowledgeBase.default().builds_on


def productions_of(c: Card, kb: KnowledgeBase | None = None) -> list[str]:
    """The card productions a card fills (its own, plus those of its extra terminals)."""
    return KnowledgeBase.of(kb).productions_of(c)


def match_reference(ref: Any, kb: KnowledgeBase | None = None) -> KnownPaper | None:
    """The known paper a ``Reference`` points to: arXiv id, title, then a known title inside the raw entry."""
    return KnowledgeBase.of(kb).match_reference(ref)


def match_target(doc: Any, kb: KnowledgeBase | None = None) -> KnownPaper | None:
    """The known paper the document itself is, if any (an appendix or supplement counts as its paper)."""
    title = _APPENDIX.sub("", getattr(doc, "title", "") or "").strip()
    return KnowledgeBase.of(kb).match_paper(title=title) if title else None


# ------------------------------------------------------------------------------------------ aliases
def card_aliases(kb: KnowledgeBase | None = None) -> AliasTable:
    """(prefilter word, pattern, (card, alias)) for every card alias."""
    return KnowledgeBase.of(kb).card_aliases


def find_spans(text: str, table: Sequence[tuple[str, re.Pattern, object]]) -> list[tuple[int, int, object]]:
    """(start, end, value) of every alias of ``table`` in ``text`` (a cheap word prefilter first)."""
    low = text.lower()
    return [(m.start(), m.end(), value) for word, pat, value in table if word in low for m in pat.finditer(text)]


# ------------------------------------------------------------------------------------------ uses
@dataclass
class CitationUse:
    """A sentence in which the paper takes something from a cited work."""

    sentence: str
    section: str
    page: int | None
    line: int | None
    relation: str                 # adopts | follows | builds_on
    pattern: str
    keys: list[str]               # reference keys cited
    papers: list[str]             # known papers they are
    components: list[str]         # cards named as taken ([] = whatever the paper provides)
    role: str = "method"

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class _Target:
    keys: list[str]
    papers: list[str]
    start: int
    end: int


def _marker_keys(inner: str, ref_keys: set[str]) -> list[str] | None:
    parts = [p.strip() for p in re.split(r"[,;]", inner) if p.strip()]
    keys: list[str] = []
    for p in parts:
        m = re.fullmatch(r"(\d+)\s*[-\u2013]\s*(\d+)", p)
        if m and int(m.group(2)) - int(m.group(1)) < 30:
            keys.extend(str(i) for i in range(int(m.group(1)), int(m.group(2)) + 1))
        else:
            keys.append(p)
    if not keys:
        return None
    if ref_keys:
        return keys if all(k in ref_keys for k in keys) else None
    return keys if all(re.fullmatch(r"[1-9]\d{0,3}", k) for k in keys) else None


def _targets(sentence: str, ref_keys: set[str], ref_papers: dict[str, str | None],
             kb: KnowledgeBase) -> list[_Target]:
    """The citation targets of ``sentence``: markers ([7], [3, 5], [key]) and known papers named by an alias."""
    out: list[_Target] = []
    for m in _MARKER.finditer(sentence):
        keys = _marker_keys(m.group(1), ref_keys)
        if keys:
            out.append(_Target(keys, [p for k in keys if (p := ref_papers.get(k))], m.start(), m.end()))
    spans = find_spans(sentence, kb.paper_aliases)
    spans += [(m.start(), m.end(), key) for key, pat in kb.patterns.bare_names for m in pat.finditer(sentence)]
    for start, end, key in longest_non_overlapping(spans):
        if all(end <= t.start or start >= t.end for t in out):
            out.append(_Target([], [key], start, end))
    return sorted(out, key=lambda t: t.start)


def cites_earlier_work(sentence: str, kb: KnowledgeBase | None = None) -> bool:
    """Whether ``sentence`` cites earlier work: a numbered reference marker ([7], [3, 5]) or a known paper named
    (an alias or a bare name such as "NeRF")."""
    return bool(_targets(sentence, set(), {}, KnowledgeBase.of(kb)))


def _tokenize(sentence: str, targets: list[_Target]) -> str:
    """The sentence with each target replaced by a token (its index in ``targets``)."""
    parts: list[str] = []
    pos = 0
    for i, t in enumerate(targets):
        parts.append(sentence[pos:t.start])
        parts.append(_TOKEN.format(i))
        pos = t.end
    parts.append(sentence[pos:])
    return "".join(parts)


def _card_hits(text: str, kb: KnowledgeBase) -> list[str]:
    """Card names whose aliases occur in ``text`` (longest alias wins), in order of first occurrence."""
    seen: list[str] = []
    for _, _, (name, _alias) in longest_non_overlapping(find_spans(text, kb.card_aliases)):
        if name not in seen:
            seen.append(name)
    return seen


def find_citation_uses(doc: Any, kb: KnowledgeBase | None = None) -> list[CitationUse]:
    """Every sentence where the paper takes something from a cited work (see citation_patterns.yaml).

    Sentences about someone else's work (related work, "X et al. [3] proposed ..."), comparisons with
    baselines and contrast clauses ("unlike [4]") are not uses."""
    kb = KnowledgeBase.of(kb)
    papers = kb.papers
    refs = {r.key: r for r in getattr(doc, "references", [])}
    ref_papers = {k: (p.key if (p := kb.match_reference(r)) else None) for k, r in refs.items()}
    target = match_target(doc, kb)
    uses: list[CitationUse] = []
    for unit in sentences(doc, kb.rules):
        if unit.role in ("title", "ignore"):
            continue
        ctx = unit.context
        targets = _targets(unit.text, set(refs), ref_papers, kb)
        if not targets:
            continue
        if unit.role == "prior" and not ctx.own:
            continue
        if ctx.prior and not ctx.usage:
            continue
        if unit.role == "experiments" and ctx.comparison and not ctx.usage:
            continue
        tokenized = _tokenize(unit.text, targets)
        taken: set[tuple[int, str]] = set()
        for pattern in kb.patterns.patterns:
            for m in pattern.regex.finditer(tokenized):
                idx = [int(i) for i in re.findall(r"\u27e6(\d+)\u27e7", m.group("cite"))]
                idx = [i for i in idx if not ctx.in_contrast(targets[i].start, targets[i].end)]
                idx = [i for i in idx if (i, pattern.relation) not in taken]
                if not idx:
                    continue
                keys = [k for i in idx for k in targets[i].keys]
                cited = list(dict.fromkeys(p for i in idx for p in targets[i].papers
                                           if not (target and p == target.key)))
                if not keys and not cited:
                    continue
                groups = m.groupdict()
                if groups.get("component") is not None:
                    named = _card_hits(re.sub(r"\u27e6\d+\u27e7", " ", groups["component"]), kb)
                else:
                    provided = {c for p in cited for c in papers[p].provides}
                    named = [c for c in _card_hits(re.sub(r"\u27e6\d+\u27e7", " ", tokenized), kb) if c in provided]
                if pattern.relation == "adopts" and not named:
                    continue
                taken.update((i, pattern.relation) for i in idx)
                taken.update((i, "follows") for i in idx)
                uses.append(CitationUse(sentence=unit.text, section=unit.section, page=unit.page, line=unit.line,
                                        relation=pattern.relation, pattern=pattern.name, keys=keys, papers=cited,
                                        components=named, role=unit.role))
    return uses


# ------------------------------------------------------------------------------------------ graph
@dataclass
class Component:
    """A component (card) filling a production, and where it was taken from."""

    card: str
    production: str
    paper: str                  # known paper key it comes from, or "target" (the paper itself)
    path: list[str]             # graph nodes from the target to that paper
    relation: str               # detected | adopts | follows | builds_on | registry
    quote: str = ""             # the sentence that says so ("" when it comes from the registry)
    section: str = ""
    page: int | None = None
    line: int | None = None

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Resolution:
    """Which component fills each needed production, every component taken, and what is missing."""

    needed: list[str]
    filled: dict[str, Component] = field(default_factory=dict)
    taken: list[Component] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    def cards(self) -> list[str]:
        return list(dict.fromkeys(c.card for c in self.taken))

    def to_dict(self) -> dict:
        return {"needed": list(self.needed), "filled": {k: v.to_dict() for k, v in self.filled.items()},
                "taken": [c.to_dict() for c in self.taken], "missing": list(self.missing)}


class CitationGraph:
    """The target paper's dependency graph (networkx DiGraph, edges target -> dependency)."""

    def __init__(self, graph: nx.DiGraph, uses: list[CitationUse], target_paper: str | None,
                 direct: list[tuple[str, Any]], kb: KnowledgeBase | None = None):
        self.kb = KnowledgeBase.of(kb)
        self.graph = graph
        self.uses = uses
        self.target_paper = target_paper
        self._direct = direct
        self.resolution = Resolution(needed=[])

    # --------------------------------------------------------------------- queries
    def dependencies(self) -> list[str]:
        """Known papers the target takes something from directly (in order of first use)."""
        return [v for _, v, d in self.graph.out_edges(TARGET, data=True) if d.get("relation") != "cites"]

    def transitive(self) -> list[str]:
        return [n for n, d in self.graph.nodes(data=True) if d.get("kind") == "transitive"]

    def resolve(self, needed: Iterable[str] | None = None) -> Resolution:
        """Fill every needed production from the paper and its dependencies, following ``builds_on``
        transitively (breadth first); what no paper reached provides is reported missing."""
        kb = self.kb
        needed = list(needed if needed is not None else kb.patterns.needed_productions)
        cards = kb.cards
        papers = kb.papers
        res = Resolution(needed=needed)
        seen: set[str] = set()

        def take(card_name: str, paper: str, path: list[str], relation: str, quote: str = "",
                 section: str = "", page=None, line=None, only_missing: bool = False) -> bool:
            c = cards.get(card_name)
            if c is None:
                return False
            prods = kb.productions_of(c)
            if only_missing and not any(p in needed and p not in res.filled for p in prods):
                return False
            if card_name in seen:
                return False
            seen.add(card_name)
            for prod in prods:
                comp = Component(card_name, prod, paper, path, relation, quote, section, page, line)
                if prod in needed and prod not in res.filled:
                    res.filled[prod] = comp
            res.taken.append(Component(card_name, prods[0], paper, path, relation, quote, section, page, line))
            for req in c.requires:  # duties: a proposal sampler brings its interlevel loss
                take(req, paper, path, "requires", quote, section, page, line)
            return True

        # 1. components the paper names as taken from a cited work
        for u in self.uses:
            for card_name in u.components:
                paper = next((p for p in u.papers if card_name in papers[p].provides),
                             u.papers[0] if u.papers else TARGET)
                path = [TARGET] if paper == TARGET else [TARGET, paper]
                take(card_name, paper, path, u.relation, u.sentence, u.section, u.page, u.line)
        # 2. techniques the paper itself is detected to use
        for card_name, ev in self._direct:
            c = cards.get(card_name)
            source = kb.card_source(c) if c else None
            paper = TARGET if source is None or source == self.target_paper else source
            path = [TARGET] if paper == TARGET else [TARGET, paper]
            take(card_name, paper, path, "detected", getattr(ev, "quote", ""), getattr(ev, "section", ""),
                 getattr(ev, "page", None), getattr(ev, "line", None))
        # 3. what the works the paper follows or builds on as a whole provide (and the paper itself, when
        #    the registry knows it), then the papers those build on (papers.yaml builds_on), breadth first.
        #    A work only named for one component ("the proposal sampler of [3]") gives that component.
        queue: deque[tuple[str, list[str], str, CitationUse | None]] = deque()
        for u in self.uses:
            if not u.components:
                for p in u.papers:
                    queue.append((p, [TARGET, p], u.relation, u))
        if self.target_paper:
            queue.append((self.target_paper, [TARGET], "registry", None))
        visited: set[str] = set()
        while queue and any(p not in res.filled for p in needed):
            key, path, relation, use = queue.popleft()
            if key in visited or key not in papers:
                continue
            visited.add(key)
            own = path == [TARGET]
            for card_name in papers[key].provides:
                take(card_name, TARGET if own else key, path, relation if len(path) <= 2 else "registry",
                     use.sentence if use else "", use.section if use else "",
                     use.page if use else None, use.line if use else None, only_missing=True)
            if own:  # what the registry says the paper itself builds on is not in the input: not followed
                continue
            for dep in papers[key].builds_on:
                queue.append((dep, [*path, dep], "registry", None))
        res.missing = [p for p in needed if p not in res.filled]
        self.resolution = res
        self._label(res)
        return res

    def _label(self, res: Resolution) -> None:
        """Write the components taken onto the graph (nodes of transitive papers added on the way)."""
        g = self.graph
        for _u, _v, d in g.edges(data=True):
            d["components"] = list(d.get("explicit", []))
        for comp in res.taken:
            if comp.paper == TARGET:
                continue
            path = comp.path
            for a, b in zip(path, path[1:], strict=False):
                if b not in g:
                    p = self.kb.papers.get(b)
                    g.add_node(b, kind="transitive", title=p.title if p else b, year=p.year if p else None,
                               arxiv=p.arxiv if p else None, provides=list(p.provides) if p else [])
                if not g.has_edge(a, b):
                    g.add_edge(a, b, relation="builds_on (registry)" if a != TARGET else comp.relation,
                               components=[], quotes=[], keys=[], explicit=[])
                elif g.edges[a, b].get("relation") == "cites":
                    g.edges[a, b]["relation"] = comp.relation
            last = g.edges[path[-2], path[-1]]
            if comp.card not in last["components"]:
                last["components"].append(comp.card)

    # --------------------------------------------------------------------- output
    def to_dict(self) -> dict:
        data = nx.node_link_data(self.graph, edges="links")
        return {"graph": _plain(data), "resolution": self.resolution.to_dict(),
                "uses": [u.to_dict() for u in self.uses]}

    def to_json(self, indent: int = 2) -> str:
        """Node-link JSON of the graph, with the resolution and the citation uses."""
        return json.dumps(self.to_dict(), indent=indent, ensure_ascii=False)

    def draw(self, png_path: Path | str) -> Path:
        """A K-Planes-style figure: the target paper, its direct and transitive dependencies, and the
        components taken from each (headless, matplotlib's Agg backend)."""
        import matplotlib

        matplotlib.use("Agg", force=True)
        import matplotlib.pyplot as plt

        g = self.graph
        deps = [n for n in nx.descendants(g, TARGET)
                if any(g.edges[e].get("components") or g.edges[e].get("relation") != "cites"
                       for e in g.in_edges(n))]
        depth = {TARGET: 0}
        for n in nx.bfs_tree(g, TARGET):
            if n != TARGET and n in deps:
                depth[n] = min(depth.get(p, 99) for p in g.predecessors(n) if p in depth or p == TARGET) + 1
        columns: dict[int, list[str]] = {}
        for n, d in depth.items():
            columns.setdefault(d, []).append(n)
        pos = {}
        for d, nodes in columns.items():
            for i, n in enumerate(sorted(nodes, key=lambda n: str(g.nodes[n].get("title")))):
                pos[n] = (d * 4.0, -(i - (len(nodes) - 1) / 2) * 1.6)
        height = max(3.0, 1.2 * max(len(v) for v in columns.values()) + 1.5)
        fig, ax = plt.subplots(figsize=(4.2 * len(columns) + 2, height))
        colors = {0: "#f6c85f", 1: "#9dd9d2", 2: "#c3b1e1"}
        for (a, b, d) in g.edges(data=True):
            if a in pos and b in pos:
                (x0, y0), (x1, y1) = pos[a], pos[b]
                ax.annotate("", xy=(x1 - 1.1, y1), xytext=(x0 + 1.1, y0),
                            arrowprops=dict(arrowstyle="-|>", color="#555", lw=1.2))
                label = d.get("relation", "")
                if d.get("components"):
                    label += ":\n" + "\n".join(d["components"])
                ax.text((x0 + x1) / 2, (y0 + y1) / 2 + 0.15, label, ha="center", va="bottom", fontsize=7,
                        color="#333")
        for n, (x, y) in pos.items():
            title = str(g.nodes[n].get("title") or n)
            short = title if len(title) <= 34 else title[:32] + "..."
            ax.text(x, y, f"{n if n != TARGET else 'this paper'}\n{short}", ha="center", va="center", fontsize=7,
                    bbox=dict(boxstyle="round,pad=0.4", fc=colors.get(min(depth[n], 2)), ec="#444"))
        missing = self.resolution.missing
        ax.set_title("Components taken from cited work" + (f" (missing: {', '.join(missing)})" if missing else ""),
                     fontsize=9)
        ax.set_xlim(-2.2, 4.0 * max(columns) + 2.2)
        ax.set_ylim(-height / 2 - 0.5, height / 2 + 0.5)
        ax.axis("off")
        out = Path(png_path)
        out.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110, bbox_inches="tight")
        plt.close(fig)
        return out


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple | set):
        return [_plain(v) for v in obj]
    return obj


def build_citation_graph(doc: Any, detections: Sequence[Any] = (),
                         needed: Iterable[str] | None = None, kb: KnowledgeBase | None = None,
                         follow: bool = True) -> CitationGraph:
    """The target paper's citation graph, resolved for ``needed`` productions (default: a field, a
    sampler, a renderer and a loss; see citation_patterns.yaml).

    ``detections`` are ``nerfify_ns.knowledge.detect.Detection`` objects; those used count as the
    paper's own components (their card's source paper becomes a dependency). ``follow=False`` (the ablation
    ``no-citations``): the references and citing sentences are not read and no paper is followed, so only the
    techniques detected in the paper's own text fill productions."""
    kb = KnowledgeBase.of(kb)
    papers = kb.papers
    target = match_target(doc, kb) if follow else None
    g = nx.DiGraph()
    g.add_node(TARGET, kind="target", title=getattr(doc, "title", "") or "", known=target.key if target else None,
               registry_builds_on=list(target.builds_on) if target else [])
    refs = list(getattr(doc, "references", [])) if follow else []
    for r in refs:
        p = kb.match_reference(r)
        node = p.key if p else f"ref:{r.key}"
        if node == (target.key if target else None):
            continue
        if node not in g:
            g.add_node(node, kind="reference" if p else "unmatched", title=p.title if p else (r.title or r.raw[:80]),
                       year=p.year if p else r.year, arxiv=p.arxiv if p else (r.arxiv or None),
                       provides=list(p.provides) if p else [], keys=[])
        g.nodes[node].setdefault("keys", []).append(r.key)
        if not g.has_edge(TARGET, node):
            g.add_edge(TARGET, node, relation="cites", components=[], quotes=[], keys=[r.key], explicit=[])
    uses = find_citation_uses(doc, kb) if follow else []
    strength = {"cites": 0, "follows": 1, "builds_on": 2, "adopts": 3}
    for u in uses:
        for p in u.papers:
            if p not in g:
                kp = papers[p]
                g.add_node(p, kind="reference", title=kp.title, year=kp.year, arxiv=kp.arxiv,
                           provides=list(kp.provides), keys=[])
            if not g.has_edge(TARGET, p):
                g.add_edge(TARGET, p, relation=u.relation, components=[], quotes=[], keys=[], explicit=[])
            e = g.edges[TARGET, p]
            if strength.get(u.relation, 0) > strength.get(e["relation"], 0):
                e["relation"] = u.relation
            e["quotes"].append(u.sentence)
            for c in u.components:
                if c in papers[p].provides or len(u.papers) == 1:
                    if c not in e["explicit"]:
                        e["explicit"].append(c)
    direct = []
    for d in detections:
        if getattr(d, "used", False):
            ev = next((e for e in d.evidence if getattr(e, "usage", False)), d.evidence[0] if d.evidence else None)
            direct.append((d.card, ev))
    graph = CitationGraph(g, uses, target.key if target else None, direct, kb)
    for card_name, _ in direct:
        c = kb.cards.get(card_name)
        src = kb.card_source(c) if c else None
        if src and src != graph.target_paper and src not in g:
            kp = papers[src]
            g.add_node(src, kind="technique", title=kp.title, year=kp.year, arxiv=kp.arxiv,
                       provides=list(kp.provides), keys=[])
    graph.resolve(needed)
    return graph
