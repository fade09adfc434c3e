"""Per-frame features: the compact part of a Measurement the smoother needs.

A Measurement carries masks and a focus map; keeping thousands of them in memory is wasteful,
and everything the optimisation needs can be computed once per frame, at ingestion:

- candidate boxes and confidences (main-subject selection);
- each person's mask as a coarse occupancy grid over its own box, so that
  g(m, R) = pixels of mask m inside a box R (DESIGN §1.1 step 2) can be evaluated later for the
  smoothed box R_f;
- each skeleton's joints and the count of its joints inside each person's mask
  (h(p, M) of step 2, independent of R_f);
- the focused fraction b of each focus region for each choice of subject (step 4): for person m
  as the subject, (foreground = band below m's feet, subject = m's mask, background = the rest),
  and for "no subject visible" (background = the whole frame).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from cinetransfer.services.smoother.anatomy import drop_implausible_bodies
from cinetransfer.shared.focus_regions import FOREGROUND_MIN_ROWS, foreground_present, region_masks
from cinetransfer.shared.focus_regions import feet_row as mask_feet_row
from cinetransfer.shared.messages import COCO17_NAMES, Measurement

N_JOINTS = len(COCO17_NAMES)
GRID = 16  # occupancy grid size (cells per side, at most)


@dataclass(frozen=True, eq=False)
class FrameFeatures:
    """What the smoother keeps of one Measurement."""

    frame_index: int
    stamp_ns: int = 0
    width: int = 0
    height: int = 0
    fps: float = float("nan")
    source: str = ""
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # (M, 4) x0 y0 x1 y1 [px]
    conf: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (M,)
    track: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (M,) detector track id, -1 = none
    grids: np.ndarray = field(default_factory=lambda: np.zeros((0, GRID, GRID)))  # (M, G, G) mask occupancy in [0, 1]
    grid_x: np.ndarray = field(default_factory=lambda: np.zeros((0, GRID + 1)))  # (M, G+1) cell edges [px]
    grid_y: np.ndarray = field(default_factory=lambda: np.zeros((0, GRID + 1)))  # (M, G+1) cell edges [px]
    joints: np.ndarray = field(default_factory=lambda: np.zeros((0, N_JOINTS, 2)))  # (P, 17, 2) [px], NaN = missing
    joint_conf: np.ndarray = field(default_factory=lambda: np.zeros((0, N_JOINTS)))  # (P, 17)
    inside: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=int))  # (P, M) joints of p in mask m
    focus: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (M, 3) b per region, m as subject
    focus_none: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # (3,) b with no subject
    has_focus: bool = False  # a focus map was measured
    valid: bool = True
    shot_change: float = float("nan")  # detector's colour distance to the previous frame; NaN = unknown
    #: the camera's motion since the previous frame: pan, tilt, roll [rad], log-zoom, translation
    #: direction (3,); NaN = unknown (shared/camera_motion.py)
    motion: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))

    n_people: int = -1  # set from boxes

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_people", int(self.boxes.shape[0]))

    def mask_pixels_inside(self, m: int, box: np.ndarray) -> float:
        """g(m, R): (approximate) pixels of person m's mask inside box R = (x0, y0, x1, y1) [px]."""
        return float(mask_pixels_inside(self.grids[m:m + 1], self.grid_x[m:m + 1], self.grid_y[m:m + 1],
                                        np.asarray(box, dtype=float)[None, :])[0])


def mask_pixels_inside(grids: np.ndarray, gx: np.ndarray, gy: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Batched g: grids (N, G, G), cell edges gx, gy (N, G+1), boxes (N, 4) -> (N,) pixels inside."""
    ovx = np.clip(np.minimum(gx[:, 1:], boxes[:, 2:3]) - np.maximum(gx[:, :-1], boxes[:, 0:1]), 0.0, None)
    ovy = np.clip(np.minimum(gy[:, 1:], boxes[:, 3:4]) - np.maximum(gy[:, :-1], boxes[:, 1:2]), 0.0, None)
    return np.einsum("ni,nij,nj->n", ovy, grids, ovx)


def empty_features(frame_index: int, *, width: int, height: int, fps: float = float("nan"),
                   stamp_ns: int = 0, source: str = "") -> FrameFeatures:
    """Features of a frame with no measurement (a gap in the stream): nothing seen."""
    return FrameFeatures(frame_index=frame_index, stamp_ns=stamp_ns, width=width, height=height, fps=fps,
                         source=source, inside=np.zeros((0, 0), dtype=int), valid=False)


def _full_mask_crop(p, W: int, H: int) -> tuple[np.ndarray, int, int]:
    """The person's mask (cropped) and its origin; the box itself when the mask is empty."""
    mask = np.asarray(p.mask, dtype=bool)
    ox, oy = int(p.mask_origin_xy[0]), int(p.mask_origin_xy[1])
    if mask.size == 0 or not mask.any():
        x0, y0, x1, y1 = [float(v) for v in p.box_xyxy]
        ix0, iy0 = int(np.floor(max(0.0, x0))), int(np.floor(max(0.0, y0)))
        ix1, iy1 = int(np.ceil(min(float(W), x1))), int(np.ceil(min(float(H), y1)))
        if ix1 <= ix0 or iy1 <= iy0:
            return np.zeros((0, 0), dtype=bool), ix0, iy0
        return np.ones((iy1 - iy0, ix1 - ix0), dtype=bool), ix0, iy0
    return mask, ox, oy


def _core(region: np.ndarray, margin: int, keep: float = 0.25) -> np.ndarray:
    """The region without a band of `margin` px along its border (where a focus map blurs
    across region boundaries), unless that leaves less than `keep` of it."""
    if margin <= 0 or not region.any():
        return region
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
    core = cv2.erode(region.astype(np.uint8), k, borderType=cv2.BORDER_REPLICATE).astype(bool)
    return core if core.sum() >= keep * region.sum() else region


def _region_fractions(infocus: np.ndarray, subj: np.ndarray | None, feet_row: int | None,
                      foreground: bool, margin: int = 0) -> np.ndarray:
    """b (foreground, subject, background) on the focus-map grid (shared.focus_regions); NaN = region absent.
    `foreground`: whether the band below the feet is one, judged at the frame's resolution."""
    out = np.full(3, np.nan)
    if subj is None:
        out[2] = float(infocus.mean()) if infocus.size else np.nan
        return out
    for t, region in enumerate(region_masks(subj, feet_row, foreground)):
        region = _core(region, margin)
        n = int(region.sum())
        if n > 0:
            out[t] = float(np.count_nonzero(infocus & region)) / n
    return out


def _track_id(t) -> int:
    """A detector's track id as an int64, -1 (none) for anything that is not a non-negative integer
    below 2**62 (the messages come from other processes)."""
    try:
        t = int(t)
    except (TypeError, ValueError, OverflowError):
        return -1
    return t if 0 <= t < 2 ** 62 else -1


def frame_features(m: Measurement, *, focus_pixel_threshold: float = 0.5,
                   foreground_min_rows: float = FOREGROUND_MIN_ROWS, min_person_confidence: float = 0.0,
                   focus_margin: float = 0.0, body_neck_min: float = 0.0,
                   body_span_min: float = 0.0, body_torso_min: float = 0.0) -> FrameFeatures:
    """Compute the FrameFeatures of one Measurement (pure). `body_*_min`: the anatomy check
    (anatomy.py; 0 = off)."""
    W, H = int(m.width), int(m.height)
    people = [p for p in m.people if float(p.confidence) >= min_person_confidence
              and np.all(np.isfinite(p.box_xyxy)) and p.box_xyxy[2] > p.box_xyxy[0] and p.box_xyxy[3] > p.box_xyxy[1]]
    keep_idx = [i for i, p in enumerate(m.people) if any(p is q for q in people)]
    M_ = len(people)
    boxes = np.array([np.asarray(p.box_xyxy, dtype=float) for p in people]).reshape(M_, 4)
    conf = np.array([float(p.confidence) for p in people], dtype=float)
    track = np.array([_track_id(p.track_id) for p in people], dtype=np.int64)

    crops = [_full_mask_crop(p, W, H) for p in people]
    grids, gx, gy = occupancy_grids(crops)

    # Skeletons (COCO-17 only) and h(p, m) = joints of skeleton p inside mask m.
    sk = [s for s in m.skeletons if s.keypoint_set == "coco17" and s.keypoints_px.shape == (N_JOINTS, 2)]
    P = len(sk)
    joints = np.array([np.asarray(s.keypoints_px, dtype=float) for s in sk]).reshape(P, N_JOINTS, 2)
    jconf = np.array([np.asarray(s.confidences, dtype=float) for s in sk]).reshape(P, N_JOINTS)
    jconf = np.where(np.isfinite(jconf), jconf, 0.0)
    jconf = drop_implausible_bodies(joints, jconf, neck_min=body_neck_min, span_min=body_span_min,
                                   torso_min=body_torso_min)
    inside = joints_inside(crops, joints)
    # A skeleton that names its person counts as fully inside that person (detectors that give
    # both from one model know the pairing better than the mask test).
    for p, s in enumerate(sk):
        if s.person_index in keep_idx:
            k = keep_idx.index(s.person_index)
            inside[p, k] = max(inside[p, k], int(np.all(np.isfinite(joints[p]), axis=1).sum()))

    focus = np.full((M_, 3), np.nan)
    focus_none = np.full(3, np.nan)
    has_focus = m.focus_map is not None and m.focus_map.size > 0 and W > 0 and H > 0
    if has_focus:
        focus, focus_none = focus_fractions(np.asarray(m.focus_map) >= focus_pixel_threshold * 255.0, crops, boxes,
                                            (W, H), foreground_min_rows=foreground_min_rows, margin=focus_margin)
    return FrameFeatures(frame_index=int(m.frame_index), stamp_ns=int(m.stamp_ns), width=W, height=H,
                         fps=float(m.fps), source=m.source, boxes=boxes, conf=conf, track=track, grids=grids,
                         grid_x=gx, grid_y=gy,
                         joints=joints, joint_conf=jconf, inside=inside, focus=focus,
                         focus_none=focus_none, has_focus=bool(has_focus), valid=bool(m.valid),
                         shot_change=float(m.shot_change), motion=motion_vector(m))


def motion_vector(m: Measurement) -> np.ndarray:
    """(7,) pan, tilt, roll [rad], log-zoom and translation direction of a measurement; NaN = unknown."""
    cmo = getattr(m, "camera_motion", None)
    if cmo is None:
        return np.full(7, np.nan)
    v = np.concatenate([np.asarray(cmo.rotation_rad, dtype=float).reshape(-1)[:3], [float(cmo.log_zoom)],
                        np.asarray(cmo.translation_dir, dtype=float).reshape(-1)[:3]])
    # a frame-to-frame motion beyond half a turn, a zoom beyond e^1 or a direction longer than 1
    # is no camera's: unknown (a message from another process must not overflow the rates)
    bad = np.abs(v[:3]) > np.pi, abs(v[3]) > 1.0, np.linalg.norm(np.nan_to_num(v[4:])) > 1.0 + 1e-6
    v[:3][bad[0]] = np.nan
    if bad[1]:
        v[3] = np.nan
    if bad[2]:
        v[4:] = np.nan
    return v


def occupancy_grids(crops: list[tuple[np.ndarray, int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each mask crop as a coarse occupancy grid over its own box: (M, G, G) occupancy in [0, 1] and
    the cell edges (M, G+1) in x and y [px]. Padding cells have zero width/height (edges repeat)."""
    M_ = len(crops)
    grids = np.zeros((M_, GRID, GRID))
    gx = np.zeros((M_, GRID + 1))
    gy = np.zeros((M_, GRID + 1))
    for k, (mask, ox, oy) in enumerate(crops):
        h, w = mask.shape
        gx[k], gy[k] = ox, oy
        if h == 0 or w == 0:
            continue
        gh, gw = min(GRID, h), min(GRID, w)
        grids[k, :gh, :gw] = cv2.resize(mask.astype(np.float32), (gw, gh), interpolation=cv2.INTER_AREA)
        gx[k] = ox + w * np.minimum(np.arange(GRID + 1), gw) / gw
        gy[k] = oy + h * np.minimum(np.arange(GRID + 1), gh) / gh
    return grids, gx, gy


def joints_inside(crops: list[tuple[np.ndarray, int, int]], joints: np.ndarray) -> np.ndarray:
    """(P, M): how many joints of skeleton p fall on a pixel of mask m."""
    inside = np.zeros((joints.shape[0], len(crops)), dtype=int)
    for k, (mask, ox, oy) in enumerate(crops):
        if mask.size == 0:
            continue
        for p, xy in enumerate(joints):
            ok = np.all(np.isfinite(xy), axis=1)
            if not ok.any():
                continue
            xi = np.floor(xy[ok, 0]).astype(int) - ox
            yi = np.floor(xy[ok, 1]).astype(int) - oy
            inb = (xi >= 0) & (yi >= 0) & (xi < mask.shape[1]) & (yi < mask.shape[0])
            inside[p, k] = int(mask[yi[inb], xi[inb]].sum())
    return inside


def focus_fractions(infocus: np.ndarray, crops: list[tuple[np.ndarray, int, int]], boxes: np.ndarray,
                    size: tuple[int, int], *, foreground_min_rows: float,
                    margin: float) -> tuple[np.ndarray, np.ndarray]:
    """The focused fraction b of each region (foreground, subject, background) from the in-focus
    pixels of the focus map: (M, 3) with person m as the subject, and (3,) with no subject."""
    W, H = size
    h, w = infocus.shape
    sx, sy = w / W, h / H
    focus = np.full((len(crops), 3), np.nan)
    focus_none = _region_fractions(infocus, None, None, False)
    # Frame pixel sampled at the centre of each focus-map pixel.
    fx = np.minimum(((np.arange(w) + 0.5) / sx).astype(int), W - 1)
    fy = np.minimum(((np.arange(h) + 0.5) / sy).astype(int), H - 1)
    for k, (mask, ox, oy) in enumerate(crops):
        subj = _mask_on_focus_map(mask, fx - ox, fy - oy)
        feet_row = mask_feet_row(subj)
        feet_row = int(np.ceil(boxes[k, 3] * sy)) if feet_row is None else feet_row
        foreground = _foreground_band(mask, oy, boxes[k, 3], H, foreground_min_rows)
        focus[k] = _region_fractions(infocus, subj, feet_row, foreground, int(round(margin * w)))
    return focus, focus_none


def _foreground_band(mask: np.ndarray, oy: int, box_bottom: float, height: int, min_share: float) -> bool:
    """Whether the band below the person's lowest mask pixel (the box's bottom without a mask) is a
    foreground, judged in frame pixels (focus_regions.foreground_present) as the truth judges it."""
    row = mask_feet_row(mask) if mask.size else None
    feet_px = oy + row if row is not None else float(box_bottom)
    return foreground_present(feet_px, height, min_share)


def _mask_on_focus_map(mask: np.ndarray, cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
    """The mask crop resampled onto the focus map: cx (w,), cy (h,) are the crop pixel of each
    focus-map column and row (outside the crop: not the subject)."""
    subj = np.zeros((cy.size, cx.size), dtype=bool)
    if mask.size:
        okx = (cx >= 0) & (cx < mask.shape[1])
        oky = (cy >= 0) & (cy < mask.shape[0])
        if okx.any() and oky.any():
            subj[np.ix_(oky, okx)] = mask[np.ix_(cy[oky], cx[okx])]
    return subj
