"""Detector: people (box, confidence, mask), COCO-17 skeletons and an in-focus map per frame.

Public API (imported lazily, so `import cinetransfer.shared.measurements_file` stays light):

    from cinetransfer.services.detector import Detector, DetectorConfig, iter_frames
    from cinetransfer.services.detector import read_measurements, write_measurements

    with Detector(DetectorConfig()) as det:
        for f in iter_frames("clip.mp4"):
            m = det.process(f.image, f.index, f.stamp_ns, source="clip.mp4", fps=f.fps)

See docs/detector.md.
"""
from __future__ import annotations

import importlib
from typing import Any

_FRAMES = "cinetransfer.shared.frame_sources"
_MEAS = "cinetransfer.shared.measurements_file"
_EXPORTS = {
    "Detector": "core", "DetectorError": "core",
    "DetectorConfig": "config", "ConfigError": "config",
    "iter_frames": _FRAMES, "probe": _FRAMES, "FrameSourceError": _FRAMES, "SourceFrame": _FRAMES,
    "read_measurements": _MEAS, "write_measurements": _MEAS,
    "iter_measurements": _MEAS, "read_header": _MEAS,
    "MeasurementsWriter": _MEAS, "MeasurementsFile": _MEAS,
    "MeasurementsFileError": _MEAS,
    "FocusEstimator": "focus",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(mod if "." in mod else f"{__name__}.{mod}"), name)
