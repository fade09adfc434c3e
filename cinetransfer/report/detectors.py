"""Which detector backend measured the source's style and the output's, as the report states it.

A fallback backend (the box-first models missing where the detector ran:
cinetransfer/detector_backend.py) measures otherwise than the box-first detector a user's install
runs, and source and output measured by different backends are not measured the same way: the
extraction's joint errors and focus agreements then compare two instruments as well as two
videos. Neither is a degraded take (the drone flew its instructions), so no goal is voided; both
are stated in the headline and on the page.
"""
from __future__ import annotations

from typing import Any

from cinetransfer.detector_backend import fix, is_fallback


def detector_facts(meta: dict[str, Any]) -> dict[str, Any]:
    """{source, output: the pass's record or None (not known), same_backend: bool or None,
    notes: what the report states}, from meta.json's "detectors"."""
    dets = meta.get("detectors") or {}
    src, out = dets.get("source"), dets.get("output")
    notes = [f"the {which} style was measured by the detector's fallback backend '{d['backend']}' "
             f"({d['fallback']}), not the box-first one{fix(d)}"
             for which, d in (("source", src), ("output", out)) if is_fallback(d)]
    same = None
    if src and out:
        same = src.get("backend") == out.get("backend")
        if not same:
            notes.append(f"source and output were not measured the same way: the source by '{src.get('backend')}', "
                         f"the output by '{out.get('backend')}'; the extraction's errors and agreements compare "
                         "two detectors as well as two videos")
    return {"source": src, "output": out, "same_backend": same, "notes": notes}
