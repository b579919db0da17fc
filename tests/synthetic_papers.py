"""Small self-made papers (markdown) for the detection, citation and plan-derivation tests."""

from __future__ import annotations

from pathlib import Path

from nerfify_ns.paper import ingest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
PAPERS = SHARED / "papers"

REFERENCES = {
    "1": "Ben Mildenhall, Pratul P. Srinivasan, Matthew Tancik, Jonathan T. Barron, Ravi Ramamoorthi, and Ren Ng. "
         "NeRF: Representing scenes as neural radiance fields for view synthesis. In ECCV, 2020.",
    "2": "Jonathan T. Barron, Ben Mildenhall, Matthew Tancik, Peter Hedman, Ricardo Martin-Brualla, and Pratul P. "
         "Srinivasan. Mip-NeRF: A multiscale representation for anti-aliasing neural radiance fields. In ICCV, 2021.",
    "3": "Jonathan T. Barron, Ben Mildenhall, Dor Verbin, Pratul P. Srinivasan, and Peter Hedman. Mip-NeRF 360: "
         "Unbounded anti-aliased neural radiance fields. In CVPR, 2022.",
    "4": "Thomas Müller, Alex Evans, Christoph Schied, and Alexander Keller. Instant NGP (an abbreviated entry). "
         "ACM TOG, 2022. arXiv:2201.05989.",
    "5": "Some Author. A totally unknown paper about other things. In CVPR, 2023.",
    "6": "Sara Fridovich-Keil, Alex Yu, Matthew Tancik, Qinhong Chen, Benjamin Recht, and Angjoo Kanazawa. "
         "Plenoxels: Radiance fields without neural networks. In CVPR, 2022.",
}


def write_paper(tmp_path: Path, sections: dict[str, str], title: str = "FooNeRF: A Test Radiance Field",
                abstract: str = "We present FooNeRF, a neural radiance field for novel view synthesis.",
                references: dict[str, str] | None = None, name: str = "paper.md"):
    """Write a markdown paper (sections in order: heading -> body) and ingest it."""
    refs = REFERENCES if references is None else references
    parts = [f"# {title}", "", "## Abstract", "", abstract, ""]
    for heading, body in sections.items():
        parts += [f"## {heading}", "", body.strip(), ""]
    if refs:
        parts += ["## References", ""] + [f"[{k}] {v}" for k, v in refs.items()] + [""]
    path = tmp_path / name
    path.write_text("\n".join(parts), encoding="utf-8")
    return ingest(path)


def real_paper(rel: str) -> Path:
    import pytest

    path = PAPERS / rel
    if not path.is_file():
        pytest.skip(f"real paper {path} not present (the shared papers folder {SHARED} is outside the project)")
    return path
