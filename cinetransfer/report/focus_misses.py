"""Why a frame's focus label is not the source's, per frame, region and side (pure numpy).

For every compared frame and region the source has, each side (the simulator's truth, the extraction on
the output video) gets one kind ('' where it gives the source's label):

- 'out_of_reach': no lens setting gives the label (reach_frames: the reason names the limit: the
  f-number, the focus range, the region's depth, the lens's hold or its rates); left out of the goals;
- 'controller': within reach, and the flight filmed the other label (the truth's depth of field and
  the region's share inside it are named, and where the lens gives the frame's labels together with how
  soft that leaves the soft regions at best: focus_reach.label_window);
- 'extraction': the truth has the source's label and the extraction on the output reads the other;
- 'absent': the side sees no such region in the frame (left out of the agreement, counted as
  "source only");
- 'unjudged': the side reads the other label where the truth has no label of its own: it sees no
  such region there (with or without the band's depths: a band below the feet too short to be a
  foreground keeps them, and is judged for reach), or records no depths or lens range;
- 'no_data': the side has nothing for the frame (no truth, no extraction row).

Every frame a region's agreement does not count as agreeing has exactly one kind, so the kinds add
up to the frames missed plus the frames the source has the region and the side does not.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from cinetransfer.report import focus_reach as FR
from cinetransfer.report import reach_frames as RF
from cinetransfer.shared import messages as M
from cinetransfer.shared.camera import REGION_IN_FOCUS_SHARE

REGIONS: tuple[str, ...] = M.FOCUS_REGIONS
KINDS: tuple[str, ...] = ("out_of_reach", "controller", "extraction", "absent", "unjudged", "no_data")
SIDES: tuple[str, ...] = ("truth", "extraction")
_WHO = {"truth": "the truth", "extraction": "the output's extraction"}


@dataclass(frozen=True, eq=False)
class Misses:
    """Per frame and region of one side: the kind ('' = the source's label) and the reason."""

    kind: np.ndarray  # (N, 3) object (str)
    why: np.ndarray  # (N, 3) object (str)


def _label(sharp: bool) -> str:
    return "sharp" if sharp else "soft"


def _share(frac: float) -> str:
    return f"{frac:.0%}" if np.isfinite(frac) else "an unknown share"


def _dof_words(t: M.GroundTruth | None) -> str:
    """The flight's depth of field in the frame, from the truth ('' when not recorded)."""
    if t is None or not (np.isfinite(t.dof_near_m) and t.dof_near_m > 0):
        return ""
    far = f"{t.dof_far_m:.3g} m" if np.isfinite(t.dof_far_m) else "infinity"
    return f" inside the depth of field {t.dof_near_m:.3g} m to {far}"


def _controller_why(r: int, asked: bool, frac: float, t: M.GroundTruth | None, window: str = "") -> str:
    return (f"{REGIONS[r]} {_label(asked)} was within the lens's reach{window}; the flight filmed it "
            f"{_label(not asked)} ({_share(frac)} of its pixels{_dof_words(t)}; in focus from "
            f"{REGION_IN_FOCUS_SHARE:.0%})")


def window_words(asked: np.ndarray, present: np.ndarray, t: M.GroundTruth | None) -> str:
    """Where the lens gives the frame's present labels together, from the truth's depths and lens
    (focus_reach.label_window): the settings' span and how soft the soft regions can be at best ('' when the
    truth has no depths or lens range, or nothing gives them)."""
    lens = RF.lens_of(t) if t is not None else None
    if lens is None:
        return ""
    w = FR.label_window(lens, asked, present, np.asarray(t.region_inverse_depth, float))
    if w is None:
        return ""
    labels = ", ".join(f"{REGIONS[k]} {_label(bool(asked[k]))}" for k in FR.PRIORITY if present[k])
    soft = "" if w.soft_circles is None else (f", the soft regions' medians at most {w.soft_circles:.2f} circles "
                                              f"soft, at f/{w.best[0]:.3g} and {w.best[1]:.3g} m")
    return (f" ({labels} together at f/{w.f_number[0]:.3g}-{w.f_number[1]:.3g} with the focus "
            f"{w.focus_m[0]:.3g}-{w.focus_m[1]:.3g} m{soft})")


def explain(src: Any, side: Any, truth: Any, reach: Any, truths: Sequence[M.GroundTruth | None],
            name: str) -> Misses:
    """The kinds and reasons of side `name` ('truth' or 'extraction'): src, side and truth are
    fidelity.Track on one timeline; reach a reach_frames.Reach on it; truths the GroundTruth per frame."""
    n = src.n
    kind = np.full((n, 3), "", dtype=object)
    why = np.full((n, 3), "", dtype=object)
    for i in range(n):
        for r in range(3):
            if not (src.available[i] and src.present[i, r]):
                continue
            k, w = _one(i, r, src, side, truth, reach, truths[i] if i < len(truths) else None, name)
            kind[i, r], why[i, r] = k, w
    return Misses(kind, why)


def _one(i: int, r: int, src: Any, side: Any, truth: Any, reach: Any, t: M.GroundTruth | None,
         name: str) -> tuple[str, str]:
    asked = bool(src.focus_in[i, r])
    who = _WHO[name]
    if not side.available[i]:
        return "no_data", f"{who} has no data for this frame"
    if not side.present[i, r]:
        return "absent", f"{who} sees no {REGIONS[r]} in this frame (the source's is {_label(asked)})"
    if bool(side.focus_in[i, r]) == asked:
        return "", ""
    if reach.unreachable[i, r]:
        return "out_of_reach", str(reach.reasons[i, r])
    truth_has = truth.available[i] and truth.present[i, r]
    if name == "extraction" and truth_has and bool(truth.focus_in[i, r]) == asked:
        return "extraction", (f"the truth has {REGIONS[r]} {_label(asked)} ({_share(truth.frac[i, r])} of its "
                              f"pixels in focus), the output's extraction reads it {_label(not asked)} "
                              f"({_share(side.frac[i, r])} of its pixels read sharp)")
    if not truth_has:
        if reach.judged[i] and _has_depths(t, r):
            return "unjudged", (f"{who} reads {REGIONS[r]} {_label(not asked)} where the source has it "
                                f"{_label(asked)}; within the lens's reach by the truth's depths, but the truth "
                                f"counts no {REGIONS[r]} in this frame (the band below the feet under the "
                                "foreground's share of the frame), so no label of its own to tell the flight "
                                "from the extraction")
        return "unjudged", (f"{who} reads {REGIONS[r]} {_label(not asked)} where the source has it {_label(asked)}; "
                            f"the truth sees no {REGIONS[r]} in this frame, so no depths to judge its reach by")
    if not reach.judged[i]:
        return "unjudged", (f"{who} reads {REGIONS[r]} {_label(not asked)} where the source has it {_label(asked)}; "
                            "the truth records no region depths or lens range to judge its reach by")
    # the labels the verdict grants together: a region out of reach is left out of the combination (focus_reach)
    judged = np.asarray(src.present[i], bool) & np.asarray(truth.present[i], bool) & ~np.asarray(reach.unreachable[i])
    return "controller", _controller_why(r, asked, float(truth.frac[i, r]), t,
                                         window_words(np.asarray(src.focus_in[i], bool), judged, t))


def _has_depths(t: M.GroundTruth | None, r: int) -> bool:
    inv = np.asarray(t.region_inverse_depth, float) if t is not None else np.zeros((0, 0))
    return inv.ndim == 2 and inv.shape[0] == 3 and inv.shape[1] > 0 and bool(np.isfinite(inv[r]).all())


def counts(m: Misses) -> dict[str, dict[str, int]]:
    """Per region, the frames of each kind (every kind listed, 0 included)."""
    return {reg: {k: int((m.kind[:, r] == k).sum()) for k in KINDS} for r, reg in enumerate(REGIONS)}


def runs(m: Misses, t_s: np.ndarray, side: str) -> list[dict[str, Any]]:
    """Consecutive frames of one kind per region as report rows: side, region, kind, first and last
    output frame, frames, time span, and the reason at the first and last frame."""
    out = []
    for r, reg in enumerate(REGIONS):
        col = m.kind[:, r]
        idx = np.flatnonzero(col != "")
        if idx.size == 0:
            continue
        cut = np.flatnonzero((np.diff(idx) > 1) | (col[idx[1:]] != col[idx[:-1]])) + 1
        for seg in np.split(idx, cut):
            a, b = int(seg[0]), int(seg[-1])
            first, last = str(m.why[a, r]), str(m.why[b, r])
            out.append({"side": side, "region": reg, "kind": str(col[a]), "first_frame": a, "last_frame": b,
                        "frames": int(seg.size), "t_s": [float(t_s[a]), float(t_s[b])],
                        "reason": first, "reason_last": last if last != first else None})
    return out
