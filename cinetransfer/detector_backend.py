"""Which pose backend measured a style, and the one line a transfer says when it was a fallback.

When the box-first backend's models are missing (npm was missing at setup, or a transfer started
while ./setup.sh was still installing them) the detector runs MediaPipe's landmarker instead
(services/detector/core.make_backend). That is another measuring instrument, not the same one
degraded: on the README clip its style differed from the box-first one in 1976 image-target
values, 987 subject-box values and 3 focus labels. So a transfer names the backend of each
detector pass in meta.json ("detectors": source, output), says so once in its log, never keeps
such a style in the style cache, and its report states it (report/detectors.py).
"""
from __future__ import annotations

from typing import Any

#: how to get the box-first backend back
FIX = "re-run ./setup.sh to install the box-first models (it needs npm: docs/detector.md, 'Without npm')"
#: the reason given when only the backend's name says it is a fallback
UNKNOWN_REASON = "the box-first backend is not installed where the detector ran"


def facts(backend: str, unavailable: str = "") -> dict[str, Any]:
    """meta.json's record of one detector pass: the backend's name and, for a fallback, why the
    configured backend did not run (None: it did)."""
    from cinetransfer.services.detector.box_models import FALLBACK_SUFFIX

    reason = unavailable or (UNKNOWN_REASON if backend.endswith(FALLBACK_SUFFIX) else "")
    return {"backend": backend, "fallback": reason or None}


def of_detector(det: Any) -> dict[str, Any]:
    """`facts` of a services.detector.core.Detector."""
    return facts(det.name, det.unavailable)


def is_fallback(f: dict[str, Any] | None) -> bool:
    return bool(f and f.get("fallback"))


def fix(f: dict[str, Any]) -> str:
    """How to get the box-first backend back, unless the reason of `f` says it already."""
    return "" if "setup.sh" in str(f.get("fallback")) else f"; {FIX}"


def warning(which: str, f: dict[str, Any], consequence: str) -> str:
    """The log line of a pass that ran a fallback backend (`which`: 'source style', ...)."""
    return (f"{which}: the detector ran the fallback backend '{f['backend']}' ({f['fallback']}), which measures "
            f"otherwise than the box-first detector{consequence}{fix(f)}")
