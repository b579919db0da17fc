"""Is this a NeRF / radiance-field paper? A keyword score over title, abstract and body."""

from __future__ import annotations

import re

from nerfify_ns.paper.document import Document
from nerfify_ns.paper.errors import NotANerfPaperError

# (pattern, weight): strong signals first
SIGNALS = [
    (r"\bnerfs?\b|-nerf\b|nerf-|\w+nerf\b", 3.0),
    (r"radiance fields?", 3.0),
    (r"novel[- ]view synthesis|view synthesis", 2.0),
    (r"volume rendering|volumetric rendering|alpha compositing", 1.5),
    (r"transmittance", 1.0),
    (r"positional encoding|hash encoding|spherical harmonics", 1.0),
    (r"\bdensity\b|\bdensities\b", 0.5),
    (r"camera rays?|\brays?\b", 0.5),
    (r"scene representation|implicit (?:neural )?representation|3d gaussian splatting", 1.0),
    (r"mip-?nerf|instant-?ngp|plenoxels|tensorf|nerfacto|nerfstudio", 2.0),
]
THRESHOLD = 6.0


def nerf_score(doc: Document) -> tuple[float, dict]:
    """(score, hits per signal); title and abstract hits count three times."""
    head = f"{doc.title}\n{doc.abstract}".lower()
    body = doc.text().lower()
    score, hits = 0.0, {}
    for pat, weight in SIGNALS:
        n_head, n_body = len(re.findall(pat, head)), len(re.findall(pat, body))
        if n_body or n_head:
            hits[pat] = n_body
            score += weight * (min(n_body, 10) ** 0.5 + 2 * min(n_head, 3))
    return score, hits


def require_nerf_paper(doc: Document, threshold: float = THRESHOLD) -> float:
    """The score, or NotANerfPaperError when the document is not about NeRF / radiance fields."""
    score, hits = nerf_score(doc)
    if score < threshold:
        found = ", ".join(f"'{re.sub(r'[^a-z -]', '', p)[:20]}' x{n}"
                          for p, n in list(hits.items())[:4]) or "no NeRF terms"
        name = doc.title or doc.source
        raise NotANerfPaperError(f"'{name[:80]}' does not look like a NeRF / radiance-field paper (score {score:.1f} < "
                                 f"{threshold}; found {found}); pass a NeRF paper")
    return score
