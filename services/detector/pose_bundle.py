"""Build MediaPipe's multi-person pose `.task` bundle offline, from the wheel's own model files.

mediapipe 0.10.21 ships `modules/pose_detection/pose_detection.tflite` (the person detector) and
`modules/pose_landmark/pose_landmark_full.tflite` (33 landmarks + segmentation), but the Tasks API
(`PoseLandmarker`, which handles several people and gives one mask each) wants a `.task` zip that
is normally downloaded. We add the image-input metadata the Tasks API needs with mediapipe's own
metadata writer and zip the two models (DESIGN §5):

- pose_detector.tflite:           input normalised to [-1, 1] (mean 127.5, std 127.5)
- pose_landmarks_detector.tflite: input normalised to [0, 1]  (mean 0, std 255)

The bundle is cached in $CT_CACHE_DIR (default ~/.cache/cinetransfer) under a name that includes
a hash of both source models, so a different mediapipe wheel gets its own bundle. Building takes
about a second; the write is atomic (temp file + rename) so concurrent first uses are safe.
"""
from __future__ import annotations

import gc
import hashlib
import logging
import os
import tempfile
import warnings
from pathlib import Path

from cinetransfer.shared import paths

log = logging.getLogger("cinetransfer.detector")

DETECTOR_REL = ("modules", "pose_detection", "pose_detection.tflite")
LANDMARK_REL = ("modules", "pose_landmark", "pose_landmark_full.tflite")


class BundleError(RuntimeError):
    """The pose bundle cannot be built (mediapipe missing or without its model files)."""


def cache_dir() -> Path:
    """shared/paths.cache_dir(): $CT_CACHE_DIR, else $XDG_CACHE_HOME/cinetransfer (~/.cache/cinetransfer)."""
    return paths.cache_dir()


def _mediapipe_dir() -> Path:
    try:
        import mediapipe
    except ImportError as e:
        raise BundleError("mediapipe is not installed: install mediapipe==0.10.21 with --no-deps "
                          "(see docs/detector.md)") from e
    return Path(mediapipe.__file__).resolve().parent


def source_models() -> tuple[Path, Path]:
    """Paths of the detector and landmark tflite files inside the installed mediapipe wheel."""
    root = _mediapipe_dir()
    det, lmk = root.joinpath(*DETECTOR_REL), root.joinpath(*LANDMARK_REL)
    for p in (det, lmk):
        if not p.is_file():
            raise BundleError(f"{p} is missing: this mediapipe wheel does not ship the pose models "
                              "(0.10.21 is the last release that does)")
    return det, lmk


def _with_image_metadata(model: bytes, name: str, mean: float, std: float) -> bytes:
    from mediapipe.tasks.python.metadata.metadata_writers import metadata_writer

    # mediapipe's metadata populator leaves temporary files open; let them be collected here,
    # quietly, rather than as ResourceWarnings at some later garbage collection.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResourceWarning)
        writer = metadata_writer.MetadataWriter.create(bytearray(model))
        writer.add_general_info(name, f"{name} (built offline by cinetransfer from the mediapipe wheel)")
        writer.add_image_input(norm_mean=[mean], norm_std=[std])
        content, _ = writer.populate()
        del writer
        gc.collect()
    return bytes(content)


def build_bundle(out_path: Path) -> Path:
    """Write the `.task` bundle to `out_path` (atomically)."""
    from mediapipe.tasks.python.metadata.metadata_writers import model_asset_bundle_utils

    det, lmk = source_models()
    models = {
        "pose_detector.tflite": _with_image_metadata(det.read_bytes(), "pose_detector", 127.5, 127.5),
        "pose_landmarks_detector.tflite": _with_image_metadata(lmk.read_bytes(), "pose_landmarks_detector",
                                                               0.0, 255.0),
    }
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=out_path.name, suffix=".tmp", dir=out_path.parent)
    os.close(fd)
    try:
        model_asset_bundle_utils.create_model_asset_bundle(models, tmp)
        os.replace(tmp, out_path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out_path


def bundle_path(*, build: bool = True) -> Path:
    """Path of the cached bundle for the installed mediapipe; built on first use."""
    det, lmk = source_models()
    h = hashlib.sha256()
    for p in (det, lmk):
        h.update(p.read_bytes())
    path = cache_dir() / f"pose_landmarker_full_{h.hexdigest()[:12]}.task"
    if build and not path.is_file():
        log.info("building the pose task bundle %s from the mediapipe wheel", path)
        build_bundle(path)
    return path
