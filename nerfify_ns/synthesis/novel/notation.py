"""What a paper's symbols stand for: the shared notation table (``notation.yaml``), the knowledge base's cards,
and the paper's own words.

    notation = Notation.load()
    notation.table_role(symbol)                  # 'density' for sigma_i, 'target_colour' for C^*, None
    words = PaperWords.read(doc)                 # the paper's definitions, stated shapes and sizes
    words.definition("h_Delta")                  # Definition(role='hidden', quote=..., where=...) or None
    words.named("h_Delta")                       # whether the paper's text names the symbol at all

Nothing paper-specific is in the table: a paper's symbols get their meaning from its own sentences
("where W_gamma and b_gamma are the pre-modulation weight matrix and bias", "the memory is concatenated
with the camera 3D coordinates", "Psi in R^{z x h}, where z = 8,192"), read here by patterns over any paper.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns.equations import ParseFailure, parse_expression
from nerfify_ns.equations.ir import BinOp, Neg, Number, Symbol, walk
from nerfify_ns.equations.mathsym import GREEK
from nerfify_ns.knowledge.cards import card_notation

NOTATION_FILE = Path(__file__).resolve().parent / "notation.yaml"
_GREEK_NAMES = {u: tex.lstrip("\\") for u, tex in GREEK.items()}
_GREEK_NAMES.update({"ϵ": "epsilon", "ε": "epsilon", "ϕ": "phi", "φ": "phi"})
_GREEK_CHARS = "".join(_GREEK_NAMES)


@dataclass(frozen=True)
class Role:
    """A Nerfstudio quantity (``notation.yaml``: roles)."""

    name: str
    kind: str
    features: tuple = ()
    range: tuple = (None, None)
    doc: str = ""
    basis: str = ""
    nerfstudio: str = ""
    composite_of: str = ""
    derived: tuple = ()    # (source role, channel weights): a standard formula over another role's channels


@dataclass
class Definition:
    """A symbol's meaning and where it comes from: ``source`` table | card | paper | correction."""

    role: str
    source: str
    phrase: str = ""
    quote: str = ""
    where: str = ""

    def evidence(self) -> str:
        if self.source == "table":
            return f"shared notation table: {self.phrase}"
        if self.source == "card":
            return f"card {self.phrase}"
        where = f"{self.where}: " if self.where else ""
        return f"{where}\"{_short(self.quote)}\"" if self.quote else self.phrase


def _describe(err: BaseException) -> str:
    message = " ".join(str(err).split())[:200]
    return f"{type(err).__name__}: {message}" if message else type(err).__name__


def _short(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


class Notation:
    """The shared notation table (``notation.yaml``)."""

    def __init__(self, data: dict):
        self.roles = {name: Role(name, r["kind"], tuple(r.get("features") or ()), tuple(r.get("range") or (None, None)),
                                 r.get("doc", ""), r.get("basis", ""), r.get("nerfstudio", ""),
                                 r.get("composite_of", ""),
                                 (r["derived"]["from"], tuple(float(v) for v in r["derived"]["weights"]))
                                 if r.get("derived") else ())
                      for name, r in data["roles"].items()}
        self.symbols: dict[str, dict] = data["symbols"]
        self.variants: list[dict] = data.get("variants") or []
        self.phrases = [(re.compile(p["pattern"], re.I), p["role"]) for p in data.get("phrases") or []]
        self.bases: dict[str, dict] = data.get("bases") or {}
        self.cards: dict[str, dict] = {**card_notation(), **(data.get("cards") or {})}
        for name, entry in self.symbols.items():
            if entry["role"] not in self.roles:
                raise ValueError(f"notation.yaml: symbol {name} has the unknown role {entry['role']}")

    @classmethod
    @functools.lru_cache(maxsize=4)
    def load(cls, path: Path | None = None) -> Notation:
        return cls(yaml.safe_load(Path(path or NOTATION_FILE).read_text(encoding="utf-8")))

    def role(self, name: str) -> Role:
        return self.roles[name]

    def table_role(self, sym: Symbol) -> str | None:
        """The role the shared table gives ``sym`` (its variants first), None when the table has none."""
        for v in self.variants:
            if v["name"] != sym.name:
                continue
            if "superscript" in v and sym.superscript != v["superscript"]:
                continue
            if "subscripts" in v and list(sym.subscripts) != list(v["subscripts"]):
                continue
            if "decorations" in v and not set(v["decorations"]) <= set(sym.decorations):
                continue
            if "args" in v and len(sym.args) != int(v["args"]):
                continue
            return v["role"]
        entry = self.symbols.get(sym.name)
        return entry["role"] if entry else None

    def phrase_role(self, phrase: str) -> str | None:
        """The role a defining phrase names ("the pre-modulation weight matrix" -> weight_matrix)."""
        for pattern, role in self.phrases:
            if pattern.search(phrase):
                return role
        return None


# ---------------------------------------------------------------------------------------------- the paper
def loose_key(name: str, scripts: Iterable[str], primes: int = 0) -> str:
    """A key that ignores whether a script is a sub- or superscript (a PDF's text layer loses it)."""
    return name + "'" * primes + "|" + ",".join(sorted(s for s in scripts if s))


INDEX_LETTERS = ("i", "j", "k")
"""Subscripts that are sample indices in a sentence's symbol (the equation reader moves them out of the key)."""


def symbol_loose_key(sym: Symbol) -> str:
    scripts = [s for s in sym.subscripts if s not in INDEX_LETTERS] + ([sym.superscript] if sym.superscript else [])
    return loose_key(sym.name, scripts, sum(1 for d in sym.decorations if d == "prime"))


def _char_name(ch: str) -> str:
    return _GREEK_NAMES.get(ch, ch)


# a symbol in a PDF's text layer: one letter, then up to three script letters (Greek or Latin lower case, digits,
# primes), each either attached or after one space ("W f ∆", "h′∆", "bγ", "Ψ")
_TEXT_SYMBOL = re.compile(
    rf"(?<![A-Za-z{_GREEK_CHARS}])([A-Za-z{_GREEK_CHARS}])([′']?)"
    rf"((?:[ ]?[a-z0-9{_GREEK_CHARS}′](?![A-Za-z{_GREEK_CHARS}]))"
    rf"{{0,3}})(?![A-Za-z])")
_WORDS = {"an", "as", "at", "be", "by", "do", "go", "if", "in", "is", "it", "me", "my", "no", "of", "on", "or", "so",
          "to", "up", "us", "we", "he", "am", "a", "e", "i", "s"}
_NUMBER = r"[-+]?\d+(?:\.\d+)?"
_INLINE_MATH = re.compile(r"\$([^$]{1,200})\$")
_VERBS = r"(?:is|are|denotes?|represents?|stands? for|corresponds? to|refers? to|indicates?|is called|are called)"


@dataclass
class Mention:
    start: int
    end: int
    loose: str
    exact: str = ""     # the IR key when the mention is LaTeX


def mentions(text: str) -> list[Mention]:
    """Symbols named in a sentence: inline LaTeX (``$\\mathbf a^{attn}$``) read by the equation reader, and
    symbols of a PDF's text layer (``h∆``, ``W f ψ``, ``Ψ``)."""
    found: list[Mention] = []
    covered = []
    for m in _INLINE_MATH.finditer(text):
        covered.append((m.start(), m.end()))
        expr = parse_expression(m.group(1))  # never raises: what it cannot read is a ParseFailure
        if isinstance(expr, ParseFailure):  # "$S \in R^{3 x K}$", "$K = 4$": the symbol before the relation
            head = re.split(r"\\in\b|∈|=|<|>|\\le\b|\\ge\b", m.group(1), maxsplit=1)[0]
            expr = parse_expression(head) if head.strip() and head != m.group(1) else expr
        if isinstance(expr, ParseFailure):
            continue
        for node in walk(expr):
            if isinstance(node, Symbol):
                found.append(Mention(m.start(), m.end(), symbol_loose_key(node), node.key))
    for m in _TEXT_SYMBOL.finditer(text):
        if any(a <= m.start() < b for a, b in covered):
            continue
        base, prime, scripts = m.group(1), m.group(2), m.group(3).replace(" ", "")
        if m.group(0).lower() in _WORDS or (m.group(0).istitle() and m.group(0).lower() in _WORDS):
            continue
        if not scripts and not prime and base.isascii() and base not in "ABCDEFGHIJKLMNOPQRSTUVWXYZ":
            continue  # a lone lower-case Latin letter is a word ("a", "i"), not a symbol
        if not scripts and not prime and base in "AI":
            continue
        parts = [_char_name(c) for c in scripts if c != "′" and c not in INDEX_LETTERS]
        primes = (1 if prime else 0) + scripts.count("′")
        found.append(Mention(m.start(), m.end(), loose_key(_char_name(base), parts, primes)))
    found.sort(key=lambda x: x.start)
    return found


_MAPS_TO = re.compile(r"(?:\\mapsto|\\longmapsto|\\rightarrow|\\to|↦|→)\s*(?:\\left)?\(\s*(.+?)\s*(?:\\right)?\)\s*$")


def _tuple_outputs(formula: str) -> list[str]:
    """The loose keys of a function's outputs written as a tuple of symbols after its arrow
    (``f:(x,t)\\mapsto(P_{static},P_{new})``), in order; [] for anything else (one output, an expression)."""
    m = _MAPS_TO.search(formula)
    if not m:
        return []
    items, depth, start, inner = [], 0, 0, m.group(1)
    for i, ch in enumerate(inner):
        depth += ch in "({["
        depth -= ch in ")}]"
        if ch == "," and depth == 0:
            items.append(inner[start:i])
            start = i + 1
    items.append(inner[start:])
    keys = []
    for item in items:
        expr = parse_expression(item.strip())
        if not isinstance(expr, Symbol):
            return []
        keys.append(symbol_loose_key(expr))
    return keys if len(keys) >= 2 and len(set(keys)) == len(keys) else []


@dataclass
class StatedShape:
    """``Psi in R^{z x h}`` with the sizes the paper gives its letters (``z = 8,192``, ``h = 256``)."""

    dims: tuple
    quote: str
    where: str


def _number(expr) -> float | None:
    """The value of a number the paper writes in any notation (a product or quotient of numbers, a sign), else
    None."""
    if isinstance(expr, Number):
        return float(expr.value)
    if isinstance(expr, Neg):
        inner = _number(expr.arg)
        return None if inner is None else -inner
    if isinstance(expr, BinOp) and expr.op in ("*", "/"):
        left, right = _number(expr.left), _number(expr.right)
        if left is None or right is None or (expr.op == "/" and right == 0.0):
            return None
        return left * right if expr.op == "*" else left / right
    return None


@dataclass
class PaperWords:
    """What the paper's sentences say about its symbols."""

    definitions: dict = field(default_factory=dict)   # loose key -> Definition
    named: set = field(default_factory=set)           # loose keys the text names
    concat_roles: list = field(default_factory=list)  # (role, quote, where) of "concatenated with the ..."
    shapes: dict = field(default_factory=dict)        # loose key -> StatedShape
    letters: dict = field(default_factory=dict)       # letter -> (value, quote, where): "h = 256"
    activations: dict = field(default_factory=dict)   # loose key -> (function, quote, where): "c^med via sigmoid"
    constants: dict = field(default_factory=dict)     # loose key -> (value, quote, where): "$\lambda=0.1$"
    learned: dict = field(default_factory=dict)       # loose key -> (quote, where): "where $\beta$ is learned"
    constraints: dict = field(default_factory=dict)   # loose key -> (low, high, quote, where): "clamped to [0, 1]"
    outputs: dict = field(default_factory=dict)       # loose key -> (place, count, quote, where): "f: x -> (P_a, P_b)"
    operators: list = field(default_factory=list)     # (operator, what the paper calls it, quote, where)
    widths: list = field(default_factory=list)        # (value, quote, where): "256 units"
    layers: list = field(default_factory=list)        # (value, quote, where): "3 layers"
    sentences: list = field(default_factory=list)     # (text, where, section)
    unread: list = field(default_factory=list)        # (where, reason, sentence): what could not be read
    _text: str = ""

    @classmethod
    def read(cls, doc: Any, notation: Notation | None = None) -> PaperWords:
        notation = notation or Notation.load()
        words = cls()
        for text, where, section in _sentences(doc):
            words.sentences.append((text, where, section))
            try:
                words._read_sentence(text, where, notation)
            except Exception as err:  # noqa: BLE001 - the per-sentence boundary: recorded, the others are read
                words.unread.append((where, f"could not read the sentence's notation: {_describe(err)}", text))
        for hp in getattr(doc, "hyperparameters", []) or []:
            try:
                where = _where_of(hp.loc, hp.section)
                if hp.name == "hidden_dim" and isinstance(hp.value, int | float):
                    words.widths.append((int(hp.value), hp.sentence, where))
                elif hp.name == "num_layers" and isinstance(hp.value, int | float):
                    words.layers.append((int(hp.value), hp.sentence, where))
            except Exception as err:  # noqa: BLE001 - a hyperparameter that is no width (inf, nan): recorded
                words.unread.append(("", f"could not read the hyperparameter {hp.name}: {_describe(err)}",
                                     hp.sentence))
        return words

    def _read_sentence(self, text: str, where: str, notation: Notation) -> None:
        ms = mentions(text)
        for m in ms:
            self.named.add(m.loose)
        # "where X and Y are the A and B, respectively" / "X denotes the A"
        for m in re.finditer(rf"\s{_VERBS}\s+(?:the\s+|a\s+|an\s+|their\s+)?(?=([^.;:]{{3,160}}))", text):
            before = [x for x in ms if x.end <= m.start() and m.start() - x.end < 80]
            if not before:
                continue
            group = [before[-1]]
            for x in reversed(before[:-1]):  # "W f ∆, W f c , W f ψ and W f µ": the list before the verb
                gap = text[x.end:group[0].start]
                if re.fullmatch(r"\s*(?:,|and|,\s*and|or)?\s*", gap):
                    group.insert(0, x)
                else:
                    break
            lead = text[max(0, group[0].start - 12):group[0].start].lower()
            if not re.search(r"(where|while|and|,|^|\()\s*$", lead.strip() + " ") and group[0].start > 0 and \
                    not re.search(r"\b(where|while)\b", text[max(0, group[0].start - 40):group[0].start].lower()):
                continue
            # the phrase ends where the next clause starts ("... is learned and $l$ is the ...")
            phrase = re.split(r"\s(?:while|whereas|which|that|where)\s|,?\s+and\s+(?=\$)|,\s*(?=\$)", m.group(1))[0]
            parts = [phrase]
            if "respective" in phrase and len(group) > 1:
                split = [p.strip() for p in re.split(r",\s*(?:and\s+)?|\s+and\s+", phrase.replace("respectively", ""))
                         if p.strip()]
                if len(split) == len(group):
                    parts = split
            for i, x in enumerate(group):
                part = parts[i] if len(parts) == len(group) else parts[0]
                role = notation.phrase_role(part)
                if role and x.loose not in self.definitions:
                    self.definitions[x.loose] = Definition(role, "paper", part.strip(), text, where)
        # "where $\beta$ is learned", "$W$ and $b$ are learnable", "a learned scalar $\beta$": learned parameters
        firsts = [x for k, x in enumerate(ms) if k == 0 or ms[k - 1].start != x.start]  # one per inline formula
        for x in firsts:
            after, before = text[x.end:x.end + 60], text[max(0, x.start - 40):x.start]
            if re.match(rf"\$?\s*(?:,\s*\S{{1,30}}\s*)*(?:and\s+\$[^$]{{1,40}}\$\s*)?{_VERBS}\s+(?:a\s+|an\s+|also\s+)?"
                        r"(?:learn(?:ed|able|t)|trainable|optimi[sz]ed)\b", after, re.I) or \
                    re.search(r"\b(?:learn(?:ed|able)|trainable)\s+(?:[a-z-]+\s+){0,2}\$?\s*$", before, re.I):
                self.learned.setdefault(x.loose, (text, where))
        # "$\mathbf{S}$ ... is clamped to [0, 1]", "kept non-negative": a constraint on the values of the symbols
        # named before it in the clause
        for m in re.finditer(r"\b(?:clamped|clipped|constrained|restricted|projected|kept|bounded)\s+"
                             rf"(?:to|in|into|within|between)\s+\$?\s*\\?[\[(]\s*({_NUMBER})\s*,\s*({_NUMBER})\s*\\?[\])]|"
                             r"\b(?:kept|constrained|clamped)\s+(non-?negative|positive)", text, re.I):
            low, high = ((float(m.group(1)), float(m.group(2))) if m.group(1) else (0.0, None))
            clause_start = max(text.rfind(";", 0, m.start()), text.rfind(".", 0, m.start()), 0)
            # the subject: the first symbol of the last formula before the phrase that states no value (K = 4)
            named = [x for x in firsts if clause_start <= x.start and x.end <= m.start() and
                     (not x.exact or "=" not in text[x.start:x.end])]
            if named and (high is None or low < high):
                self.constraints.setdefault(named[-1].loose, (low, high, text, where))
        # "$c^{med}$ via sigmoid", "$a^{attn}$ and $a^{bs}$ via softplus": the output activation of a network
        for m in re.finditer(r"\bvia\s+(?:a\s+|an\s+)?(sigmoid|softplus|relu|tanh|exp)", text, re.I):
            clause_start = max(text.rfind(";", 0, m.start()), text.rfind(":", 0, m.start()), 0)
            for x in ms:
                if clause_start <= x.start and x.end <= m.start():
                    self.activations.setdefault(x.loose, (m.group(1).lower(), text, where))
        # "$f:(p,t)\mapsto(P_{a},P_{b},P_{c})$": a function's outputs, each symbol at its place in the tuple
        for m in _INLINE_MATH.finditer(text):
            places = _tuple_outputs(m.group(1))
            for place, key in enumerate(places):
                self.outputs.setdefault(key, (place, len(places), text, where))
        # "$\lambda=0.1$, $\alpha=0.01$": a symbol's value stated in the text
        for m in _INLINE_MATH.finditer(text):
            for part in re.split(r",\s*(?=\\?[A-Za-z])", m.group(1)):
                c = re.fullmatch(r"\s*(\\?[A-Za-z]+(?:_\{?[A-Za-z0-9]+\}?)?)\s*=\s*([^=<>]{1,60}?)\s*", part)
                if c:
                    expr, value = parse_expression(c.group(1)), _number(parse_expression(c.group(2)))
                    if isinstance(expr, Symbol) and value is not None:  # 0.1, 1e-4, 10^{-4}, 5 \times 10^{-3}
                        self.constants.setdefault(symbol_loose_key(expr), (value, text, where))
        # "where ⊗ represents the dot product": what the paper calls an operator (checked against the shapes)
        for m in re.finditer(r"(⊗|⊙|∘|\\otimes|\\odot|\\circ)\s*\$?\s*(?:represents|denotes|is)\s+"
                             r"(?:the\s+|a\s+|an\s+)?"
                             r"(dot|inner|scalar|element-?wise|hadamard|outer|kronecker|matrix)\s+product", text, re.I):
            self.operators.append((m.group(1), m.group(2).lower(), text, where))
        # "concatenated with the camera 3D coordinates"
        for m in re.finditer(r"concatenat\w*\s+with\s+(?:the\s+)?([^.;,]{3,80})", text, re.I):
            role = notation.phrase_role(m.group(1))
            if role:
                self.concat_roles.append((role, text, where))
        # "Psi in R^{z x h}" (text layer: "Ψ ∈Rz×h"; LaTeX: \Psi \in \mathbb{R}^{z \times h})
        for m in re.finditer(r"(\S{1,12})\s*(?:∈|\\in)\s*(?:R|ℜ|\\mathbb\{R\}|\\mathbb R)\s*\^?\{?\s*"
                             r"([A-Za-z0-9]{1,6})\s*"
                             r"(?:×|\\times)\s*([A-Za-z0-9]{1,6})\s*\}?", text):
            expr = parse_expression(m.group(1).lstrip("$"))
            keys = [symbol_loose_key(expr)] if isinstance(expr, Symbol) else [x.loose for x in mentions(m.group(1))]
            if keys:
                self.shapes[keys[-1]] = StatedShape((m.group(2), m.group(3)), text, where)
        # "z = 8, 192 is the number of ...", "h = 256 hidden neurons"
        for m in re.finditer(r"(?<![A-Za-z])([A-Za-z])\s*=\s*(\d{1,3}(?:,\s?\d{3})+|\d+)(?!\d|\.\d)", text):
            value = int(re.sub(r"[,\s]", "", m.group(2)))
            self.letters.setdefault(m.group(1), (value, text, where))
        for m in re.finditer(r"(\d{1,5})\s+(?:hidden\s+)?(?:units|neurons|channels)\b", text):
            self.widths.append((int(m.group(1)), text, where))

    # ------------------------------------------------------------------ look-ups
    def constraint(self, sym: Symbol) -> tuple | None:
        """(low, high, quote, where) of the sentence constraining ``sym``'s values, None when none does."""
        return self.constraints.get(symbol_loose_key(sym))

    def is_learned(self, sym: Symbol) -> tuple | None:
        """(quote, where) of the sentence saying ``sym`` is learned, None when none does."""
        return self.learned.get(symbol_loose_key(sym))

    def definition(self, sym: Symbol) -> Definition | None:
        return self.definitions.get(symbol_loose_key(sym))

    def names(self, sym: Symbol) -> bool:
        """Whether the text names ``sym`` (by its letters and scripts, in LaTeX or in a PDF's text layer, where
        scripts follow the letter: ``σmed``, ``h∆``, ``W f ψ``)."""
        if symbol_loose_key(sym) in self.named:
            return True
        if not self._text:
            self._text = "\n".join(text for text, _, _ in self.sentences)
        return any(re.search(rf"(?<![A-Za-z{_GREEK_CHARS}]){re.escape(form)}(?![A-Za-z{_GREEK_CHARS}])", self._text)
                   for form in surface_forms(sym))

    def first_sentence(self, sym: Symbol) -> tuple | None:
        """The first sentence that names ``sym`` (text, where), None when none does."""
        key = symbol_loose_key(sym)
        forms = surface_forms(sym)
        latex = _latex_pattern(sym)
        for text, where, _ in self.sentences:
            if any(m.loose == key for m in mentions(text)) or any(f in text for f in forms) or \
                    (latex is not None and latex.search(text)):
                return text, where
        return None

    def shape_of(self, sym: Symbol) -> tuple | None:
        """The paper's stated shape of ``sym`` with its letters resolved: ((rows, evidence), (width, evidence))."""
        stated = self.shapes.get(symbol_loose_key(sym))
        if stated is None:
            return None
        out = []
        for d in stated.dims:
            if d.isdigit():
                out.append((int(d), stated.quote, stated.where))
            elif d in self.letters:
                value, quote, where = self.letters[d]
                out.append((value, f"{stated.quote} ... {quote}" if quote != stated.quote else quote, where))
            else:
                return None
        return tuple(out)


_GLYPHS = {}
for _char, _tex in GREEK.items():
    _GLYPHS.setdefault(_tex.lstrip("\\"), _char)


def surface_forms(sym: Symbol) -> list[str]:
    """How a PDF's text layer writes ``sym``: its letter then its scripts (``σmed``, ``h∆``, ``W f ψ``, ``h′c``);
    a lone letter has none (it would match words)."""
    def glyph(name: str) -> str:
        return _GLYPHS.get(name, name)

    subs = [glyph(x) for x in sym.subscripts if x not in INDEX_LETTERS]
    sup = [glyph(sym.superscript)] if sym.superscript else []
    if not subs and not sup:
        return [glyph(sym.name)] if len(glyph(sym.name)) == 1 and not glyph(sym.name).isascii() else []
    base = glyph(sym.name) + "′" * sum(1 for d in sym.decorations if d == "prime")
    forms = set()
    for order in (subs + sup, sup + subs):
        forms.add(base + "".join(order))
        forms.add(base + " " + " ".join(order))
    return sorted(forms)


def _latex_pattern(sym: Symbol) -> re.Pattern | None:
    """``P_{\\text{deform}}`` and its spellings in LaTeX a sentence holds (for a symbol with a word script)."""
    scripts = [x for x in list(sym.subscripts) + [sym.superscript or ""] if x and len(x) > 1 and x.isalpha()]
    if not scripts or not sym.name.isalpha() or len(sym.name) > 1:
        return None
    word = re.escape(scripts[0])
    return re.compile(rf"(?<![A-Za-z]){re.escape(sym.name)}\s*[_^]\s*\{{?\s*(?:\\(?:text|mathrm|rm|operatorname)\s*"
                      rf"\{{)?\s*{word}(?![A-Za-z])")


def _where_of(loc: Any, section: str = "") -> str:
    page, line = getattr(loc, "page", None), getattr(loc, "line", None)
    first = f"p.{page}" if page is not None else (f"l.{line}" if line is not None else "")
    return ", ".join(x for x in (first, f"Sec. {section}" if section else "") if x)


def _sentences(doc: Any):
    from nerfify_ns.knowledge.sentences import split_sentences

    for s in getattr(doc, "sections", []) or []:
        for p in s.paragraphs:
            where = _where_of(p.loc, s.heading)
            for sent in split_sentences(p.text[:20000]):
                yield sent[:2000], where, s.heading
