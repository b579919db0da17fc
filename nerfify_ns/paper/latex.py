"""LaTeX reader: a .tex file, a source folder or an arXiv tarball, into blocks and a Document."""

from __future__ import annotations

import re
import tempfile
from bisect import bisect_right
from collections.abc import Iterator
from pathlib import Path

from nerfify_ns.paper.bibtex import load_references, parse_bbl
from nerfify_ns.paper.builder import Block, build
from nerfify_ns.paper.document import Document, Location
from nerfify_ns.paper.errors import EmptyDocumentError, PaperLimitError
from nerfify_ns.paper.language import prose, require_english
from nerfify_ns.paper.latex_source import (
    Flat,
    MacroBudget,
    SourceTree,
    collect_macros,
    expand_macros,
    find_main_file,
    flatten,
    line_starts,
    read_group,
    safe_extract,
)
from nerfify_ns.paper.limits import DEFAULT_LIMITS, Limits, check_elements

MATH_ENVS = ("equation", "align", "eqnarray", "gather", "multline", "displaymath", "flalign", "alignat")
_ENV = ("abstract", *MATH_ENVS, "figure", "table", "algorithm", "algorithm2e", "thebibliography")
_TOKEN = re.compile(
    r"\\(?P<sec>section|subsection|subsubsection|paragraph)(?P<star>\*?)\s*(?:\[[^\[\]]{0,2000}\])?\s*(?=\{)"
    r"|\\begin\{(?P<env>(?:" + "|".join(_ENV) + r")\*?)\}"
    r"|(?P<dmath>\\\[|\$\$)|(?P<appendix>\\appendix\b)")
_LABEL_AFTER = re.compile(r"\s*\\label\s*\{([^{}]{0,2000})\}")
_PARAGRAPH = re.compile(r"\S[^\n]*(?:\n(?![^\S\n]*\n)[^\n]*)*")
"""A paragraph: from a non-blank character up to a blank line (the lookahead stops at the next line break, so
the scan is linear)."""
_TWO_LETTERS = re.compile(r"[^\W\d_]{2}")
"""A paragraph has two letters in a row (in any script) once commands are removed."""
_COMMAND_NAME = re.compile(r"\\[A-Za-z]+")
_LEVEL = {"section": 1, "subsection": 2, "subsubsection": 3, "paragraph": 4}
ARCHIVES = (".tar.gz", ".tgz", ".tar")

# Patterns of _clean/_prose, compiled once. Arguments stop at the next brace or bracket and are bounded, so every
# scan starts after the previous one ended (linear in the text, however many unclosed commands it holds).
_ARG = r"\{([^{}]{0,2000})\}"
_OPT = r"\[[^\[\]]{0,2000}\]"
_SPECIAL = re.compile(r"[\\~${}`'-]")
_BLANKS = re.compile(r"[ \t]+")
_CITE = re.compile(r"\\(?:cite|citep|citet|citealp|autocite|parencite|textcite|citeauthor)\*?\s*"
                   r"(?:" + _OPT + r"\s*){0,2}" + _ARG)
_EQREF = re.compile(r"\\eqref\s*" + _ARG)
_REF = re.compile(r"\\(?:ref|autoref|cref|Cref)\s*" + _ARG)
_LABEL = re.compile(r"\\label\s*" + _ARG)
_URL = re.compile(r"\\url\s*" + _ARG)
_HREF = re.compile(r"\\href\s*\{[^{}]{0,2000}\}\s*" + _ARG)
_FOOTNOTE = re.compile(r"\\footnote\s*\{((?:[^{}]|\{[^{}]*\})*)\}")
_LIST_ENV = re.compile(r"\\(?:begin|end)\s*\{(?:itemize|enumerate|description|center|small|footnotesize)\}")
_ITEM = re.compile(r"\\item\s*(?:\[([^\[\]]{0,2000})\])?")
_INLINE_MATH = re.compile(r"(\$[^$]+\$)")
_STYLE = re.compile(r"\\(?:emph|textbf|textit|texttt|textsc|underline|text|mbox|textrm|textsf|noindent)\s*"
                    r"\{((?:[^{}]|\{[^{}]*\})*)\}")
_SPACING = re.compile(r"\\(?:noindent|centering|vspace\*?\{[^{}]{0,2000}\}|hspace\*?\{[^{}]{0,2000}\}|"
                      r"medskip|smallskip|bigskip|maketitle|newpage|clearpage|par)\b")
_BIB_CMD = re.compile(r"\\(?:bibliography|bibliographystyle|addbibresource)\s*\{[^{}]{0,2000}\}")
_GRAPHICS = re.compile(r"\\(?:includegraphics|input)\s*(?:" + _OPT + r")?\{[^{}]{0,2000}\}")
_COMMAND = re.compile(r"\\[A-Za-z]+\*?")


def read_latex(path: Path, limits: Limits = DEFAULT_LIMITS) -> Document:
    """Ingest a .tex file, a folder of sources, or a .tar/.tar.gz/.tgz of sources. Only files inside the
    paper's folder or archive are read (see :class:`SourceTree`), within ``limits``."""
    if path.is_dir():
        tree = SourceTree(path, limits)
        return _read_tree(find_main_file(path, tree), tree, str(path))
    if path.name.lower().endswith(ARCHIVES):
        with tempfile.TemporaryDirectory(prefix="nerfify-tex-") as tmp:
            tree = SourceTree(safe_extract(path, Path(tmp), limits), limits)
            return _read_tree(find_main_file(tree.root, tree), tree, str(path))
    tree = SourceTree(path.resolve().parent, limits)
    return _read_tree(path.resolve(), tree, str(path))


def _read_tree(main: Path, tree: SourceTree, source: str) -> Document:
    flat = flatten(main, tree=tree)
    macros, text = collect_macros(flat.text)
    parser = _Parser(text, flat, macros, MacroBudget(tree.limits, Path(source).name))
    blocks = list(parser.blocks())
    if not blocks and not parser.title:
        raise EmptyDocumentError(f"{source}: no text found in the LaTeX sources; check the main file")
    check_elements(blocks, Path(source).name, tree.limits)
    require_english(prose([Block("title", parser.title), *blocks]), Path(source).name)
    refs = parser.bib_refs if parser.bib_refs is not None else load_references(
        tree, main, parser.bib_names, parser.cited)
    doc = build(blocks, source=source, kind="latex", references=refs, title=parser.title,
                authors=parser.authors, cite_keys={r.key for r in refs} | set(parser.cited))
    return doc


class _Parser:
    """Walks the flattened source between \\begin{document} and \\end{document}."""

    def __init__(self, text: str, flat: Flat, macros: dict, budget: MacroBudget | None = None):
        self.text, self.flat, self.macros = text, flat, macros
        self.budget = budget or MacroBudget()
        self.source = self.budget.source or "the paper"
        self.pieces, self.max_pieces = 0, self.budget.limits.max_elements
        self.eq_no = self.fig_no = self.tab_no = self.alg_no = 0
        self.sec = [0, 0, 0, 0]
        self.appendix = False
        self.labels: dict[str, str] = {}
        self.cited: list[str] = []
        self.bib_names: list[str] = []
        self.bib_refs: list | None = None
        self.line_starts = line_starts(text)
        self.title = self._clean(self._command_arg("title"))
        self.authors = self._authors()

    # ----- helpers ------------------------------------------------------------------------------------
    def _loc(self, offset: int) -> Location:
        i = max(0, bisect_right(self.line_starts, offset) - 1)
        fname, line = self.flat.origins[i] if i < len(self.flat.origins) else ("", 0)
        return Location(file=fname, line=line)

    def _command_arg(self, name: str) -> str:
        m = re.search(r"\\" + name + r"\s*(?:\[[^\[\]]{0,2000}\])?\s*(?=\{)", self.text)
        return read_group(self.text, m.end())[0] if m else ""

    def _authors(self) -> list[str]:
        raw = self._command_arg("author")
        raw = re.sub(r"\\(?:thanks|footnote|inst|affiliation|email)\s*\{[^{}]*\}", "", raw)
        names = []
        for part in re.split(r"\\and\b|,|\\AND\b", raw):
            first = re.split(r"\\\\", part)[0]
            name = self._clean(first).strip(" *0123456789")
            if name and len(name.split()) <= 5:
                names.append(name)
        return names

    def _expand(self, s: str) -> str:
        return expand_macros(s, self.macros, budget=self.budget)

    def _clean(self, s: str) -> str:
        """LaTeX prose to text: macros expanded, citations as [keys], math kept in $...$."""
        self._count()
        if not _SPECIAL.search(s):  # plain words: nothing to expand or convert
            return _BLANKS.sub(" ", s).strip()
        s = self._expand(s)
        s = _CITE.sub(self._cite, s)
        s = _EQREF.sub(lambda m: f"({self.labels.get(m.group(1).strip(), '?')})", s)
        s = _REF.sub(lambda m: self.labels.get(m.group(1).strip(), "?"), s)
        s = _LABEL.sub("", s)
        s = _URL.sub(r"\1", s)
        s = _HREF.sub(r"\1", s)
        s = _FOOTNOTE.sub(r" (\1)", s)
        s = _LIST_ENV.sub("\n", s)
        s = _ITEM.sub(lambda m: "\n- " + (m.group(1) or ""), s)
        segs = _INLINE_MATH.split(s)
        segs = [seg if seg.startswith("$") else self._prose(seg) for seg in segs]
        return _BLANKS.sub(" ", "".join(segs)).strip()

    def _count(self) -> None:
        """One more piece of the paper (a text cleaned, an equation): refused beyond ``max_elements``."""
        self.pieces += 1
        if self.pieces > self.max_pieces:
            raise PaperLimitError(f"{self.source}: more than {self.max_pieces:,} pieces of text and equations "
                                  "(paragraphs, table cells, algorithm lines; the limit); pass the paper's own sources")

    def _cite(self, m: re.Match) -> str:
        keys = [k.strip() for k in m.group(1).split(",") if k.strip()]
        self.cited.extend(keys)
        return "[" + ", ".join(keys) + "]"

    @staticmethod
    def _prose(s: str) -> str:
        s = s.replace("~", " ").replace("\\\\", " ").replace("---", "—").replace("--", "–")
        s = s.replace("``", "“").replace("''", "”").replace("\\%", "%").replace("\\&", "&").replace("\\_", "_")
        if "\\" in s:
            for _ in range(3):
                s = _STYLE.sub(r"\1", s)
            s = _SPACING.sub(" ", s)
            s = _BIB_CMD.sub("", s)
            s = _GRAPHICS.sub("", s)
            s = _COMMAND.sub("", s)
        return s.replace("{", "").replace("}", "")

    # ----- walk ---------------------------------------------------------------------------------------
    def blocks(self) -> Iterator[Block]:
        begin = self.text.find("\\begin{document}")
        start = begin + len("\\begin{document}") if begin >= 0 else 0
        end = self.text.find("\\end{document}")
        end = end if end >= 0 else len(self.text)
        bib_cmds = re.finditer(r"\\(?:bibliography|addbibresource)\s*\{([^{}]{0,2000})\}", self.text)
        self.bib_names = [n.strip() for m in bib_cmds for n in m.group(1).split(",")]
        out: list[Block] = []
        pos = start
        while True:
            m = _TOKEN.search(self.text, pos, end)
            if not m:
                break
            out.extend(self._prose_blocks(self.text[pos:m.start()], pos))
            pos = self._token(m, out)
        out.extend(self._prose_blocks(self.text[pos:end], pos))
        for b in out:  # resolve \ref / \cite now that every label has its number
            if b.kind in ("para", "abstract", "caption"):
                b.text = self._clean(b.text)
        yield from (b for b in out if b.text or b.kind in ("equation", "table", "algorithm"))

    def _prose_blocks(self, chunk: str, offset: int) -> Iterator[Block]:
        for m in _PARAGRAPH.finditer(chunk):
            para = m.group(0).rstrip()
            if _TWO_LETTERS.search(_COMMAND_NAME.sub("", para)):
                yield Block("para", para, self._loc(offset + m.start()))

    def _token(self, m: re.Match, out: list) -> int:
        if m.group("sec"):
            return self._section(m, out)
        if m.group("appendix"):
            self.appendix, self.sec = True, [0, 0, 0, 0]
            return m.end()
        if m.group("dmath"):
            closer = "\\]" if m.group("dmath") == "\\[" else "$$"
            stop = self.text.find(closer, m.end())
            stop = stop if stop >= 0 else len(self.text)
            self._count()
            latex = self._expand(self.text[m.end():stop]).strip()
            out.append(Block("equation", "", self._loc(m.start()), latex=latex))
            return stop + len(closer)
        env = m.group("env")
        body, after = self._env_body(env, m.end())
        handler = {"abstract": self._abstract, "figure": self._float, "table": self._float,
                   "algorithm": self._algorithm, "algorithm2e": self._algorithm,
                   "thebibliography": self._bibliography}.get(env.rstrip("*"), self._math)
        out.extend(handler(env, body, self._loc(m.start())))
        return after

    def _env_body(self, env: str, start: int) -> tuple[str, int]:
        """The body of the environment opened just before ``start`` (nested ones of the same name kept), and the
        index after its ``\\end``; an unclosed environment runs to the end. One scan from ``start``."""
        depth = 1
        for m in re.compile(r"\\(begin|end)\{" + re.escape(env) + r"\}").finditer(self.text, start):
            depth += 1 if m.group(1) == "begin" else -1
            if depth == 0:
                return self.text[start:m.start()], m.end()
        return self.text[start:], len(self.text)

    def _section(self, m: re.Match, out: list) -> int:
        title, after = read_group(self.text, m.end())
        level = _LEVEL[m.group("sec")]
        number = ""
        if not m.group("star") and level <= 3:
            self.sec[level - 1] += 1
            self.sec[level:] = [0] * (4 - level)
            first = chr(ord("A") + self.sec[0] - 1) if self.appendix else str(self.sec[0])
            number = ".".join([first, *map(str, self.sec[1:level])])
        label = _LABEL_AFTER.match(self.text, after)
        if label:
            self.labels[label.group(1).strip()] = number
        out.append(Block("heading", self._clean(title), self._loc(m.start()), level=level, number=number))
        return after

    def _abstract(self, env: str, body: str, loc: Location) -> Iterator[Block]:
        yield Block("abstract", body.strip(), loc)

    def _float(self, env: str, body: str, loc: Location) -> Iterator[Block]:
        is_table = env.startswith("table")
        read = 0
        for cm in re.finditer(r"\\caption\s*(?:\[[^\[\]]{0,2000}\])?\s*(?=\{)", body):
            if cm.start() < read:
                continue  # inside the previous caption (an unclosed one runs to the end of the float)
            if is_table:
                self.tab_no += 1
            else:
                self.fig_no += 1
            number = str(self.tab_no if is_table else self.fig_no)
            caption, read = read_group(body, cm.end())
            label = re.search(r"\\label\s*\{([^{}]{0,2000})\}", body)
            if label:
                self.labels[label.group(1).strip()] = number
            kind = "Table" if is_table else "Figure"
            yield Block("caption", f"{kind} {number}: {caption.strip()}", loc, number=number,
                        label=label.group(1).strip() if label else "", title=kind.lower())
        if is_table and (rows := self._tabular_rows(body)):
            yield Block("table", "", loc, rows=rows, number=str(self.tab_no))

    def _tabular_rows(self, body: str) -> list[list[str]]:
        m = re.search(r"\\begin\{tabular\*?\}\s*(?:\{[^{}]{0,2000}\}\s*)?(?:\{(?:[^{}]|\{[^{}]*\})*\})", body)
        if not m:
            return []
        end = body.find("\\end{tabular", m.end())
        content = body[m.end(): end if end >= 0 else len(body)]
        content = re.sub(r"\\(?:hline|toprule|midrule|bottomrule|cline\{[^{}]{0,2000}\}|"
                         r"cmidrule(?:\([^)]{0,2000}\))?\{[^{}]{0,2000}\})", "", content)
        content = re.sub(r"\\multicolumn\{\d+\}\{[^{}]{0,2000}\}\{((?:[^{}]|\{[^{}]*\})*)\}", r"\1", content)
        content = re.sub(r"\\multirow\{[^{}]{0,2000}\}\{[^{}]{0,2000}\}\{((?:[^{}]|\{[^{}]*\})*)\}", r"\1", content)
        rows = []
        for row in re.split(r"\\\\", content):
            cells = [self._clean(c).strip() for c in row.split("&")]
            if any(cells):
                rows.append(cells)
        numeric = sum(1 for r in rows for c in r if re.fullmatch(r"[-+]?\d+(?:\.\d+)?%?", c))
        return rows if numeric >= 2 else []

    def _algorithm(self, env: str, body: str, loc: Location) -> Iterator[Block]:
        self.alg_no += 1
        caption = re.search(r"\\caption\s*(?=\{)", body)
        title = self._clean(read_group(body, caption.end())[0]) if caption else ""
        label = re.search(r"\\label\s*\{([^{}]{0,2000})\}", body)
        if label:
            self.labels[label.group(1).strip()] = str(self.alg_no)
        lines = []
        for raw in re.split(r"\n|\\\\|(?=\\(?:State|If|ElsIf|Else|EndIf|For|ForAll|EndFor|While|EndWhile|Require|"
                            r"Ensure|Return|Function|EndFunction|Procedure|EndProcedure|KwIn|KwOut)\b)", body):
            raw = re.sub(r"\\(?:caption|label)\s*\{(?:[^{}]|\{[^{}]*\})*\}|"
                         r"\\(?:begin|end)\{algorithmic\}(\[[^\[\]]{0,2000}\])?", "", raw)
            kw = re.match(r"\s*\\(State|If|ElsIf|Else|EndIf|For|ForAll|EndFor|While|EndWhile|Require|Ensure|Return|"
                          r"Function|EndFunction|Procedure|EndProcedure)\b", raw)
            prefix = "" if not kw or kw.group(1) == "State" else kw.group(1).lower() + " "
            txt = raw[kw.end():] if kw else raw
            txt = self._clean(txt)
            if txt or prefix:
                lines.append((prefix + txt).strip())
        text = "\n".join([f"Algorithm {self.alg_no}: {title}".strip(), *lines])
        yield Block("algorithm", text, loc, number=str(self.alg_no), title=title)

    def _bibliography(self, env: str, body: str, loc: Location) -> Iterator[Block]:
        self.bib_refs = parse_bbl(body, self.budget.limits.max_references, self.source)
        return iter(())

    def _math(self, env: str, body: str, loc: Location) -> Iterator[Block]:
        base = env.rstrip("*")
        starred = env.endswith("*") or base == "displaymath"
        body = self._expand(body)
        rows = [body] if base in ("equation", "multline") else _split_rows(body)
        pending: list[str] = []
        for row in rows:
            label = re.search(r"\\label\s*\{([^{}]{0,2000})\}", row)
            tag = re.search(r"\\tag\*?\s*\{([^{}]{0,2000})\}", row)
            clean = re.sub(r"\\(?:label|tag\*?)\s*\{[^{}]{0,2000}\}|\\(?:nonumber|notag)\b", "", row).strip()
            numbered = not starred and not re.search(r"\\(?:nonumber|notag)\b", row) or tag
            pending.append(clean)
            if not numbered or not clean and not tag:
                continue
            if tag:
                number = tag.group(1).strip()
            else:
                self.eq_no += 1
                number = str(self.eq_no)
            if label:
                self.labels[label.group(1).strip()] = number
            self._count()
            yield Block("equation", "", loc, number=number, latex=" \\\\ ".join(p for p in pending if p),
                        label=label.group(1).strip() if label else "")
            pending = []
        if any(pending):
            yield Block("equation", "", loc, latex=" \\\\ ".join(p for p in pending if p))


_ROW_TOKEN = re.compile(r"\\begin(?=\{)|\\end(?=\{)|\\\\|[{}]")


def _split_rows(body: str) -> list[str]:
    """Split an align-like body at top-level ``\\\\`` (not inside nested environments or braces); one scan."""
    rows, depth, env_depth, start = [], 0, 0, 0
    for m in _ROW_TOKEN.finditer(body):
        t = m.group()
        if t == "{":
            depth += 1
        elif t == "}":
            depth -= 1
        elif t == "\\begin":
            env_depth += 1
        elif t == "\\end":
            env_depth -= 1
        elif depth == 0 and env_depth == 0:
            rows.append(body[start:m.start()])
            start = m.end()
    rows.append(body[start:])
    return [r for r in rows if r.strip()]
