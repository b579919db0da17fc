"""``equations.yaml``: what the compiler made of each novel part, in a form a person corrects and reruns.

    write_records(folder, implementation, doc)        # equations.yaml + equations/<hole>.py in the run folder
    corrections, cache = read_corrections(path)       # ns-nerfify PAPER --equations path/equations.yaml

Each hole's record holds the equations as read (LaTeX a person may fix: a subscript, an operator), the bindings
(what each symbol is: ``as: input|network|parameter|constant`` and its ``role``), the sizes (``shape``), the
status and the reason, ``hash``: the digest of those editable parts as written, and ``source_hash``: the digest
of the generated component ``equations/<hole>.py`` as it was written. On a rerun, a hole whose editable parts
still match its hash was not edited: its component is taken from ``equations/<hole>.py`` next to the file (not
recompiled) only when that file still matches ``source_hash``; a component edited (or replaced, or missing its
recorded digest) is compiled again, and the hole's notes say so. An edited hole is recompiled with the person's
LaTeX, bindings and sizes. A hole built from the paper's sentences (``source: prose``, typed terminals: see
``prose.py``) is built again on every rerun, with the values a person wrote under ``asked`` or in its ``prose``
parameters. The file is read within the bounds of :mod:`nerfify_ns.safeio` (size, depth, aliases).
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
from pathlib import Path
from typing import Any

import yaml

from nerfify_ns import runfolder, safeio
from nerfify_ns.errors import NerfifyError
from nerfify_ns.synthesis.novel.implement import HoleResult, Implementation

FILE = runfolder.EQUATIONS
FOLDER = "equations"
MAX_BYTES = 4 << 20
MAX_SOURCE = 1 << 20
"""Bytes of a generated component read back for reuse."""
LOG = logging.getLogger("nerfify")


class EquationsFileError(NerfifyError):
    """An equations.yaml that cannot be read (bad input: one line, nothing written)."""


def editable(record: dict) -> dict:
    """The parts of a hole's record a person edits (images and statuses are not)."""
    out = {"equations": [{"number": e.get("number", ""), "key": e.get("key", ""), "latex": e.get("latex", "")}
                         for e in record.get("equations") or [] if isinstance(e, dict)],
           "bindings": record.get("bindings") or {}, "sizes": record.get("sizes") or {}}
    if record.get("source") == "prose":  # a part built from the paper's sentences: its parameters and those asked
        out["asked"] = {k: (v.get("value") if isinstance(v, dict) else v)
                        for k, v in (record.get("asked") or {}).items()}
        out["prose"] = [{"part": p.get("part"), "parameters": {k: (v.get("value") if isinstance(v, dict) else v)
                                                               for k, v in (p.get("parameters") or {}).items()}}
                        for p in record.get("prose") or [] if isinstance(p, dict)]
    return out


def editable_hash(record: dict) -> str:
    data = json.dumps(editable(record), sort_keys=True, default=str)
    return hashlib.sha256(data.encode()).hexdigest()[:16]


def source_hash(source: str) -> str:
    """The digest of a generated component's code as written (UTF-8)."""
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


def to_yaml(implementation: Implementation, doc: Any = None) -> str:
    title = (getattr(doc, "title", "") or "").strip()
    holes = []
    for r in implementation.records:
        data = r.to_dict()
        data["hash"] = editable_hash(data)
        if r.source:
            data["source_hash"] = source_hash(r.source)
        holes.append(data)
    body = {"paper": title, "summary": implementation.headline(), "equations": implementation.counts,
            "seconds": round(implementation.seconds, 3), "holes": holes}
    head = ("# The paper's novel parts as the equation compiler read them (nerfify-ns). Correct a hole's equations\n"
            "# (latex), bindings (as: input|network|parameter|constant, role) or sizes (shape) and rerun:\n"
            "#   ns-nerfify PAPER --equations equations.yaml\n"
            "# Holes you do not edit are not recompiled (their hash still matches). A part built from the paper's\n"
            "# sentences (source: prose) lists under `asked` the sizes the paper does not state: set a value, rerun.\n")
    return head + yaml.safe_dump(body, sort_keys=False, width=110, allow_unicode=True)


def render_images(folder: Path, implementation: Implementation, doc: Any = None) -> None:
    """Each hole's equations as read, rendered (matplotlib mathtext), and the PDF region each came from, under
    equations/<hole id>/; the records name the files (``image``, ``crop``). A rendering failure is said in the
    record, never hidden."""
    from nerfify_ns.equations.eqcheck import crop_png, render_latex_png

    pdf = None
    source = Path(str(getattr(doc, "source", "") or ""))
    if source.suffix.lower() == ".pdf" and source.is_file():
        try:
            import pymupdf

            pdf = pymupdf.open(str(source))
        except Exception:  # noqa: BLE001 - no crops, said per equation
            pdf = None
    try:
        for r in implementation.records:
            sub = Path(folder) / FOLDER / r.id
            for k, e in enumerate(r.equations[:40]):
                sub.mkdir(parents=True, exist_ok=True)
                ok, err, _, _ = render_latex_png(e.get("latex", ""), sub / f"eq{k}.png")
                e["image"] = f"{r.id}/eq{k}.png"
                if not ok and err:
                    e["render_error"] = err[:300]
                if pdf is not None and e.get("page") and e.get("bbox"):
                    try:
                        crop_png(pdf, int(e["page"]), e["bbox"], sub / f"crop{k}.png")
                        e["crop"] = f"{r.id}/crop{k}.png"
                    except Exception as exc:  # noqa: BLE001 - said in the record
                        e["crop_error"] = str(exc)[:200]
    finally:
        if pdf is not None:
            pdf.close()


def write_records(folder: Path, implementation: Implementation, doc: Any = None, images: bool = False) -> Path:
    """equations.yaml and the compiled components (equations/<hole id>.py) in ``folder``; ``images``: the
    equations rendered and cropped too (render_images)."""
    folder = Path(folder)
    if images:
        render_images(folder, implementation, doc)
    path = folder / FILE
    path.write_text(to_yaml(implementation, doc))
    sources = folder / FOLDER
    for r in implementation.records:
        if r.source:
            sources.mkdir(exist_ok=True)
            (sources / f"{r.id}.py").write_text(r.source, encoding="utf-8")
    return path


def read_corrections(path: Path) -> tuple[dict, dict]:
    """(corrections, cache) from a person's equations.yaml: corrections holds the edited holes (by id); cache the
    unedited holes' earlier results (by hole id), with their component source when it lies next to the file."""
    path = Path(path)
    try:
        data = safeio.load_yaml(path, MAX_BYTES, what=f"--equations {path}")
    except safeio.ReadRefused as exc:
        raise EquationsFileError(str(exc)) from None
    if not isinstance(data, dict) or not isinstance(data.get("holes"), list):
        raise EquationsFileError(f"--equations {path}: not an equations.yaml (a mapping with a list of holes)")
    edited, kept = [], {}
    for hole in data["holes"]:
        if not isinstance(hole, dict) or not isinstance(hole.get("id"), str):
            raise EquationsFileError(f"--equations {path}: every hole needs an id")
        for key in ("equations",):
            if hole.get(key) is not None and not isinstance(hole[key], list):
                raise EquationsFileError(f"--equations {path}: hole {hole['id']}: {key} must be a list")
        for key in ("bindings", "sizes"):
            if hole.get(key) is not None and not isinstance(hole[key], dict):
                raise EquationsFileError(f"--equations {path}: hole {hole['id']}: {key} must be a mapping")
        for key in ("asked",):
            if hole.get(key) is not None and not isinstance(hole[key], dict):
                raise EquationsFileError(f"--equations {path}: hole {hole['id']}: {key} must be a mapping")
        if hole.get("prose") is not None and not isinstance(hole["prose"], list):
            raise EquationsFileError(f"--equations {path}: hole {hole['id']}: prose must be a list")
        if hole.get("source") == "prose":  # built again from the sentences (cheap, deterministic), with its values
            edited.append(copy.deepcopy(hole))
        elif hole.get("hash") and editable_hash(hole) == hole["hash"]:
            source_file = path.parent / FOLDER / f"{hole['id']}.py"
            result = HoleResult(id=hole["id"], slot=str(hole.get("slot", "")),
                                production=str(hole.get("production", "")), section=str(hole.get("section", "")),
                                status=str(hole.get("status", "")), reason=str(hole.get("reason", "")),
                                equations=hole.get("equations") or [], bindings=hole.get("bindings") or {},
                                sizes=hole.get("sizes") or {}, state=hole.get("state") or {},
                                notes=list(hole.get("notes") or []), component=hole.get("component") or {},
                                checks=hole.get("checks") or {}, hash=hole["hash"])
            if result.component:
                source, why = _reusable_source(source_file, hole)
                if source is not None:
                    result.source = source
                    kept[hole["id"]] = result
                elif why:
                    LOG.warning("--equations %s: hole %s: %s", path, hole["id"], why)
                    edited.append({**copy.deepcopy(hole), RECOMPILE_NOTE: why})
            else:
                kept[hole["id"]] = result
        else:
            edited.append(copy.deepcopy(hole))
    return {"holes": edited}, kept


RECOMPILE_NOTE = "recompiled_because"
"""Key of a correction whose hole is compiled again because its generated component cannot be reused."""


def _reusable_source(source_file: Path, hole: dict) -> tuple:
    """(the component's code, None) when ``source_file`` matches the hole's ``source_hash``; else (None, why the
    hole is compiled again), or (None, None) when there is no file to reuse (compiled again, as before)."""
    if not source_file.is_file() and not source_file.is_symlink():
        return None, None
    name = f"{FOLDER}/{source_file.name}"
    recorded = hole.get("source_hash")
    if not isinstance(recorded, str) or not recorded:
        return None, (f"not reused: {name} has no source_hash recorded when it was generated; compiled again")
    try:
        data = safeio.read_bytes(source_file, MAX_SOURCE, what=name, follow_links=False)
    except safeio.ReadRefused as exc:
        return None, f"not reused: {exc}; compiled again"
    if hashlib.sha256(data).hexdigest() != recorded:
        return None, (f"not reused: {name} does not match the source_hash recorded when it was generated (edited "
                      "or replaced since); compiled again")
    return data.decode("utf-8", errors="replace"), None


