"""Command-line tools of the smoother:

    cinetransfer smooth measurements.msgpack -o style.json [--plot style.png]
    cinetransfer extract VIDEO -o style.json [--measurements m.msgpack] [--plot style.png]
    cinetransfer plot style.json -o style.png
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any, Iterable

from cinetransfer.services.smoother.config import STREAMING_FIELDS, SmootherConfig
from cinetransfer.shared import instructions as I
from cinetransfer.shared import nodeconfig
from cinetransfer.shared.errors import ConfigError, report_config_error
from cinetransfer.shared.instructions import StyleFileError, load_style_file
from cinetransfer.shared.measurements_file import (MeasurementsFileError, iter_measurements, read_header,
                                                   read_measurements)

log = logging.getLogger("cinetransfer.smoother")


def add_config_arguments(ap: argparse.ArgumentParser) -> None:
    """The smoother's flags for the batch tools (its config fields that name one, but streaming)."""
    nodeconfig.add_settings_arguments(ap, SmootherConfig, "smoother", skip=STREAMING_FIELDS)


def config_from_args(args: argparse.Namespace) -> SmootherConfig:
    """The code defaults with the flags that were given."""
    return nodeconfig.config_from_args(SmootherConfig, args, "smoother")


def _progress(it: Iterable[Any], total: int | None, desc: str, enabled: bool) -> Iterable[Any]:
    if not enabled:
        return it
    from tqdm import tqdm

    # disable=None: quiet when stderr is not a terminal (a log file, CI)
    return tqdm(it, total=total, desc=desc, unit="frame", file=sys.stderr, dynamic_ncols=True, disable=None)


def write_result(result: Any, out: Path, plot: Path | None, *, diagnostics: bool) -> None:
    warnings = tuple(getattr(result, "warnings", ()))
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    I.save_style(out, result.instructions, result.diagnostics if diagnostics else None, warnings)
    ins = result.instructions
    print(f"wrote {out}: {ins.image_targets.shape[0]} frames at {ins.fps:g} fps, subject visible in "
          f"{100.0 * ins.subject_visible.mean():.0f}% of frames, joints {', '.join(ins.joint_names)}")
    if plot is not None:
        from cinetransfer.services.smoother.plot import plot_style

        plot_style(I.load_style_file(out), plot)
        print(f"wrote {plot}")


def smooth_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="cinetransfer smooth", description="measurements file -> style.json")
    ap.add_argument("measurements", type=Path, help="measurements file written by 'cinetransfer detect'")
    ap.add_argument("-o", "--output", type=Path, default=Path("style.json"), help="style file to write")
    ap.add_argument("--plot", type=Path, default=None, help="also draw the style to this image")
    ap.add_argument("--no-diagnostics", action="store_true", help="leave the raw per-frame measures out")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--allow-truncated", action="store_true",
                    help="smooth the complete records of a file cut short (a warning) instead of refusing it")
    add_config_arguments(ap)
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args)
    except ConfigError as e:
        return report_config_error(e, "cinetransfer smooth")
    from cinetransfer.services.smoother.core import SmootherInputError, features_from_measurements, smooth_sequence

    try:
        header = read_header(args.measurements)
        total = header.source.n_frames or None
        # strict: a file cut short (crash, full disk, partial copy) is an error, not a silently
        # shorter style; --allow-truncated keeps the complete records and says so
        if args.allow_truncated:
            mf = read_measurements(args.measurements)
            if mf.truncated:
                print(f"warning: {args.measurements} is truncated: using its {len(mf.measurements)} complete "
                      f"measurements", file=sys.stderr)
            ms = iter(mf.measurements)
        else:
            ms = iter_measurements(args.measurements, strict=True)
        ms = _progress(ms, total, "reading", not args.quiet)
        feats = features_from_measurements(ms, cfg)
        t0 = time.perf_counter()
        result = smooth_sequence(feats, cfg, source=header.source if header.source.path else None)
        log.info("smoothed %d frames in %.1f ms", len(feats), 1e3 * (time.perf_counter() - t0))
    except (MeasurementsFileError, SmootherInputError) as e:
        print(f"cinetransfer smooth: {e}", file=sys.stderr)
        return 1
    write_result(result, args.output, args.plot, diagnostics=not args.no_diagnostics)
    return 0


def plot_main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="cinetransfer plot", description="draw a style.json (Figs 3c/4b/5c style)")
    ap.add_argument("style", type=Path, help="style file")
    ap.add_argument("-o", "--output", type=Path, default=None, help="image to write (default: STYLE.png)")
    ap.add_argument("--joint", default="chest", help="joint to plot: 'chest' or a COCO-17 name")
    ap.add_argument("--title", default=None)
    args = ap.parse_args(argv)
    from cinetransfer.services.smoother.plot import plot_style, summary

    out = args.output or args.style.with_suffix(".png")
    try:
        style = load_style_file(args.style)
        plot_style(style, out, joint=args.joint, title=args.title)
    except (StyleFileError, ValueError) as e:
        print(f"cinetransfer plot: {e}", file=sys.stderr)
        return 1
    print(f"wrote {out}: {json.dumps(summary(style))}")
    return 0
