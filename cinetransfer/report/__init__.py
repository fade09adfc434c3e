"""Fidelity report of a run: how closely the recorded shot follows the source's style.

    from cinetransfer.report import build_report
    summary = build_report(outdir, source_style=..., output_style=..., truths=[...],
                           source_video=..., output_video=..., meta={...})

writes outdir/report.html (self-contained, offline), outdir/report.json and outdir/fig_*.png.
Modules: fidelity (pure metrics), figures (matplotlib Agg PNGs), html (the page),
truthfile (the run's GroundTruth log), style (path-or-message adapter), camera_motion (the
camera's moves: source, output, truth), cli
(`cinetransfer report RUN_DIR`). See docs/report.md.
"""
from __future__ import annotations

from typing import Any

__all__ = ["build_report"]


def build_report(*args: Any, **kwargs: Any) -> dict[str, Any]:
    """See `cinetransfer.report.build.build_report` (imported lazily: matplotlib loads on use)."""
    from cinetransfer.report.build import build_report as _build

    return _build(*args, **kwargs)
