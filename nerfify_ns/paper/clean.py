"""An implementation-focused markdown of a Document, and a check that the abstract's key terms survive it."""

from __future__ import annotations

import re
from collections import Counter

from nerfify_ns.paper.document import Document, Section

DROP = re.compile(r"^(?:introduction|related works?|prior work|previous work|background and related work|"
                  r"acknowledge?ments?|references|bibliography)\b", re.IGNORECASE)
_STOP = set("""a an the and or of for to in on at by with from into via using use used is are be been we our
our this that these those its it as can which while where when than then such both each other more most also
not only new based via method methods approach paper results show present propose proposed work works well
however thus over under between across within without about several many first second two one three high
low better state art novel existing prior recent""".split())


def _is_dropped(s: Section) -> bool:
    return bool(DROP.match(s.title.strip()))


def clean_markdown(doc: Document) -> str:
    """Markdown without introduction, related work and acknowledgements; every equation, algorithm,
    caption, hyperparameter and citation kept (equations and hyperparameters of dropped sections too)."""
    out = [f"# {doc.title or 'Untitled'}", ""]
    if doc.abstract:
        out += ["## Abstract", "", doc.abstract, ""]
    eqs_by_sec = _group(doc.equations)
    algs_by_sec = _group(doc.algorithms)
    for s in doc.sections:
        head = "#" * min(6, s.level + 1) + " " + s.heading
        if _is_dropped(s):
            out += _dropped_summary(doc, s, head, eqs_by_sec.get(s.heading, []))
            continue
        out += [head, ""]
        placed = _in_place(s.paragraphs, eqs_by_sec.get(s.heading, []))
        for k, p in enumerate(s.paragraphs):
            out += [_equation_md(e) for e in placed.get(k, [])]
            out += [p.text, ""]
        out += [_equation_md(e) for e in placed.get(len(s.paragraphs), [])]
        out += [_algorithm_md(a) for a in algs_by_sec.get(s.heading, [])]
    orphans = eqs_by_sec.get("", [])
    if orphans:
        out += ["## Equations (outside sections)", ""] + [_equation_md(e) for e in orphans]
    if algs_by_sec.get(""):
        out += ["## Algorithms", ""] + [_algorithm_md(a) for a in algs_by_sec[""]]
    if doc.captions:
        out += ["## Figure and table captions", ""] + [f"- {c.text}" for c in doc.captions] + [""]
    if doc.hyperparameters:
        out += ["## Hyperparameters", ""]
        out += [f"- `{h.name}` = {h.value}{' ' + h.unit if h.unit else ''}"
                f"{' (' + h.qualifier + ')' if h.qualifier else ''} [{h.loc}]: \"{h.sentence}\""
                for h in doc.hyperparameters] + [""]
    if doc.references:
        out += ["## References", ""] + [f"- [{r.key}] {r.raw}" for r in doc.references] + [""]
    return "\n".join(out).rstrip() + "\n"


def _group(items) -> dict:
    groups: dict = {}
    for it in items:
        groups.setdefault(it.section, []).append(it)
    return groups


_MARK = re.compile(r"⟨Eq\.[^⟩]*⟩")
_ANCHOR = 40


def _flat(text: str) -> str:
    return re.sub(r"[^0-9a-z]+", "", text.lower())


def _in_place(paragraphs: list, equations: list) -> dict[int, list]:
    """Paragraph index -> the display equations shown before it (``len(paragraphs)``: after the last), each where
    the paper shows it: after the paragraph that introduces it (the text before it in its ``sentence``), else
    before the paragraph that goes on after it; one without an anchor of its own follows the equation before it
    (the first: the section's end). A rendering that moved every equation to the end of its section would detach it from
    the sentences that say which part it defines."""
    flats = [_flat(p.text) for p in paragraphs]
    placed: dict[int, list] = {}
    start, previous = 0, len(paragraphs)
    for e in equations:
        parts = _MARK.split(e.sentence or "", maxsplit=1)
        before, after = (parts[0], parts[1]) if len(parts) == 2 else ("", "")
        tail, head = _flat(before)[-_ANCHOR:], _flat(after)[:_ANCHOR]
        where = None
        if len(tail) >= 12:
            where = next((k + 1 for k in range(start, len(flats)) if tail in flats[k]), None)
        if where is None and len(head) >= 12:
            where = next((k for k in range(start, len(flats)) if flats[k].startswith(head)), None)
        if where is None:  # no anchor of its own ("and ⟨Eq. 9⟩"): beside the equation before it
            where = previous
        else:
            start = max(start, where - 1)
        placed.setdefault(where, []).append(e)
        previous = where
    return placed


def _equation_md(e) -> str:
    body = e.latex or e.text
    tag = f" \\tag{{{e.number}}}" if e.number else ""
    return f"$$\n{body}{tag}\n$$\n"


def _algorithm_md(a) -> str:
    return "```\n" + "\n".join(a.lines) + "\n```\n"


def _dropped_summary(doc: Document, s: Section, head: str, eqs: list) -> list[str]:
    """A dropped section leaves its citations, hyperparameter sentences and equations behind."""
    keys = [k for c in doc.citations if c.section == s.heading for k in c.keys]
    lines = [head, "", f"_({s.title} omitted: narrative)_"]
    if keys:
        lines.append(f"_Cites: {', '.join('[' + k + ']' for k in dict.fromkeys(keys))}_")
    sentences = dict.fromkeys(h.sentence for h in doc.hyperparameters if h.section == s.heading)
    lines += [""] + [f"> {x}" for x in sentences]
    return lines + [""] + [_equation_md(e) for e in eqs]


# ----- key terms --------------------------------------------------------------------------------------
def key_terms(text: str, limit: int = 25, corpus: str = "", min_count: int = 2) -> list[str]:
    """Method names (NeRF, BioNeRF, MLP) and technical bigrams ("radiance fields") of a text; with a
    ``corpus`` (the whole paper), only bigrams it repeats at least ``min_count`` times."""
    names = re.findall(r"\b[A-Za-z]*[A-Z][a-z]*[A-Z][\w\-]*\b|\b[A-Z]{2,}[a-z]?s?\b", text)
    words = re.findall(r"[A-Za-z][A-Za-z\-]+", text)
    bigrams = Counter()
    for a, b in zip(words, words[1:], strict=False):
        if a.lower() in _STOP or b.lower() in _STOP or len(a) < 4 or len(b) < 4:
            continue
        if a[0].isupper() and not a.isupper() and b[0].islower():
            continue  # sentence start
        bigrams[f"{a.lower()} {b.lower()}"] += 1
    if corpus:
        low = re.sub(r"\s+", " ", corpus.lower())
        bigrams = Counter({t: n for t, n in bigrams.items() if low.count(t) >= min_count})
    terms = list(dict.fromkeys(n for n in names if len(n) >= 2))
    terms += [t for t, _ in bigrams.most_common(limit)]
    return terms[:limit]


def _stem(term: str) -> str:
    return re.sub(r"(?:ies|es|s)\b", "", term.lower())


def key_terms_report(doc: Document, cleaned: str) -> dict:
    """Which key terms of the abstract survive in the cleaned markdown's body (the abstract itself excluded)."""
    body = re.sub(r"## Abstract\n.*?(?=\n## |\Z)", "", cleaned, flags=re.DOTALL)
    haystack = _stem(re.sub(r"\s+", " ", body))
    terms = key_terms(doc.abstract or doc.title, corpus=doc.text())
    kept = [t for t in terms if _stem(t) in haystack]
    missing = [t for t in terms if t not in kept]
    return {"terms": terms, "kept": kept, "missing": missing,
            "coverage": round(len(kept) / len(terms), 3) if terms else 1.0}
