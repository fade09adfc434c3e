"""`cinetransfer detect VIDEO -o measurements.msgpack [--overlay out.mp4]`: measure a whole video.

Writes a measurements file (see measurements_file.py / docs/detector.md), one Measurement per
decoded frame, streamed as it goes (an interrupted run leaves a readable file). Exit codes:
0 = done; 1 = the source cannot be read (message says why) or the detector cannot start;
2 = bad arguments; 130 = interrupted (what was measured so far is kept).
"""
from __future__ import annotations

import argparse
import collections
import logging
import sys
import time
from pathlib import Path
from typing import Any

from cinetransfer.services.detector.config import add_config_arguments, config_from_args
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.frame_sources import FrameSourceError, iter_frames, probe
from cinetransfer.shared.measurements_file import MeasurementsWriter

log = logging.getLogger("cinetransfer.detector")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinetransfer detect", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", help="video file (anything OpenCV decodes) or a folder of images")
    ap.add_argument("-o", "--output", required=True, help="measurements file to write (.msgpack)")
    ap.add_argument("--overlay", metavar="VIDEO", default=None,
                    help="also write a video with boxes, masks, skeletons and the focus map drawn (.mp4/.avi)")
    ap.add_argument("--start", type=int, default=0, help="first frame index (default 0)")
    ap.add_argument("--stop", type=int, default=None, help="stop before this frame index")
    ap.add_argument("--fps", type=float, default=None, help="override the source frame rate (image folders: 24)")
    ap.add_argument("--hash", action="store_true", help="record the source file's sha256 in the header")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    add_config_arguments(ap)
    return ap


def _start(args: argparse.Namespace) -> tuple[Any, Any, Path, Any] | int:
    """(config, source info, output path, detector), or the exit status when one of them fails."""
    try:
        cfg = config_from_args(args)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer detect")
    if args.start < 0 or (args.stop is not None and args.stop <= args.start):
        log.error("--start/--stop: need 0 <= start < stop")
        return 2
    from cinetransfer.services.detector.core import Detector, DetectorError

    try:
        info = probe(args.source, hash_file=args.hash, fps=args.fps)
    except FrameSourceError as e:
        log.error("cannot read the source: %s", e)
        return 1
    out = Path(args.output)
    if out.parent and not out.parent.exists():
        log.error("output folder %s does not exist", out.parent)
        return 1
    try:
        return cfg, info, out, Detector(cfg)
    except (DetectorError, OSError, RuntimeError) as e:
        log.error("detector cannot start: %s", e)
        return 1


class _Run:
    """Frames measured, people seen and the overlay of one `detect` run."""

    def __init__(self) -> None:
        self.n, self.people, self.overlay, self.t0 = 0, 0, None, time.perf_counter()

    def measure(self, args: argparse.Namespace, cfg: Any, info: Any, out: Path, det: Any) -> None:
        from tqdm import tqdm

        total = info.n_frames
        if total:
            total = max(0, min(total, args.stop if args.stop is not None else total) - args.start)
        with MeasurementsWriter(out, source=info, detector=det.name, config=cfg,
                                focus_map_scale=det.focus_map_scale(info.width, info.height)) as writer, \
                tqdm(total=total or None, unit="frame", disable=True if args.no_progress else None, dynamic_ncols=True,
                     desc=Path(args.source).name) as bar:
            read: collections.deque = collections.deque()  # frames handed to the detector, not yet measured

            def frames():
                for f in iter_frames(args.source, start=args.start, stop=args.stop, fps=args.fps):
                    read.append(f)
                    yield f

            for m in det.process_frames(frames(), source=info.path):  # measured in order, a frame or two behind
                f = read.popleft()
                writer.write(m)
                if args.overlay:
                    self._overlay(args.overlay, f, m)
                self.n += 1
                self.people += len(m.people)
                bar.update(1)
                bar.set_postfix(fps=f"{self.n / max(1e-9, time.perf_counter() - self.t0):.1f}",
                                people=len(m.people), refresh=False)

    def _overlay(self, path: str, f: Any, m: Any) -> None:
        if self.overlay is None:
            from cinetransfer.services.detector.overlay import OverlayWriter

            self.overlay = OverlayWriter(path, f.fps, f.image.shape[1], f.image.shape[0])
        self.overlay.write(f.image, m)


def main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level), format="%(levelname)s %(name)s: %(message)s")
    started = _start(args)
    if isinstance(started, int):
        return started
    cfg, info, out, det = started

    run, rc = _Run(), 0
    try:
        run.measure(args, cfg, info, out, det)
    except FrameSourceError as e:
        log.error("cannot read the source: %s", e)
        rc = 1
    except KeyboardInterrupt:
        log.warning("interrupted: kept %d measurements", run.n)
        rc = 130
    except OSError as e:
        log.error("%s", e)
        rc = 1
    finally:
        det.close()
        if run.overlay is not None:
            run.overlay.close()
    dt = time.perf_counter() - run.t0
    if run.n:
        log.info("%d frames in %.1f s (%.1f frames/s), %.2f people/frame -> %s%s", run.n, dt, run.n / dt,
                 run.people / run.n, out, f", overlay {args.overlay}" if run.overlay is not None else "")
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
