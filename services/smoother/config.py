"""Parameters of the smoother (one frozen dataclass, validated at start-up).

Smoothness weights are given for a 24 fps source and scaled by (fps / 24)^2, so that the
smoothing time constant stays the same in seconds at any frame rate (a first-difference
penalty lambda smooths over about sqrt(lambda) frames).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cinetransfer.shared.messages import COCO17_NAMES

DEFAULT_JOINTS: tuple[str, ...] = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
FOCUS_METHODS = ("hmm", "viterbi", "l2", "literal")
SUBJECT_METHODS = ("viterbi", "literal")
REFERENCE_FPS = 24.0


class ConfigError(ValueError):
    """A smoother parameter is out of its allowed range."""


@dataclass(frozen=True)
class SmootherConfig:
    """Every tunable of the smoother, with units and allowed ranges."""

    # --- controlled joints (DESIGN §1.2)
    joints: tuple[str, ...] = DEFAULT_JOINTS  # COCO-17 names of the E controlled joints
    # --- main subject (DESIGN §1.1 step 1)
    subject_method: str = "viterbi"  # 'viterbi' (exact DP + box QP) or 'literal' (paper's bilinear NLP, IPOPT)
    min_person_confidence: float = 0.05  # detections below this are ignored, [0, 1)
    move_cost: float = 100.0  # continuity: cost per (box change / box size - free_move)^2 per frame, >= 0
    free_move: float = 0.0  # box change per frame (at 24 fps, relative to the box diagonal) that costs nothing, >= 0
    miss_cost: float = 1.0  # cost of a frame where the subject is not visible, > 0
    reentry_cost: float = 2.0  # cost of re-appearing after an absence longer than max_bridge_s, >= 0
    continuity: str = "box"  # continuity measure: 'box' (|box change| / box size) or 'iou' (1 - IoU)
    confidence_cost: float = 0.2  # cost of a detection of confidence c is confidence_cost * (1 - c), >= 0
    extend_min_iou: float = 0.5  # after selection, re-admit a left-out detection overlapping the chosen box this much (1 = off)
    max_bridge_s: float = 0.5  # longest detector dropout bridged as 'visible' [s], >= 0
    cut_threshold: float = 0.25  # shot-change score that can start a new shot, (0, 1]; 1 = never cut
    cut_ratio: float = 3.0  # ... if also this many times the median score of its +-5 neighbours, >= 1
    box_smoothness: float = 0.02  # lambda of the box QP's first-difference term at 24 fps (data weights: confidences), > 0
    box_accel_smoothness: float = 0.1  # lambda2 of the box QP's second-difference term at 24 fps, >= 0
    # --- joints (DESIGN §1.1 step 3)
    joint_smoothness: float = 0.1  # lambda of the joint QP's first-difference (paper's) term at 24 fps, > 0
    joint_accel_smoothness: float = 3.0  # lambda2 of our added second-difference term at 24 fps, >= 0
    min_joint_confidence: float = 0.1  # joints below this confidence count as missing, [0, 1)
    # --- focus (DESIGN §1.1 step 4)
    focus_method: str = "hmm"  # 'hmm' (ours, default), 'viterbi', 'l2' (quadratic + threshold), 'literal'
    focus_pixel_threshold: float = 0.5  # focus-map probability above which a pixel counts as in focus, (0, 1)
    focus_adaptive_levels: bool = False  # HMM: fit the in/out levels of b per region from the sequence (see focus.fit_levels)
    focus_switch_prob: float = 0.02  # HMM: probability per frame (at 24 fps) that a region changes state, (0, 0.5)
    focus_noise: float = 0.25  # HMM: std of the measured fraction b around its state (0 or 1), > 0
    focus_smoothness: float = 4.0  # 'l2' method: lambda at 24 fps, > 0
    theta: float = 0.5  # region in focus when B > theta, (0, 1)
    # a shot where no region reaches theta is judged relative to its sharpest region (focus.soft_shot)
    focus_soft_floor: float = 0.1  # ... if that region reads at least this, (0, 1]; 1 = off
    foreground_min_rows: float = 0.03  # foreground band (below the feet) exists when >= this fraction of the height
    focus_region_margin: float = 0.015  # b ignores a border band of each region this wide (fraction of the map width), [0, 0.2]
    mu_m: float = 1.0  # depth-of-field margin mu [m] written into the instructions, > 0
    # --- timing
    default_fps: float = 24.0  # used when the measurements carry no frame rate [Hz], > 0
    # --- streaming service
    window_s: float = 10.0  # streaming: instructions window published (newest frames) [s], > 0
    history_s: float = 60.0  # streaming: frames of history the window solve uses [s], >= window_s
    publish_period_s: float = 0.25  # streaming: at most one window per period [s]; lag bound, (0, 0.5]
    end_idle_s: float = 3.0  # end of stream after this long without measurements [s]; 0 = only on command

    def validate(self) -> "SmootherConfig":
        def bad(name: str, allowed: str) -> ConfigError:
            return ConfigError(f"smoother config: {name}={getattr(self, name)!r} is invalid; allowed: {allowed}")

        if not self.joints:
            raise bad("joints", "a non-empty list of COCO-17 names")
        for j in self.joints:
            if j not in COCO17_NAMES:
                raise ConfigError(f"smoother config: joints contains {j!r}, not a COCO-17 name; allowed: "
                                  + ", ".join(COCO17_NAMES))
        if len(set(self.joints)) != len(self.joints):
            raise bad("joints", "distinct names")
        if self.subject_method not in SUBJECT_METHODS:
            raise bad("subject_method", " | ".join(SUBJECT_METHODS))
        if self.focus_method not in FOCUS_METHODS:
            raise bad("focus_method", " | ".join(FOCUS_METHODS))
        for name in ("min_person_confidence", "min_joint_confidence"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise bad(name, "0 <= value < 1")
        if not 0.0 < self.extend_min_iou <= 1.0:
            raise bad("extend_min_iou", "0 < value <= 1")
        if self.continuity not in ("box", "iou"):
            raise bad("continuity", "box | iou")
        for name in ("move_cost", "free_move", "reentry_cost", "confidence_cost", "max_bridge_s", "joint_accel_smoothness", "box_accel_smoothness"):
            if not getattr(self, name) >= 0.0:
                raise bad(name, ">= 0")
        for name in ("miss_cost", "box_smoothness", "joint_smoothness", "focus_noise", "focus_smoothness",
                     "mu_m", "default_fps", "window_s"):
            if not getattr(self, name) > 0.0:
                raise bad(name, "> 0")
        for name in ("focus_pixel_threshold", "theta"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise bad(name, "0 < value < 1")
        if not 0.0 < self.cut_threshold <= 1.0:
            raise bad("cut_threshold", "0 < value <= 1 (1 = never cut)")
        if not self.cut_ratio >= 1.0:
            raise bad("cut_ratio", ">= 1")
        if not 0.0 < self.focus_soft_floor <= 1.0:
            raise bad("focus_soft_floor", "0 < value <= 1 (1 = off)")
        if not 0.0 < self.focus_switch_prob < 0.5:
            raise bad("focus_switch_prob", "0 < value < 0.5")
        if not 0.0 <= self.focus_region_margin <= 0.2:
            raise bad("focus_region_margin", "0 <= value <= 0.2")
        if not 0.0 <= self.foreground_min_rows < 1.0:
            raise bad("foreground_min_rows", "0 <= value < 1")
        if not self.history_s >= self.window_s:
            raise bad("history_s", f">= window_s ({self.window_s})")
        if not 0.0 < self.publish_period_s <= 0.5:
            raise bad("publish_period_s", "0 < value <= 0.5 (the lag bound)")
        if not self.end_idle_s >= 0.0:
            raise bad("end_idle_s", ">= 0")
        return self

    def replace(self, **changes: object) -> "SmootherConfig":
        return dataclasses.replace(self, **changes).validate()

    def lam(self, value: float, fps: float, order: int = 1) -> float:
        """A smoothness weight given at 24 fps, scaled to `fps` (differences of `order` shrink as
        1/fps^order, so their squares as 1/fps^(2 order))."""
        return float(value) * (float(fps) / REFERENCE_FPS) ** (2 * order)
