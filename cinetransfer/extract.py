"""Detector + smoother features in one process: a video file in, per-frame features out.

`cinetransfer extract` (`main`) and the evaluation scripts use it. It joins two services, so it
lives above them; the detector is imported lazily, so loading this module stays light.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any, Iterator

from cinetransfer.services.smoother.cli import add_config_arguments, config_from_args, write_result
from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.core import SmootherInputError, feature_options, smooth_sequence
from cinetransfer.services.smoother.features import FrameFeatures, frame_features
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.messages import Measurement, SourceInfo


class ExtractError(RuntimeError):
    """The video cannot be read or the detector cannot run."""


def measure_video(video: str | os.PathLike, *, detector_config: Any = None, stop: int | None = None,
                  progress: bool = False) -> tuple[Iterator[Measurement], SourceInfo, Any]:
    """(measurement iterator, source info, detector) for a video; close the detector when done."""
    try:
        from cinetransfer.services.detector.config import DetectorConfig
        from cinetransfer.services.detector.core import Detector, DetectorError
        from cinetransfer.shared.frame_sources import FrameSourceError, probe
    except ImportError as e:  # pragma: no cover - a build without the detector
        raise ExtractError(f"the detector is not available in this build ({e})") from None
    try:
        source = probe(video, hash_file=True)
        det = Detector(detector_config or DetectorConfig())
    except (FrameSourceError, DetectorError, OSError) as e:
        raise ExtractError(str(e)) from None
    total = source.n_frames if stop is None else min(source.n_frames or stop, stop)
    it: Iterator[Measurement] = det.process_source(str(video), stop=stop)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, total=total or None, desc=f"extract {Path(video).name}", unit="frame", file=sys.stderr,
                  dynamic_ncols=True, disable=None)  # None: quiet when stderr is not a terminal

    def guarded() -> Iterator[Measurement]:
        try:
            yield from it
        except FrameSourceError as e:
            raise ExtractError(str(e)) from None

    return guarded(), source, det


def extract_features(video: str | os.PathLike, cfg: SmootherConfig, *,
                     measurements_path: str | os.PathLike | None = None,
                     stop: int | None = None, progress: bool = False,
                     detector_config: Any = None, measured_by: dict | None = None
                     ) -> tuple[list[FrameFeatures], SourceInfo]:
    """Run the detector over a video and keep the smoother's features of every frame (optionally
    also writing the measurements file; `measured_by` is filled with the detector's backend,
    cinetransfer/detector_backend.facts)."""
    ms, source, det = measure_video(video, detector_config=detector_config, stop=stop, progress=progress)
    if measured_by is not None:
        from cinetransfer.detector_backend import of_detector

        measured_by.update(of_detector(det))
    opts = feature_options(cfg)
    feats: list[FrameFeatures] = []
    writer = None
    try:
        if measurements_path is not None:
            from cinetransfer.shared.measurements_file import MeasurementsWriter

            writer = MeasurementsWriter(measurements_path, source=source, detector=det.name, config=det.cfg,
                                        focus_map_scale=det.focus_map_scale(source.width, source.height))
        for m in ms:
            if writer is not None:
                writer.write(m)
            feats.append(frame_features(m, **opts))
    finally:
        if writer is not None:
            writer.close()
        det.close()
    if not feats:
        raise ExtractError(f"{video}: no frame could be read")
    return feats, source


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="cinetransfer extract",
                                 description="video -> style.json (detector and smoother in one process)")
    ap.add_argument("video", help="source video file (or image folder)")
    ap.add_argument("-o", "--output", type=Path, default=Path("style.json"), help="style file to write")
    ap.add_argument("--measurements", type=Path, default=None, help="also keep the measurements in this file")
    ap.add_argument("--plot", type=Path, default=None, help="also draw the style to this image")
    ap.add_argument("--no-diagnostics", action="store_true", help="leave the raw per-frame measures out")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--stop", type=int, default=None, help="stop after this many frames")
    ap.add_argument("--cuts", default=None, metavar="ROWS",
                    help="rows where shots begin, comma-separated, instead of finding them ('' = one shot)")
    add_config_arguments(ap)
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args)
        cuts = None if args.cuts is None else [int(r) for r in args.cuts.split(",") if r.strip()]
    except ConfigError as e:
        return report_config_error(e, "cinetransfer extract")
    except ValueError as e:  # --cuts is not a list of row numbers
        print(f"cinetransfer extract: --cuts: {e}", file=sys.stderr)
        return 2
    det: dict = {}
    try:
        feats, source = extract_features(args.video, cfg, measurements_path=args.measurements, stop=args.stop,
                                         progress=not args.quiet, measured_by=det)
        result = smooth_sequence(feats, cfg, source=source, known_cuts=cuts)
    except (ExtractError, SmootherInputError) as e:
        print(f"cinetransfer extract: {e}", file=sys.stderr)
        return 1
    result = _name_detector(result, det)
    write_result(result, args.output, args.plot, diagnostics=not args.no_diagnostics)
    return 0


def _name_detector(result: Any, det: dict) -> Any:
    """The style says which backend measured it (diagnostics "detector"), and a fallback one in
    its warnings too, which --no-diagnostics keeps (cinetransfer/detector_backend.py)."""
    import dataclasses

    from cinetransfer.detector_backend import is_fallback, warning

    result.diagnostics["detector"] = det
    if is_fallback(det):
        result = dataclasses.replace(result, warnings=(*result.warnings, warning("measured", det, "")))
    return result
