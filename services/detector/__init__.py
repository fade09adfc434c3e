"""Detector: people (box, confidence, mask), COCO-17 skeletons and an in-focus map per frame.

Public API (imported lazily, so `import cinetransfer.services.detector.measurements_file` stays light):

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

_EXPORTS = {
    "Detector": "core", "DetectorError": "core",
    "DetectorConfig": "config", "ConfigError": "config",
    "iter_frames": "sources", "probe": "sources", "FrameSourceError": "sources", "SourceFrame": "sources",
    "read_measurements": "measurements_file", "write_measurements": "measurements_file",
    "iter_measurements": "measurements_file", "read_header": "measurements_file",
    "MeasurementsWriter": "measurements_file", "MeasurementsFile": "measurements_file",
    "MeasurementsFileError": "measurements_file",
    "FocusEstimator": "focus",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{mod}"), name)
