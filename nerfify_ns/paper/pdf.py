"""PDF reader (pymupdf): two-column reading order, headings, equations, captions, tables, references."""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from nerfify_ns.paper.builder import CAPTION, Block, build, heading_level, split_heading
from nerfify_ns.paper.document import Document, Location
from nerfify_ns.paper.errors import (
    CorruptPdfError,
    EmptyDocumentError,
    EncryptedPdfError,
    InputTooLargeError,
    PaperLimitError,
    ScannedPdfError,
)
from nerfify_ns.paper.language import SAMPLE_CHARS, require_english
from nerfify_ns.paper.limits import DEFAULT_LIMITS, Limits, check_elements
from nerfify_ns.paper.pdf_math import enrich_document
from nerfify_ns.paper.plaintext import MATHY, NAMED_HEADING
from nerfify_ns.paper.references import is_references_heading

EQ_NUMBER = re.compile(r"\(\s*(\d+[a-z]?)\s*\)\s*$")
_NUM_HEAD = re.compile(r"^((?:\d+|[A-Z])(?:\.\d+){0,3})\.?\s+([A-Z][^\n]{1,100})$")
_NUMERIC = re.compile(r"^[-−+]?\d+(?:[.,]\d+)?%?$")


@dataclass
class Unit:
    """A text block (or a merged row of fragments) on a page."""

    page: int
    x0: float
    y0: float
    x1: float
    y1: float
    lines: list[str]
    size: float
    bold: bool
    column: str = "full"
    kind: str = "para"
    extra: dict = field(default_factory=dict)

    @property
    def text(self) -> str:
        joined = "\n".join(self.lines)
        joined = re.sub(r"(?<=[a-z])-\n(?=[a-z])", "", joined)
        return re.sub(r"\s*\n\s*", " ", joined).strip()


def open_pdf(path: Path, max_pages: int | None = None):
    """Open with pymupdf, turning its failures into typed errors."""
    import pymupdf

    try:
        pdf = pymupdf.open(str(path), filetype="pdf")
    except Exception as e:  # pymupdf raises several exception types for broken files
        raise CorruptPdfError(f"{path.name}: cannot open the PDF ({e}); re-export or re-download it") from e
    if pdf.needs_pass or pdf.is_encrypted:
        raise EncryptedPdfError(f"{path.name}: the PDF is password-protected; save an unencrypted copy and retry")
    if max_pages is not None and pdf.page_count > max_pages:
        raise InputTooLargeError(f"{path.name}: {pdf.page_count} pages, more than the limit of {max_pages}; "
                                 "pass the paper alone or raise the page limit")
    if pdf.page_count == 0:
        raise CorruptPdfError(f"{path.name}: no page could be read from the PDF; re-export or re-download it")
    return pdf


def read_pdf(path: Path, max_pages: int | None = None, limits: Limits = DEFAULT_LIMITS) -> Document:
    """Ingest a PDF (at most ``limits.max_text_chars`` characters of text; English prose only)."""
    pdf = open_pdf(path, max_pages)
    try:
        units, images, words, total = [], 0, {}, 0
        for pno, page in enumerate(pdf, start=1):
            try:
                page_units = _page_units(page, pno)
                units.extend(page_units)
                total += sum(len(u.text) for u in page_units)
                if total > limits.max_text_chars:
                    raise PaperLimitError(f"{path.name}: more than {limits.max_text_chars:,} characters of text by "
                                          f"page {pno} (the limit on a paper's text); pass the paper alone")
                if any(_table_like(u.text) for u in page_units):
                    words[pno] = page.get_text("words")
                images += len(page.get_images(full=False))
            except PaperLimitError:
                raise
            except Exception as e:
                raise CorruptPdfError(f"{path.name}: page {pno} cannot be parsed ({e}); re-export the PDF") from e
        chars = sum(len(u.text) for u in units)
        if chars < 40 * max(1, min(pdf.page_count, 3)) // 2:
            if images:
                raise ScannedPdfError(f"{path.name}: pages are images with no text layer (scanned?); "
                                      "run OCR (e.g. ocrmypdf) first or pass the LaTeX/markdown source")
            raise EmptyDocumentError(f"{path.name}: the PDF holds no text; pass a PDF with text or the source")
        require_english(_sample(units), path.name)  # every unit: a paper in another script may yield no block
        blocks = _to_blocks(units, words)
        check_elements(blocks, path.name, limits)
        meta_title = (pdf.metadata or {}).get("title", "") or ""
        doc = build(blocks, source=str(path), kind="pdf", page_count=pdf.page_count)
        if not doc.title and len(meta_title) > 8:
            doc.title = meta_title.strip()
        enrich_document(doc, pdf)  # display equations as LaTeX from the text layer, with confidences
        return doc
    finally:
        pdf.close()


def _sample(units: list[Unit]) -> str:
    """The text of the first units, up to the language check's sample size."""
    parts, n = [], 0
    for u in units:
        parts.append(u.text)
        n += len(parts[-1]) + 1
        if n >= SAMPLE_CHARS:
            break
    return "\n".join(parts)


# ----- page layout ------------------------------------------------------------------------------------
def _page_units(page, pno: int) -> list[Unit]:
    width, height = page.rect.width, page.rect.height
    units = []
    import pymupdf

    flags = pymupdf.TEXT_PRESERVE_WHITESPACE | pymupdf.TEXT_MEDIABOX_CLIP  # no images: 6x faster
    for b in page.get_text("dict", flags=flags)["blocks"]:
        if b.get("type") != 0:
            continue
        lines, sizes, bold_chars, chars = [], Counter(), 0, 0
        for ln in b["lines"]:
            if abs(ln["dir"][0] - 1) > 0.01:  # rotated text: arXiv stamps, margins
                continue
            text = "".join(s["text"] for s in ln["spans"])
            if not text.strip():
                continue
            lines.append(text)
            for s in ln["spans"]:
                n = len(s["text"].strip())
                sizes[round(s["size"], 1)] += n
                chars += n
                if s["flags"] & 16 or "bold" in s["font"].lower():
                    bold_chars += n
        if not lines:
            continue
        x0, y0, x1, y1 = b["bbox"]
        u = Unit(pno, x0, y0, x1, y1, lines, sizes.most_common(1)[0][0], bold_chars > 0.6 * max(chars, 1))
        if not _is_noise(u, width, height):
            units.append(u)
    return _reading_order(units, width)


def _is_noise(u: Unit, width: float, height: float) -> bool:
    text = u.text
    if re.fullmatch(r"[\d\s]+", text) and (u.x1 < 0.08 * width or u.x0 > 0.92 * width):
        return True  # review-copy line numbers
    if (u.y1 < 0.065 * height or u.y0 > 0.915 * height) and len(text) < 120:
        return True  # running headers, footers, page numbers
    return False


def _reading_order(units: list[Unit], width: float) -> list[Unit]:
    """Left column, then right column, between full-width blocks (title, wide figures and captions)."""
    mid, slack = width / 2, 0.03 * width
    for u in units:
        u.column = "left" if u.x1 <= mid + slack else "right" if u.x0 >= mid - slack else "full"
    body = [u for u in units if u.column != "full" and (u.x1 - u.x0) > 0.25 * width]
    two_col = (sum(len(u.text) for u in body if u.column == "left") >= 150
               and sum(len(u.text) for u in body if u.column == "right") >= 150)
    if not two_col:
        for u in units:
            u.column = "full"
        return _merge_rows(sorted(units, key=lambda u: (round(u.y0), u.x0)))
    out: list[Unit] = []
    left = sorted((u for u in units if u.column == "left"), key=lambda u: (u.y0, u.x0))
    right = sorted((u for u in units if u.column == "right"), key=lambda u: (u.y0, u.x0))
    for f in sorted((u for u in units if u.column == "full"), key=lambda u: u.y0):
        out.extend(_merge_rows([u for u in left if u.y0 < f.y0]))
        out.extend(_merge_rows([u for u in right if u.y0 < f.y0]))
        left = [u for u in left if u.y0 >= f.y0]
        right = [u for u in right if u.y0 >= f.y0]
        out.append(f)
    return out + _merge_rows(left) + _merge_rows(right)


def _merge_rows(units: list[Unit]) -> list[Unit]:
    """Join fragments on the same visual row (equations split into pieces) left to right."""
    out: list[Unit] = []
    for u in sorted(units, key=lambda u: (u.y0, u.x0)):
        prev = out[-1] if out else None
        if prev and _same_row(prev, u):
            pieces = sorted(prev.extra.get("pieces", [prev]) + [u], key=lambda v: v.x0)
            merged_lines = [" ".join(" ".join(p.lines) for p in pieces)]
            out[-1] = Unit(u.page, min(prev.x0, u.x0), min(prev.y0, u.y0), max(prev.x1, u.x1), max(prev.y1, u.y1),
                           merged_lines, max(prev.size, u.size), prev.bold and u.bold, prev.column,
                           extra={"pieces": pieces})
        else:
            out.append(u)
    return out


def _same_row(a: Unit, b: Unit) -> bool:
    overlap = min(a.y1, b.y1) - max(a.y0, b.y0)
    short = len(a.lines) <= 4 and len(b.lines) <= 4 and len(a.text) < 200 and len(b.text) < 200
    return short and overlap > 0.4 * min(a.y1 - a.y0, b.y1 - b.y0)


# ----- classification ---------------------------------------------------------------------------------
def _body_size(units: list[Unit]) -> float:
    sizes = Counter()
    for u in units:
        sizes[u.size] += len(u.text)
    return sizes.most_common(1)[0][0] if sizes else 10.0


def _to_blocks(units: list[Unit], words: dict | None = None) -> list[Block]:
    body = _body_size(units)
    title_unit = _title_unit(units, body)
    blocks: list[Block] = []
    in_refs = front = False
    for u in units:
        front = front or u is title_unit
        head = _heading(u, body)
        is_section = bool(head and (head[0] or NAMED_HEADING.match(head[1])))
        if front and u is not title_unit and u.page == 1 and not is_section:
            if len(u.text.split()) < 40:  # authors and affiliations; a long one may be an unlabeled abstract
                names = _names(u.text)
                if names:
                    blocks.append(Block("authors", ", ".join(names), Location(page=1)))
                continue
        elif front and u is not title_unit:
            front = False
        loc = Location(page=u.page)
        text = u.text
        if u is title_unit or (title_unit and u.page == 1 and u.size == title_unit.size and
                               abs(u.y0 - title_unit.y1) < 2 * u.size and blocks and blocks[-1].kind == "title"):
            if blocks and blocks[-1].kind == "title":
                blocks[-1].text += " " + text
            else:
                blocks.append(Block("title", text, loc))
            continue
        if head:
            number, title = head
            in_refs = is_references_heading(title)
            blocks.append(Block("heading", title, loc, level=heading_level(number), number=number))
            continue
        if in_refs:
            blocks.append(Block("para", "\n".join(u.lines), loc))
            continue
        b = _classify_body(u, text, loc)
        b.rows = [[u.x0, u.y0, u.x1, u.y1]] if b.kind == "table" else b.rows
        blocks.append(b)
    return _postprocess(blocks, words or {})


_AFFIL = re.compile(r"universit|institut|department|school|college|lab|@|inc\.|corp|research|street|\d|"
                    r"\b(?:UK|USA|China|Germany|France|Japan|Korea|Canada|Scotland|England|Brazil|Israel|Italy)\b",
                    re.IGNORECASE)


def _names(text: str) -> list[str]:
    """Person names in a front-matter line (affiliations and e-mails dropped)."""
    out = []
    for piece in re.split(r",|\band\b|\s{2,}|·", text):
        piece = re.sub(r"[*†‡§¶∗]+|\s+\d+$", "", piece).strip()
        if _AFFIL.search(piece) or not re.fullmatch(r"(?:[A-Z][\w'’˜´`¨.\-]*\s+){1,3}[A-Z][\w'’˜´`¨\-]+", piece):
            continue
        out.append(piece)
    return out


def _title_unit(units: list[Unit], body: float) -> Unit | None:
    first = [u for u in units if u.page == 1 and len(u.text) < 250]
    if not first:
        return None
    top = max(first, key=lambda u: (u.size, -u.y0))
    return top if top.size >= body * 1.2 else None


def _heading(u: Unit, body: float) -> tuple[str, str] | None:
    raw = " ".join(ln.strip() for ln in u.lines)
    if len(u.lines) > 3 or len(raw) > 110 or raw.endswith((".", ",")) and not NAMED_HEADING.match(raw):
        return None
    emphasised = u.bold or u.size >= body + 0.8
    m = _NUM_HEAD.match(raw)
    if m and emphasised and not re.search(r"[=∑∫]", raw) and len(raw.split()) <= 14:
        return m.group(1), m.group(2).strip()
    if NAMED_HEADING.match(raw) and (emphasised or len(u.lines) == 1):
        return "", raw.rstrip(":.")
    if emphasised and len(u.lines) <= 2 and len(raw.split()) <= 10 and u.size >= body * 1.1 \
            and not EQ_NUMBER.search(raw) and re.match(r"[A-Z]", raw):
        return split_heading(raw)
    return None


def _classify_body(u: Unit, text: str, loc: Location) -> Block:
    if CAPTION.match(text):
        return Block("caption", text, loc)
    alg = re.match(r"Algorithm\s+(\d+)[.:]?\s*(.*)", text)
    if alg:
        return Block("algorithm", "\n".join(u.lines), loc, number=alg.group(1), title=alg.group(2).split("\n")[0][:120])
    m = EQ_NUMBER.search(text)
    if m and len(text) < 300 and (MATHY.search(text) or len(u.lines) > 1) and not text.rstrip().endswith(".)"):
        return Block("equation", EQ_NUMBER.sub("", text).strip(), loc, number=m.group(1))
    if _table_like(text):
        return Block("table", text, loc)
    return Block("para", text, loc)


def _table_like(text: str) -> bool:
    tokens = text.split()
    numeric = sum(1 for t in tokens if _NUMERIC.match(t.strip("()±")))
    return numeric >= 3 and numeric >= 0.4 * len(tokens)


def _postprocess(blocks: list[Block], words: dict) -> list[Block]:
    """Join paragraphs split across columns/pages; attach short math rows to the following equation."""
    out: list[Block] = []
    for b in blocks:
        prev = out[-1] if out else None
        if prev and prev.kind == "para" and b.kind == "para" and re.match(r"[a-z]", b.text) \
                and not re.search(r"[.!?:]\s*$", prev.text):
            prev.text = re.sub(r"(?<=[a-z])-$", "", prev.text) + ("" if prev.text.endswith("-") else " ") + b.text
            continue
        if b.kind == "table":
            same = [t for t in out[-6:] if t.kind == "table" and t.loc.page == b.loc.page]
            if same:  # columns of one table come as separate blocks
                same[-1].rows.extend(b.rows)
                continue
        if b.kind == "equation" and prev and prev.kind == "para" and len(prev.text) < 80 \
                and MATHY.search(prev.text) and not prev.text.endswith("."):
            out.pop()
            b.text = prev.text + " " + b.text
        out.append(b)
    _number_tables(out)
    for t in (b for b in out if b.kind == "table"):
        t.rows = _grid(t.rows, words.get(t.loc.page, []))
    return [b for b in out if b.kind != "table" or b.rows]


def _grid(boxes: list[list[float]], words: list) -> list[list[str]]:
    """Rows of cells from the words inside the table's boxes, widened to the rows' full width."""
    if not boxes or not words:
        return []
    y0, y1 = min(b[1] for b in boxes), max(b[3] for b in boxes)
    x0, x1 = min(b[0] for b in boxes), max(b[2] for b in boxes)
    inside = [w for w in words if w[1] >= y0 - 1 and w[3] <= y1 + 1 and w[0] >= x0 - 150 and w[2] <= x1 + 5]
    rows: list[list] = []
    for w in sorted(inside, key=lambda w: ((w[1] + w[3]) / 2, w[0])):
        yc = (w[1] + w[3]) / 2
        if rows and abs(rows[-1][0] - yc) < 3:
            rows[-1][1].append(w)
        else:
            rows.append([yc, [w]])
    grid = []
    for _, ws in rows:
        cells, last_x = [], None
        for w in sorted(ws, key=lambda w: w[0]):
            if last_x is not None and w[0] - last_x < 4:
                cells[-1] += " " + w[4]
            else:
                cells.append(w[4])
            last_x = w[2]
        grid.append(cells)
    return [r for r in grid if len(r) >= 2]


def _number_tables(blocks: list[Block]) -> None:
    """Give each table the number of the nearest "Table n" caption on its page."""
    captions = [b for b in blocks if b.kind == "caption" and re.match(r"\s*Tab", b.text)]
    for t in (b for b in blocks if b.kind == "table"):
        same_page = [c for c in captions if c.loc.page == t.loc.page]
        if same_page:
            c = min(same_page, key=lambda c: abs(blocks.index(c) - blocks.index(t)))
            m = CAPTION.match(c.text)
            t.number, t.title = (m.group(2) if m else ""), c.text
