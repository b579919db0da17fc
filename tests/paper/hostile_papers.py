"""Hostile papers, generated (nothing copied): LaTeX folders and tarballs that reach outside the paper, bombs
(include trees, macro expansion, archives that inflate, bibliographies, oversized text), papers that are not in
English, and paper text made of rich markup and terminal escapes. Shared by the in-process tests and the tests
that run the real CLI."""

from __future__ import annotations

import gzip
import io
import os
import tarfile
import uuid
from pathlib import Path

import pymupdf

MAIN = ("\\documentclass{{article}}\n\\title{{HostNeRF: Neural Radiance Fields for View Synthesis}}\n"
        "\\begin{{document}}\n\\maketitle\n\\begin{{abstract}}\nWe present a neural radiance field that renders "
        "camera rays with volume rendering for novel view synthesis of a scene.\n\\end{{abstract}}\n"
        "\\section{{Method}}\nWe use a hash encoding and a small MLP for the density of the radiance field.\n"
        "{body}\n\\end{{document}}\n")
"""A small English NeRF paper; ``{body}`` is where the hostile part goes."""


def token() -> str:
    """A string that appears nowhere unless something leaked it."""
    return f"canary-{uuid.uuid4().hex}"


def latex_folder(root: Path, body: str, files: dict[str, str] | None = None) -> Path:
    """A LaTeX source folder: main.tex holding ``body`` and any other ``files`` (relative path -> text)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "main.tex").write_text(MAIN.format(body=body))
    for rel, text in (files or {}).items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def outside_canary(tmp: Path) -> tuple[Path, str]:
    """A file beside (outside) the paper's folder holding a fresh token: ``tmp/outside/canary.tex``."""
    secret = token()
    path = tmp / "outside" / "canary.tex"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"\\section{{Leaked}}\n{secret} neural radiance field\n")
    (path.parent / "refs.bib").write_text(f"@article{{leak, title={{{secret}}}, year={{2020}}}}\n")
    return path, secret


def tarball(path: Path, files: dict[str, str]) -> Path:
    """A .tar.gz of text files."""
    with tarfile.open(path, "w:gz") as tar:
        for name, text in files.items():
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


_MiB = 1 << 20


def inflating_tarball(path: Path, members: list[tuple[str, int]], header_type: bytes = tarfile.REGTYPE) -> Path:
    """A tar.gz whose ``members`` (name, size in bytes) hold zeros, written as concatenated gzip members (one per
    MiB, about 1 KB each), so a tarball of about 1 MB inflates to about 1 GB without ever compressing 1 GB here."""
    zeros = gzip.compress(bytes(_MiB), 9)
    with open(path, "wb") as f:
        for name, size in members:
            info = tarfile.TarInfo(name)
            info.size, info.type = size, header_type
            f.write(gzip.compress(info.tobuf(format=tarfile.GNU_FORMAT)))
            for _ in range(size // _MiB):
                f.write(zeros)
            rest = size % _MiB + (-size) % 512
            if rest:
                f.write(gzip.compress(bytes(rest)))
        f.write(gzip.compress(bytes(1024)))  # the archive's end
    return path


def include_tree(root: Path, fanout: int = 4, depth: int = 20) -> Path:
    """main.tex inputs f1 ``fanout`` times, f1 inputs f2 ``fanout`` times, ... ``depth`` levels: fanout**depth
    inclusions if followed."""
    files = {f"f{k}.tex": f"level {k}\n" + f"\\input{{f{k + 1}}}\n" * fanout for k in range(1, depth)}
    files[f"f{depth}.tex"] = "the leaf of the radiance field\n"
    return latex_folder(root, "\\input{f1}\n" * fanout, files)


def macro_bomb(root: Path, repeat: int = 200, levels: int = 6) -> Path:
    """\\def\\mA{x}, \\def\\mB{\\mA ... \\mA} (``repeat`` times), ... ``levels`` deep, then one use of the last:
    repeat**levels characters if expanded."""
    names = [f"m{chr(65 + k)}" for k in range(levels + 1)]
    defs = [f"\\def\\{names[0]}{{x}}"]
    defs += [f"\\def\\{names[k]}{{{(chr(92) + names[k - 1] + ' ') * repeat}}}" for k in range(1, levels + 1)]
    return latex_folder(root, "\n".join(defs) + f"\nThe field is \\{names[-1]}.\n")


def big_bib(path: Path, entries: int, pad: int = 0) -> Path:
    """A .bib with ``entries`` entries (each padded with ``pad`` characters of abstract)."""
    abstract = "a" * pad
    with open(path, "w") as f:
        for k in range(entries):
            f.write(f"@article{{key{k}, title={{Radiance Field {k}}}, author={{Ada Lovelace and Alan Turing}}, "
                    f"journal={{ACM TOG}}, year={{2022}}, abstract={{{abstract}}}}}\n")
    return path


ZH_TITLE = "神经辐射场：用于新视角合成的快速方法"
ZH_PARA = "我们提出一种神经辐射场方法，使用多分辨率哈希编码和体积渲染来合成新视角图像，并在合成场景上取得了很好的结果。"


def chinese_pdf(path: Path) -> Path:
    """A Chinese-language NeRF paper as a PDF (pymupdf's built-in CJK font ``china-s``)."""
    doc = pymupdf.open()
    page = doc.new_page(width=612, height=792)
    page.insert_text((50, 72), ZH_TITLE, fontname="china-s", fontsize=16)
    y = 110
    for _ in range(14):
        page.insert_text((50, y), ZH_PARA[:30], fontname="china-s", fontsize=10)
        page.insert_text((50, y + 14), ZH_PARA[30:], fontname="china-s", fontsize=10)
        y += 34
    doc.save(path)
    doc.close()
    return path


GERMAN = ("Wir stellen eine Methode vor, die neuronale Strahlungsfelder mit einer Hash-Kodierung kombiniert. Die "
          "Dichte wird entlang der Kamerastrahlen integriert und das Netzwerk mit einem photometrischen Verlust "
          "optimiert. In unseren Experimenten verwenden wir eine Batchgröße von 4096 Strahlen und eine Lernrate von "
          "0,0005, die exponentiell abnimmt. ")


def german_markdown(path: Path) -> Path:
    """A German-language NeRF paper (Latin script, so only the word signal tells)."""
    path.write_text("# FeldNeRF: Neuronale Strahlungsfelder (NeRF) für die Synthese neuer Ansichten\n\n"
                    f"## Zusammenfassung\n\n{GERMAN * 3}\n\n## Methode\n\n{GERMAN * 6}\n", encoding="utf-8")
    return path


RUSSIAN = ("Мы представляем метод, который объединяет нейронные поля излучения (NeRF) с хеш-кодированием и "
           "объёмным рендерингом лучей камеры для синтеза новых видов сцены. ")


def russian_text(path: Path) -> Path:
    path.write_text(f"Нейронные поля излучения NeRF для синтеза новых видов\n\n{RUSSIAN * 8}\n\n{RUSSIAN * 8}\n",
                    encoding="utf-8")
    return path


def fifo(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path)
    return path
