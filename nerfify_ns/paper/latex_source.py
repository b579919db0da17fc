"""LaTeX sources: find the main file, extract tarballs safely, follow \\input/\\include, expand macros.

Paper input stays inside the paper: every file the sources name (``\\input``, ``\\include``, ``\\subfile``,
``\\import``, ``\\bibliography``) and every source file found in the paper's folder is read through a
:class:`SourceTree`, which reads only regular files inside the paper's folder or extracted archive (links
resolved first; absolute paths, ``..``, ``/proc``, ``/sys``, ``/dev``, pipes and devices refused with
:class:`OutsidePaperError` naming the file). Extraction, inclusion, macro expansion and the amount read are
bounded by :mod:`nerfify_ns.paper.limits`, each checked while the work is done, and each step is linear in
its input.
"""

from __future__ import annotations

import bz2
import gzip
import io
import lzma
import os
import re
import stat
import tarfile
from bisect import bisect_right
from dataclasses import dataclass, field
from itertools import accumulate, repeat
from pathlib import Path, PurePosixPath

from nerfify_ns.paper.errors import (
    MissingLatexFileError,
    OutsidePaperError,
    PaperLimitError,
    UnsafeArchiveError,
    UnsupportedInputError,
)
from nerfify_ns.paper.limits import DEFAULT_LIMITS, Limits, size_text

SOURCE_SUFFIXES = frozenset({".tex", ".ltx", ".bib", ".bbl", ".sty", ".cls", ".clo", ".bst", ".def", ".cfg",
                             ".txt", ".inc", ".tikz", ".pgf", ""})
"""Archive members written to disk: what the LaTeX reader may read (``\\input{name}`` without a suffix included).
Figures and other binaries are read through (counted against the limits) but never written."""

SPECIAL_ROOTS = tuple(Path(p) for p in ("/proc", "/sys", "/dev"))
"""Never read from, wherever a link points."""


# ----- archives ---------------------------------------------------------------------------------------
class _BoundedReader(io.RawIOBase):
    """A decompressed stream that refuses to yield more than ``budget`` bytes: a single read never asks the
    decompressor for more than what is left, so a bomb is never inflated beyond the budget, even in memory."""

    def __init__(self, raw, budget: int, on_exceeded):
        self.raw, self.left, self.on_exceeded = raw, budget, on_exceeded

    def readable(self) -> bool:
        return True

    def read(self, n: int = -1) -> bytes:
        if n is None or n < 0 or n > self.left + 1:
            n = self.left + 1
        data = self.raw.read(n)
        self.left -= len(data)
        if self.left < 0:
            self.on_exceeded()
        return data

    def readinto(self, b) -> int:
        data = self.read(len(b))
        b[:len(data)] = data
        return len(data)


def _decompressed(f) -> object:
    """The archive's tar stream: gzip, bzip2 and xz recognised from their magic bytes, else read as it is."""
    head = f.read(6)
    f.seek(0)
    if head[:2] == b"\x1f\x8b":
        return gzip.GzipFile(fileobj=f, mode="rb")
    if head[:3] == b"BZh":
        return bz2.BZ2File(f, mode="rb")
    if head[:6] == b"\xfd7zXZ\x00":
        return lzma.LZMAFile(f, mode="rb")
    return f


def _member_path(archive: Path, name: str) -> PurePosixPath:
    p = PurePosixPath(name)
    if p.is_absolute() or ".." in p.parts or name.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", name) \
            or "\\" in name or "\x00" in name:
        raise UnsafeArchiveError(f"{archive.name}: member '{name}' would escape the extraction folder; "
                                 "repack the sources with relative paths")
    return p


def safe_extract(archive: Path, dest: Path, limits: Limits = DEFAULT_LIMITS) -> Path:
    """Extract the sources of a .tar/.tar.gz/.tgz (also bzip2, xz) into ``dest``, streaming.

    Refuses absolute paths, ``..``, links and devices; counts members and their uncompressed bytes from each
    header before reading the data, and caps the decompressed stream itself, so an archive that inflates
    beyond ``limits.max_archive_bytes`` or holds more than ``limits.max_archive_files`` members is refused
    with nothing beyond the limit inflated or written. Only source files (:data:`SOURCE_SUFFIXES`) are
    written; figures are read through."""
    max_bytes, max_files = limits.max_archive_bytes, limits.max_archive_files

    def too_big() -> None:
        raise PaperLimitError(f"{archive.name}: the archive inflates to more than {size_text(max_bytes)} (the limit "
                              "on an archive's uncompressed size); pass the paper's sources alone")

    total = files = 0
    try:
        with open(archive, "rb") as raw:
            stream = _BoundedReader(_decompressed(raw), max_bytes + 1024 * (max_files + 64), too_big)
            with tarfile.open(fileobj=io.BufferedReader(stream, 1 << 16), mode="r|") as tar:
                for m in tar:
                    files += 1
                    if files > max_files:
                        raise PaperLimitError(f"{archive.name}: more than {max_files} members in the archive (the "
                                              "limit); pass the paper's sources alone")
                    rel = _member_path(archive, m.name)
                    if m.issym() or m.islnk() or m.isdev() or m.isfifo() or not (m.isfile() or m.isdir()):
                        raise UnsafeArchiveError(f"{archive.name}: member '{m.name}' is a link or device; "
                                                 "repack the sources with plain files only")
                    total += max(0, m.size)
                    if total > max_bytes:
                        too_big()
                    target = dest.joinpath(*rel.parts) if rel.parts else dest
                    if m.isdir():
                        target.mkdir(parents=True, exist_ok=True)
                    elif rel.suffix.lower() in SOURCE_SUFFIXES:
                        _write_member(tar, m, target)
    except tarfile.TarError as e:
        raise UnsupportedInputError(f"{archive.name}: not a readable tar archive ({e}); pass the .tex file or "
                                    "folder") from e
    except (EOFError, OSError, lzma.LZMAError) as e:
        raise UnsupportedInputError(f"{archive.name}: the archive cannot be read ({e}); pass the .tex file or "
                                    "folder") from e
    return dest


def _write_member(tar: tarfile.TarFile, m: tarfile.TarInfo, target: Path) -> None:
    """One regular member's data into ``target`` (never through a link: none is ever created)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    src = tar.extractfile(m)
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0), 0o600)
    with os.fdopen(fd, "wb") as out:
        while chunk := src.read(1 << 16):
            out.write(chunk)


# ----- the paper's files ------------------------------------------------------------------------------
def _names_outside(name: str) -> bool:
    """An include name that points outside any folder it is resolved against (before looking at the disk)."""
    p = PurePosixPath(name)
    return (p.is_absolute() or ".." in p.parts or name.startswith(("~", "|", "\\")) or "\x00" in name
            or re.match(r"^[A-Za-z]:", name) is not None)


class SourceTree:
    """The paper's folder (or extracted archive): the only place LaTeX sources are read from.

    ``read`` reads a regular file inside the folder (links resolved; anything leading outside it, into
    ``/proc``, ``/sys`` or ``/dev``, or that is not a regular file raises :class:`OutsidePaperError` naming
    the file), at most ``limit`` bytes of it and at most ``limits.max_archive_bytes`` from the tree in all;
    ``files`` lists the folder's files, visiting at most ``limits.max_archive_files`` entries."""

    def __init__(self, root: Path, limits: Limits = DEFAULT_LIMITS):
        try:
            self.root = Path(root).resolve(strict=True)
        except (OSError, RuntimeError) as e:
            raise UnsupportedInputError(f"{root}: the paper's folder cannot be read ({e}); check the path") from e
        self.limits = limits
        self.bytes_read = 0
        self._cache: dict[Path, str] = {}
        self._files: list[Path] | None = None
        self._complete = True

    def rel(self, path: Path) -> str:
        """``path`` as the paper names it: relative to the folder when inside it."""
        try:
            return Path(path).relative_to(self.root).as_posix()
        except ValueError:
            return str(path)

    def check(self, path: Path, shown: str) -> Path:
        """The real file behind ``path`` when it is a regular file inside the folder; else OutsidePaperError."""
        try:
            real = Path(path).resolve(strict=True)
            st = os.stat(real)
        except (OSError, RuntimeError, ValueError) as e:
            raise OutsidePaperError(f"{shown}: cannot be resolved inside the paper's folder ({type(e).__name__}); "
                                    "LaTeX sources must be plain files inside the paper's folder or archive") from e
        if not real.is_relative_to(self.root) or any(real.is_relative_to(s) for s in SPECIAL_ROOTS):
            raise OutsidePaperError(f"{shown}: leads outside the paper's folder or archive; LaTeX sources must be "
                                    "plain files inside it (copy the file in)")
        if not stat.S_ISREG(st.st_mode):
            raise OutsidePaperError(f"{shown}: not a regular file (a device, pipe or socket); LaTeX sources must "
                                    "be plain files inside the paper's folder or archive")
        return real

    def read(self, path: Path, shown: str, limit: int, what: str = "LaTeX source") -> str:
        """The text of a source file (undecodable bytes replaced), refused beyond ``limit`` bytes."""
        real = self.check(path, shown)
        if real in self._cache:
            return self._cache[real]
        try:
            fd = os.open(real, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0))
        except OSError as e:
            raise OutsidePaperError(f"{shown}: cannot be opened ({e.strerror}); LaTeX sources must be plain files "
                                    "inside the paper's folder or archive") from e
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise OutsidePaperError(f"{shown}: not a regular file; LaTeX sources must be plain files inside "
                                        "the paper's folder or archive")
            data = f.read(limit + 1)
        if len(data) > limit:
            raise PaperLimitError(f"{shown}: more than {size_text(limit)} of {what} (the limit on one file); "
                                  "pass the paper's own sources")
        self.bytes_read += len(data)
        if self.bytes_read > self.limits.max_archive_bytes:
            raise PaperLimitError(f"{shown}: reading the paper's sources goes past "
                                  f"{size_text(self.limits.max_archive_bytes)} (the limit); pass the paper's own "
                                  "folder")
        text = data.decode("utf-8", errors="replace")
        self._cache[real] = text
        return text

    def files(self, strict: bool = True) -> list[Path]:
        """Every file under the folder, sorted (links listed, not followed into folders). Past
        ``limits.max_archive_files`` entries: PaperLimitError when ``strict``, else the files seen so far (a
        lookup for a .bib beside a single .tex file in a crowded folder)."""
        if self._files is None:
            found, seen, complete = [], 0, True
            for dirpath, dirnames, filenames in os.walk(self.root, followlinks=False):
                seen += len(dirnames) + len(filenames)
                if seen > self.limits.max_archive_files:
                    complete = False
                    break
                dirnames.sort()
                found.extend(Path(dirpath) / f for f in filenames)
            self._files, self._complete = sorted(found), complete
        if strict and not self._complete:
            raise PaperLimitError(f"{self.root.name}: more than {self.limits.max_archive_files} files in the "
                                  "paper's folder (the limit); pass the paper's own folder")
        return self._files

    def with_suffix(self, suffix: str, strict: bool = True) -> list[Path]:
        return [p for p in self.files(strict) if p.name.endswith(suffix)]

    def locate(self, name: str, bases: list[Path], shown: str, suffixes: tuple = ("", ".tex")) -> Path | None:
        """The file an include names, tried under each of ``bases`` with each suffix; None when there is none.
        Names that point outside the folder, and files that lead outside it, raise OutsidePaperError."""
        if _names_outside(name):
            raise OutsidePaperError(f"{shown} points outside the paper's folder or archive (an absolute path, '..' "
                                    "or a shell command); LaTeX inputs must be files inside it")
        for base in bases:
            for suffix in suffixes:
                cand = base / f"{name}{suffix}"
                if not os.path.lexists(cand):
                    continue
                if cand.is_dir() and not cand.is_symlink():
                    continue
                return self.check(cand, shown)
        return None


# ----- main file --------------------------------------------------------------------------------------
def find_main_file(folder: Path, tree: SourceTree | None = None) -> Path:
    """The .tex file with \\documentclass (and \\begin{document}); the biggest such one on ties."""
    tree = tree or SourceTree(folder)
    candidates = []
    for tex in tree.with_suffix(".tex"):
        rel = tree.rel(tex)
        head = tree.read(tex, rel, tree.limits.max_latex_chars)
        score = ("\\documentclass" in head) * 2 + ("\\begin{document}" in head)
        if score:
            candidates.append((score, len(head), tex))
    if not candidates:
        raise UnsupportedInputError(f"{folder}: no .tex file with \\documentclass or \\begin{{document}}; "
                                    "pass the main .tex file")
    return max(candidates, key=lambda c: (c[0], c[1]))[2]


# ----- flattening with a line map ---------------------------------------------------------------------
_COMMENT = re.compile(r"(?<!\\)%[^\n]*")


def strip_comments(text: str) -> str:
    """Remove ``%`` comments (not ``\\%``), keeping line breaks so line numbers stay right."""
    return _COMMENT.sub("", text)


@dataclass
class Flat:
    """The flattened source and, per line of it, the (file, line) it came from."""

    text: str = ""
    origins: list[tuple[str, int]] = field(default_factory=list)
    line_starts: list[int] = field(default_factory=list)

    def where(self, offset: int) -> tuple[str, int]:
        i = max(0, bisect_right(self.line_starts, offset) - 1)
        return self.origins[i] if self.origins else ("", 0)


_INPUT = re.compile(
    r"\\(?P<cmd>input|include|subfile)[^\S\n]*\{(?P<name>[^{}\n]{1,1000})\}"
    r"|\\input[^\S\n]+(?P<bare>[^\s{}\\]{1,1000})"
    r"|\\(?P<imp>subimport|import|subinputfrom|inputfrom|subincludefrom|includefrom)\*?[^\S\n]*"
    r"\{(?P<dir>[^{}\n]{0,1000})\}[^\S\n]*\{(?P<file>[^{}\n]{1,1000})\}")
"""An include on one line (as LaTeX writes them): the name stops at a brace or line break and is bounded."""


@dataclass
class _Walk:
    tree: SourceTree
    parts: list = field(default_factory=list)
    origins: list = field(default_factory=list)
    includes: int = 0
    chars: int = 0


def line_starts(text: str) -> list[int]:
    """The offset of every line of ``text`` (C-speed: one split, one running sum)."""
    return [0, *accumulate(len(line) + 1 for line in text.split("\n")[:-1])]


def flatten(main: Path, root: Path | None = None, limits: Limits = DEFAULT_LIMITS,
            tree: SourceTree | None = None) -> Flat:
    """The main file with every \\input/\\include/\\subfile/\\import inlined (comments stripped); only files inside
    the paper's folder (``root``, default the main file's) are read, within the limits. The text before and after
    an include on its line become lines of their own."""
    tree = tree or SourceTree(root or Path(main).resolve().parent, limits)
    walk = _Walk(tree)
    real = tree.check(main, Path(main).name)
    _inline(real, walk, depth=0)
    flat = Flat(text="\n".join(walk.parts), origins=walk.origins)
    flat.line_starts = line_starts(flat.text)
    return flat


def _inline(path: Path, walk: _Walk, depth: int) -> None:
    tree, limits = walk.tree, walk.tree.limits
    rel = tree.rel(path)
    text = strip_comments(tree.read(path, rel, limits.max_latex_chars))
    pos, lineno = 0, 1
    for m in _INPUT.finditer(text):
        lineno += text.count("\n", pos, m.start())
        where = f"{rel}:{lineno}"
        if m.group("imp"):
            folder, name = m.group("dir").strip(), m.group("file").strip()
            shown = f"{where}: \\{m.group('imp')}{{{folder}}}{{{name}}}"
            if _names_outside(folder):
                raise OutsidePaperError(f"{shown} points outside the paper's folder or archive (an absolute path "
                                        "or '..'); LaTeX inputs must be files inside it")
            name = f"{folder.rstrip('/')}/{name}" if folder else name
            bases = [path.parent] if m.group("imp").startswith("sub") else [tree.root, path.parent]
        else:
            name = (m.group("name") or m.group("bare")).strip()
            shown = f"{where}: \\{m.group('cmd') or 'input'}{{{name}}}"
            bases = [tree.root, path.parent]
        if depth + 1 > limits.max_include_depth:
            raise PaperLimitError(f"{shown}: \\input nesting deeper than {limits.max_include_depth} (the limit); "
                                  "is there a cycle?")
        walk.includes += 1
        if walk.includes > limits.max_includes:
            raise PaperLimitError(f"{shown}: more than {limits.max_includes} \\input/\\include files followed "
                                  "(the limit); are files included over and over?")
        target = tree.locate(name, bases, shown)
        if target is None:
            raise MissingLatexFileError(f"{where}: \\input/\\include file '{name}' not found; "
                                        "add it to the sources or remove the \\input")
        _emit(walk, text[pos:m.start()], rel, lineno - text.count("\n", pos, m.start()))
        _inline(target, walk, depth + 1)
        lineno += m.group().count("\n")
        pos = m.end()
    _emit(walk, text[pos:], rel, lineno)


def _emit(walk: _Walk, text: str, rel: str, first_line: int) -> None:
    """A piece of one file (starting on ``first_line``) as lines of the flattened source."""
    walk.chars += len(text) + 1
    limit = walk.tree.limits.max_latex_chars
    if walk.chars > limit:
        raise PaperLimitError(f"{rel}:{first_line}: the LaTeX source with its \\input files inlined is longer than "
                              f"{limit:,} characters (the limit); pass the paper's own sources")
    walk.parts.append(text)
    walk.origins.extend(zip(repeat(rel), range(first_line, first_line + text.count("\n") + 1)))


# ----- macros -----------------------------------------------------------------------------------------
_CONTROL_WORD = re.compile(r"\\[A-Za-z]+|\\.", re.DOTALL)
_BRACE = re.compile(r"(?<!\\)[{}]")


def read_group(text: str, i: int) -> tuple[str, int]:
    """The balanced ``{...}`` group starting at (or after blanks from) ``i``: (content, index after it). An
    unclosed group runs to the end of ``text``; a control sequence or one character stands for a group."""
    n = len(text)
    while i < n and text[i] in " \t\n":
        i += 1
    if i >= n or text[i] != "{":
        if i < n and text[i] == "\\":
            m = _CONTROL_WORD.match(text, i)
            return m.group(0), m.end()
        return (text[i], i + 1) if i < n else ("", i)
    depth = 0
    for m in _BRACE.finditer(text, i):
        if m.group() == "{":
            depth += 1
        else:
            depth -= 1
            if depth == 0:
                return text[i + 1:m.start()], m.end()
    return text[i + 1:], n


@dataclass
class Macro:
    name: str
    nargs: int
    body: str
    default: str | None = None


_DEF_START = re.compile(r"\\(?:(?:re)?newcommand|providecommand|DeclareRobustCommand)\*?\s*|\\def\s*|"
                        r"\\DeclareMathOperator\*?\s*")
_DEF_NAME = re.compile(r"\\([A-Za-z]+)((?:#\d)*)")
_NARGS = re.compile(r"\s*\[(\d)\]")
_DEFAULT = re.compile(r"\s*\[([^\[\]]{0,2000})\]")
_OPTIONAL = re.compile(r"\[([^\[\]]{0,2000})\]")
_NAME = re.compile(r"[A-Za-z]+")


def collect_macros(text: str) -> tuple[dict[str, Macro], str]:
    """Macro definitions of ``text`` and the text with them blanked out (line breaks kept)."""
    macros: dict[str, Macro] = {}
    out, pos = [], 0
    for m in _DEF_START.finditer(text):
        if m.start() < pos:
            continue
        parsed = _parse_definition(text, m)
        if parsed is None:
            continue
        macro, end = parsed
        macros[macro.name] = macro
        out.append(text[pos:m.start()])
        out.append("\n" * text.count("\n", m.start(), end))
        pos = end
    out.append(text[pos:])
    return macros, "".join(out)


def _parse_definition(text: str, m: re.Match) -> tuple[Macro, int] | None:
    i = m.end()
    kind = m.group(0).strip()
    if kind.startswith("\\def"):
        nm = _DEF_NAME.match(text, i)
        if not nm:
            return None
        body, end = read_group(text, nm.end())
        return Macro(nm.group(1), len(nm.group(2)) // 2, body), end
    name, i = read_group(text, i)
    name = name.strip().lstrip("\\")
    if not _NAME.fullmatch(name):
        return None
    if kind.startswith("\\DeclareMathOperator"):
        body, end = read_group(text, i)
        return Macro(name, 0, f"\\operatorname{{{body}}}"), end
    nargs, default = 0, None
    if (a := _NARGS.match(text, i)):
        nargs, i = int(a.group(1)), a.end()
        if (d := _DEFAULT.match(text, i)):
            default, i = d.group(1), d.end()
    body, end = read_group(text, i)
    return Macro(name, nargs, body, default), end


class MacroBudget:
    """What macro expansion may still do in one document: expansions (steps) and inserted characters, shared by
    every call of :func:`expand_macros` for the document (its blocks, every pass), so the total work of
    expansion is linear in the limits. ``source`` names the paper in the error."""

    def __init__(self, limits: Limits = DEFAULT_LIMITS, source: str = ""):
        self.limits, self.source = limits, source
        self.steps = self.chars = 0

    def spend(self, macro: str, chars: int) -> None:
        self.steps += 1
        self.chars += chars
        where = f"{self.source}: " if self.source else ""
        if self.steps > self.limits.max_macro_steps:
            raise PaperLimitError(f"{where}expanding the paper's macros takes more than "
                                  f"{self.limits.max_macro_steps:,} steps (the limit; last \\{macro}); does a macro "
                                  "expand into itself?")
        if self.chars > self.limits.max_macro_output_chars:
            raise PaperLimitError(f"{where}expanding the paper's macros produces more than "
                                  f"{self.limits.max_macro_output_chars:,} characters (the limit; last \\{macro}); "
                                  "does a macro repeat another one, nested?")


def expand_macros(text: str, macros: dict[str, Macro], passes: int = 5,
                  budget: MacroBudget | None = None) -> str:
    """Expand user macros (with arguments and an optional first-argument default), a few passes deep, within
    ``budget`` (default: a fresh one with the default limits)."""
    if not macros:
        return text
    budget = budget or MacroBudget()
    for _ in range(passes):
        out, pos, changed = [], 0, False
        for m in _CONTROL_WORD.finditer(text):
            macro = macros.get(m.group()[1:])
            if macro is None or m.start() < pos:
                continue
            i, args = m.end(), []
            if macro.default is not None:
                opt = _OPTIONAL.match(text, i)
                args.append(opt.group(1) if opt else macro.default)
                i = opt.end() if opt else i
            while len(args) < macro.nargs:
                arg, i = read_group(text, i)
                args.append(arg)
            body = macro.body
            if args:
                grow = sum(body.count(f"#{k}") * len(a) for k, a in enumerate(args, start=1))
                budget.spend(macro.name, len(body) + grow)  # before the replacement allocates it
                for k, a in enumerate(args, start=1):
                    body = body.replace(f"#{k}", a)
            else:
                budget.spend(macro.name, len(body))
            if body[-1:].isalpha() and i < len(text) and text[i:i + 1].isalpha() and body.lstrip().startswith("\\"):
                body += " "
            out.append(text[pos:m.start()])
            out.append(body)
            pos, changed = i, True
        out.append(text[pos:])
        text = "".join(out)
        if not changed:
            break
    return text

