"""Camera poses from the images alone, as ``ns-process-data images`` estimates them, with COLMAP's Python
bindings (``pycolmap``, CPU).

Nerfstudio 1.1.5's ``ns-process-data`` runs the COLMAP program (``process_data/colmap_utils.run_colmap``):
SIFT features with one shared camera of model ``OPENCV``, matching, the incremental mapper (global bundle
adjustment tolerance 1e-6), then a bundle adjustment that also refines the principal point; then
``colmap_to_json`` writes ``transforms.json`` from the model (OpenCV -> OpenGL camera axes, the world turned so
that z is up, the ``applied_transform`` recorded) and a ``sparse_pc.ply``. We run the same steps through
pycolmap (exhaustive matching: a small capture needs no vocabulary tree, which ns-process-data would download)
and call Nerfstudio's own ``colmap_to_json`` on the result, so the folder is what a user's ns-process-data run
gives: ``images/``, ``colmap/sparse/0/{cameras,images,points3D}.bin`` (and COLMAP's log, ``colmap/colmap.log``),
``transforms.json``, ``sparse_pc.ply``.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .errors import SceneError
from .pbr import RendererUnavailable

CAMERA_MODEL = "OPENCV"
"""ns-process-data's default camera model (``--camera-type perspective``)."""
MIN_REGISTERED = 3


class PoseEstimationError(SceneError):
    """COLMAP could not register enough of the images."""


@dataclass(frozen=True)
class SfmResult:
    registered: int
    """Images with an estimated pose."""
    images: int
    """Images given."""
    points: int
    """Triangulated 3D points."""
    mean_reprojection_error: float
    """Pixels, over the model's points."""


def pycolmap_module():
    try:
        import pycolmap
    except ImportError:
        raise RendererUnavailable("estimating poses needs pycolmap (pip install 'nerfify-ns[scenes]', or "
                                  "scripts/setup.sh --dev)") from None
    return pycolmap


def estimate_poses(folder: Path, seed: int = 0) -> SfmResult:
    """Run COLMAP on ``folder/images`` and write ``folder/colmap/sparse/0`` and ``folder/transforms.json``
    (Nerfstudio's ``colmap_to_json``). Raises :class:`PoseEstimationError` when fewer than 3 images register."""
    pycolmap = pycolmap_module()
    log = folder / "colmap" / "colmap.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    with _stderr_to(log):  # COLMAP logs every step to stderr (as ns-process-data's non-verbose runs, kept in a file)
        return _estimate(pycolmap, folder, seed)


@contextmanager
def _stderr_to(path: Path) -> Iterator[None]:
    """File descriptor 2 (where COLMAP's C++ logging writes) redirected to ``path`` for the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    with open(path, "ab") as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)


def _estimate(pycolmap, folder: Path, seed: int) -> SfmResult:
    images = folder / "images"
    colmap_dir = folder / "colmap"
    sparse = colmap_dir / "sparse"
    sparse.mkdir(parents=True, exist_ok=True)
    database = colmap_dir / "database.db"
    pycolmap.set_random_seed(seed)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = CAMERA_MODEL
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.use_gpu = False
    extraction.num_threads = 2
    pycolmap.extract_features(database, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=extraction, device=pycolmap.Device.cpu)
    pycolmap.match_exhaustive(database, device=pycolmap.Device.cpu)
    options = pycolmap.IncrementalPipelineOptions()
    options.ba_global_function_tolerance = 1e-6  # as ns-process-data passes to the mapper
    options.random_seed = seed
    options.num_threads = 2
    # COLMAP's defaults expect photographs with thousands of features; our captures are a few hundred pixels a
    # side (a few hundred features an image), so the initial pair and each registration need fewer inliers
    options.mapper.init_min_num_inliers = 50
    options.mapper.abs_pose_min_num_inliers = 15
    models = pycolmap.incremental_mapping(database, images, sparse, options=options)
    n_images = len([p for p in images.iterdir() if p.is_file()])
    if not models:
        raise PoseEstimationError(f"COLMAP registered none of the {n_images} images (too few features; render "
                                  "larger images, or write exact poses with --poses exact)")
    best = max(models, key=lambda k: models[k].num_reg_images())
    model = models[best]
    if model.num_reg_images() < MIN_REGISTERED:
        raise PoseEstimationError(f"COLMAP registered {model.num_reg_images()} of {n_images} images (at least "
                                  f"{MIN_REGISTERED}); render larger images, or write exact poses with --poses exact")
    ba = pycolmap.BundleAdjustmentOptions()
    ba.refine_principal_point = True  # ns-process-data's bundle_adjuster step (refine_intrinsics)
    ba.print_summary = False
    pycolmap.bundle_adjustment(model, ba)
    for child in sparse.iterdir():
        shutil.rmtree(child)
    final = sparse / "0"
    final.mkdir()
    model.write_binary(str(final))
    database.unlink(missing_ok=True)
    from nerfstudio.process_data.colmap_utils import colmap_to_json

    colmap_to_json(final, folder)
    errors = [p.error for p in model.points3D.values()]
    return SfmResult(model.num_reg_images(), n_images, len(errors), float(sum(errors) / max(len(errors), 1)))
