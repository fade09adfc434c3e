"""The smoother's pure pipeline: measurements -> recording instructions (DESIGN §1.1, §1.2).

    feats = [frame_features(m, ...) for m in measurements]       # compact, once per frame
    result = smooth_sequence(feats, cfg, source=SourceInfo(...))  # SmoothResult
    result.instructions                                            # messages.Instructions

Steps: order and de-duplicate frames (gaps become empty frames, bridged), select the main
subject (`subject.select_subject`, or the paper's bilinear NLP in `baseline`), smooth its box,
pick its mask and skeleton, smooth the joints (`joints`), compute and smooth the focused
fraction per region (`focus`), and assemble the Instructions. No Zenoh, no clock, no globals.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from cinetransfer.services.smoother import anatomy
from cinetransfer.services.smoother import focus as focus_mod
from cinetransfer.services.smoother import shots as shots_mod
from cinetransfer.services.smoother import joints as joints_mod
from cinetransfer.services.smoother import subject as subject_mod
from cinetransfer.services.smoother.config import SmootherConfig
from cinetransfer.services.smoother.camera_motion import motion_style
from cinetransfer.services.smoother.features import FrameFeatures, empty_features, frame_features
from cinetransfer.shared import messages as M


class SmootherInputError(ValueError):
    """The measurements cannot give instructions (empty sequence, no person, bad sizes)."""


@dataclass(frozen=True, eq=False)
class SmoothResult:
    """Instructions plus the per-frame diagnostics the plots and evaluations need."""

    instructions: M.Instructions
    diagnostics: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()  #: stored in the style file (e.g. the source was truncated)


def feature_options(cfg: SmootherConfig) -> dict[str, float]:
    """The config values `frame_features` takes."""
    return {"focus_pixel_threshold": cfg.focus_pixel_threshold, "foreground_min_rows": cfg.foreground_min_rows,
            "min_person_confidence": cfg.min_person_confidence, "focus_margin": cfg.focus_region_margin,
            "body_neck_min": cfg.body_neck_min, "body_span_min": cfg.body_span_min,
            "body_torso_min": cfg.body_torso_min}


def features_from_measurements(measurements: Iterable[M.Measurement], cfg: SmootherConfig) -> list[FrameFeatures]:
    opts = feature_options(cfg)
    return [frame_features(m, **opts) for m in measurements]


def order_frames(feats: Iterable[FrameFeatures]) -> tuple[list[FrameFeatures], int, int]:
    """Sort by frame index, keep the first copy of a duplicate, fill gaps with empty frames.

    Returns (frames, duplicates dropped, gap frames filled)."""
    by_index: dict[int, FrameFeatures] = {}
    dups = 0
    for f in feats:
        if f.frame_index in by_index:
            dups += 1
            continue
        by_index[f.frame_index] = f
    if not by_index:
        return [], dups, 0
    idx = sorted(by_index)
    ref = next((by_index[i] for i in idx if by_index[i].width > 0 and by_index[i].height > 0), by_index[idx[0]])
    out, gaps = [], 0
    for i in range(idx[0], idx[-1] + 1):
        f = by_index.get(i)
        if f is None:
            f = empty_features(i, width=ref.width, height=ref.height, fps=ref.fps, source=ref.source)
            gaps += 1
        out.append(f)
    return out, dups, gaps


def _frame_size(feats: list[FrameFeatures]) -> tuple[int, int]:
    sizes = {(f.width, f.height) for f in feats if f.width > 0 and f.height > 0}
    if not sizes:
        raise SmootherInputError("measurements carry no frame size (width/height are 0)")
    if len(sizes) > 1:
        raise SmootherInputError(f"frame size changes within the sequence: {sorted(sizes)}")
    return sizes.pop()


def _fps(feats: list[FrameFeatures], cfg: SmootherConfig) -> float:
    for f in feats:
        if math.isfinite(f.fps) and f.fps > 0:
            return float(f.fps)
    return float(cfg.default_fps)


def _shot_start(cuts: np.ndarray | None, n: int) -> np.ndarray:
    """Row k starts a shot: row 0, and every frame the cut detector marked."""
    out = np.zeros(n, dtype=bool) if cuts is None else np.asarray(cuts, dtype=bool).copy()
    if n:
        out[0] = True
    return out


def smooth_sequence(feats: Iterable[FrameFeatures], cfg: SmootherConfig | None = None, *,
                    source: M.SourceInfo | None = None, final: bool = True,
                    known_cuts: Iterable[int] | None = None) -> SmoothResult:
    """The whole optimisation for one sequence of frames (any order, duplicates allowed).

    `known_cuts`: the rows where shots begin, when they are known rather than to be found (the
    output of a transfer flown one take per shot is edited at exactly the takes' first rows)."""
    cfg = (cfg or SmootherConfig()).validate()
    frames, dups, gaps = order_frames(feats)
    if not frames:
        raise SmootherInputError("no measurements: the sequence is empty")
    W, H = _frame_size(frames)
    fps = _fps(frames, cfg)
    if not any(f.n_people for f in frames):
        raise SmootherInputError(f"no person detected in any of the {len(frames)} frames: no main subject to follow")
    scores, cuts = _shot_cuts(frames, cfg)
    if known_cuts is not None:
        cuts = np.zeros(len(frames), dtype=bool)
        cuts[[r for r in known_cuts if 0 < r < len(frames)]] = True
    track = _track_subject(frames, cfg, fps=fps, size=(W, H), cuts=cuts)
    focus = _focus(frames, track, cfg, fps=fps, cuts=cuts)
    src = source or M.SourceInfo(path=frames[0].source, width=W, height=H, fps=fps, n_frames=len(frames))
    src, warnings = reconcile_frame_count(src, first=frames[0].frame_index, rows=len(frames), final=final)
    instr = _instructions(frames, track, focus, cfg, fps=fps, size=(W, H), cuts=cuts, source=src, final=final,
                          complete=gaps == 0)
    diag = {
        "shot_change": scores,
        "cut": cuts,
        "frame_index": np.array([f.frame_index for f in frames]),
        "n_people": np.array([f.n_people for f in frames]),
        "person": track.sel.person.copy(),
        "bridged": track.sel.bridged.copy(),
        "mask_index": track.mask_idx,
        "skeleton_index": track.skel_idx,
        "raw_box": track.raw_box / np.array([W, H, W, H], dtype=float),
        "raw_joints": track.raw_joints / np.array([W, H], dtype=float),
        "raw_joint_conf": track.joint_conf,
        "smoothed_joints": track.joints / np.array([W, H], dtype=float),
        "focus_B_unmasked": focus.B,
        "selection_cost": float(track.sel.cost),
        "duplicates": int(dups),
        "gaps": int(gaps),
        "config": dataclasses.asdict(cfg),
    }
    return SmoothResult(instr, diag, warnings)


def _shot_cuts(frames: list[FrameFeatures], cfg: SmootherConfig) -> tuple[np.ndarray, np.ndarray]:
    """Step 0, shots: the shot-change scores and the cuts found in them (chains of smoothing never
    cross a cut)."""
    scores = np.array([f.shot_change for f in frames], dtype=float)
    cuts = shots_mod.find_cuts(scores, threshold=cfg.cut_threshold, ratio=cfg.cut_ratio) \
        if cfg.cut_threshold < 1.0 else np.zeros(len(frames), dtype=bool)
    return scores, cuts


@dataclass(frozen=True, eq=False)
class _Track:
    """The main subject through the sequence: who, its box, mask, skeleton and joints [px]."""

    sel: Any  #: the selection (subject.Selection or the baseline's)
    raw_box: np.ndarray
    box: np.ndarray
    mask_idx: np.ndarray
    skel_idx: np.ndarray
    raw_joints: np.ndarray
    joint_conf: np.ndarray
    joints: np.ndarray  #: smoothed


def _select(frames: list[FrameFeatures], cfg: SmootherConfig, *, fps: float, cuts: np.ndarray):
    """Step 1, the main subject of each frame."""
    if cfg.subject_method == "literal":
        from cinetransfer.services.smoother import baseline  # casadi: imported only when asked for

        sel = baseline.literal_selection(frames, fps=fps, max_bridge_s=cfg.max_bridge_s)
    else:
        sel = subject_mod.select_subject(frames, fps=fps, move_cost=cfg.move_cost, miss_cost=cfg.miss_cost,
                                         confidence_cost=cfg.confidence_cost, max_bridge_s=cfg.max_bridge_s,
                                         free_move=cfg.free_move * 24.0 / fps, continuity=cfg.continuity,
                                         reentry_cost=cfg.reentry_cost, cuts=cuts)
        sel = subject_mod.extend_runs(frames, sel, min_iou=cfg.extend_min_iou, cuts=cuts) \
            if cfg.extend_min_iou < 1 else sel
    if not sel.visible.any():
        raise SmootherInputError(f"no main subject found in {len(frames)} frames")
    return sel


def _track_subject(frames: list[FrameFeatures], cfg: SmootherConfig, *, fps: float, size: tuple[int, int],
                   cuts: np.ndarray) -> _Track:
    """Steps 1-3: the main subject, its smoothed box, its mask and skeleton, its smoothed joints."""
    W, H = size
    sel = _select(frames, cfg, fps=fps, cuts=cuts)
    raw_box, box = subject_mod.smooth_box(frames, sel, lam=cfg.lam(cfg.box_smoothness, fps), width=W, height=H,
                                          lam2=cfg.lam(cfg.box_accel_smoothness, fps, order=2), cuts=cuts)
    mask_idx, skel_idx, raw_joints, joint_conf = joints_mod.raw_subject_joints(frames, box, sel.visible)
    sm_joints = joints_mod.smooth_joints(raw_joints, joint_conf, sel.visible,
                                         lam=cfg.lam(cfg.joint_smoothness, fps), width=W, height=H,
                                         min_confidence=cfg.min_joint_confidence,
                                         lam2=cfg.lam(cfg.joint_accel_smoothness, fps, order=2),
                                         max_gap=int(round(cfg.max_bridge_s * fps)), cuts=cuts)
    sm_joints = anatomy.drop_short_trunks(sm_joints, cfg.body_torso_min)
    # a joint seen for a few frames only (a skeleton found for 3 frames on tos_clip01's robot) is no
    # target: no camera reframes in that time, and a plan anticipating it spoils the frames before
    min_run = math.ceil(cfg.joint_min_run_s * fps - 1e-9)
    flat = focus_mod.drop_short_runs(sm_joints.reshape(len(sm_joints), -1), min_run=min_run)
    sm_joints = flat.reshape(sm_joints.shape)
    return _Track(sel, raw_box, box, mask_idx, skel_idx, raw_joints, joint_conf, sm_joints)


@dataclass(frozen=True, eq=False)
class _Focus:
    """Step 4, focus per region (foreground, subject, background), (F, 3) each."""

    b: np.ndarray  #: measured focused fraction (NaN = not measured)
    present: np.ndarray  #: the region exists in the frame
    B: np.ndarray  #: smoothed, before masking by `present`
    B_out: np.ndarray  #: smoothed where the region exists and was ever measured, else NaN
    focus_in: np.ndarray  #: B_out above theta


def raw_focus(frames: list[FrameFeatures], visible: np.ndarray, mask_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """b per frame and region (NaN = not measured) and which regions exist. A region whose extent
    is unknown (no focus map) is assumed present where the subject is."""
    F = len(frames)
    b = np.full((F, 3), np.nan)
    present = np.zeros((F, 3), dtype=bool)
    for f, feat in enumerate(frames):
        m = mask_idx[f]
        if not visible[f]:
            present[f] = (False, False, True)
            if feat.has_focus:
                b[f] = feat.focus_none
        elif m >= 0:
            present[f] = np.isfinite(feat.focus[m]) if feat.has_focus else (True, True, True)
            if feat.has_focus:
                b[f] = feat.focus[m]
                present[f] = np.isfinite(feat.focus[m])
        else:  # visible but not detected (bridged): regions exist, b unknown
            present[f] = (True, True, True)
    return b, present


def _focus(frames: list[FrameFeatures], track: _Track, cfg: SmootherConfig, *, fps: float,
           cuts: np.ndarray) -> _Focus:
    """Step 4: b per region, which regions exist, then B smoothed shot by shot."""
    b, present = raw_focus(frames, track.sel.visible, track.mask_idx)
    B = np.full_like(b, np.nan)
    measured = np.zeros(b.shape, dtype=bool)
    for seg in shots_mod.segments(cuts):  # each shot's focus on its own: a cut may change it at once
        b_seg, _ = focus_mod.soft_shot(b[seg], theta=cfg.theta, floor=cfg.focus_soft_floor)  # soft footage
        B[seg] = focus_mod.smooth_focus(b_seg, method=cfg.focus_method, fps=fps,
                                        switch_prob_24=cfg.focus_switch_prob, sigma=cfg.focus_noise,
                                        lam_24=cfg.focus_smoothness, adaptive=cfg.focus_adaptive_levels)
        # A region never measured in its shot is unknown there, not "out of focus": the smoother's
        # prior (B = 0.5) is no evidence (tos_clip01's morph frames asked to defocus everything).
        measured[seg] = np.isfinite(b[seg]).any(axis=0)
    B_out = np.where(present & measured & np.isfinite(B), B, np.nan)
    B_out = focus_mod.drop_short_runs(B_out, min_run=math.ceil(cfg.focus_min_run_s * fps - 1e-9))
    return _Focus(b, present, B, B_out, np.nan_to_num(B_out, nan=0.0) > cfg.theta)


def _instructions(frames: list[FrameFeatures], track: _Track, focus: _Focus, cfg: SmootherConfig, *, fps: float,
                  size: tuple[int, int], cuts: np.ndarray, source: M.SourceInfo, final: bool,
                  complete: bool) -> M.Instructions:
    """The Instructions message: targets and box normalised by the frame size."""
    W, H = size
    jidx = [M.COCO17_NAMES.index(n) for n in cfg.joints]
    targets = track.joints[:, jidx, :] / np.array([W, H], dtype=float)
    box_n = track.box / np.array([W, H, W, H], dtype=float)
    stamp = max(f.stamp_ns for f in frames)
    valid = all(f.valid for f in frames if f.n_people or f.has_focus) and complete
    return M.Instructions(
        stamp_ns=int(stamp), valid=bool(valid), source=source, fps=float(fps), frame_duration_s=1.0 / fps,
        first_frame=int(frames[0].frame_index), final=bool(final), joint_names=list(cfg.joints),
        image_targets=targets.astype(np.float32), subject_visible=track.sel.visible.copy(),
        subject_box=box_n.astype(np.float32), focus_raw=np.where(focus.present, focus.b, np.nan).astype(np.float32),
        focus_smoothed=focus.B_out.astype(np.float32), focus_in=focus.focus_in, theta=float(cfg.theta),
        mu_m=float(cfg.mu_m), shot_start=_shot_start(cuts, len(frames)),
        **motion_style(np.array([f.motion for f in frames]), fps, cuts))


def reconcile_frame_count(src: M.SourceInfo, *, first: int, rows: int,
                          final: bool) -> tuple[M.SourceInfo, tuple[str, ...]]:
    """Source info whose `n_frames` agrees with the rows of a final instruction set, and a warning
    when the source declared another count (a truncated video: its container promises frames
    that never decoded; or a run stopped early). A window (not final) is left alone."""
    have = first + rows
    if not final or src.n_frames == have:
        return src, ()
    msg = (f"source {src.path or '?'} declares {src.n_frames} frames but {have} were measured "
           f"(truncated video, or stopped early); n_frames set to {have}")
    return dataclasses.replace(src, n_frames=have), (msg,)


def smooth_measurements(measurements: Iterable[M.Measurement], cfg: SmootherConfig | None = None, *,
                        source: M.SourceInfo | None = None) -> SmoothResult:
    """Convenience: Measurement messages -> SmoothResult."""
    cfg = (cfg or SmootherConfig()).validate()
    return smooth_sequence(features_from_measurements(measurements, cfg), cfg, source=source)
