"""Parameters of the smoother (one frozen dataclass, validated at start-up).

Smoothness weights are given for a 24 fps source and scaled by (fps / 24)^2, so that the
smoothing time constant stays the same in seconds at any frame rate (a first-difference
penalty lambda smooths over about sqrt(lambda) frames).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from cinetransfer.shared.errors import ConfigError  # noqa: F401 (callers import it from here)
from cinetransfer.shared.focus_regions import FOREGROUND_MIN_ROWS
from cinetransfer.shared.messages import COCO17_NAMES
from cinetransfer.shared.nodeconfig import setting

DEFAULT_JOINTS: tuple[str, ...] = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")
FOCUS_METHODS = ("hmm", "viterbi", "l2", "literal")
SUBJECT_METHODS = ("viterbi", "literal")
REFERENCE_FPS = 24.0
#: flags of the streaming node only (the batch tools `smooth` and `extract` have no stream)
STREAMING_FIELDS = ("window_s", "history_s", "publish_period_s", "end_idle_s")


@dataclass(frozen=True)
class SmootherConfig:
    """Every tunable of the smoother, with units and allowed ranges."""

    # --- controlled joints (DESIGN §1.2)
    joints: tuple[str, ...] = setting(DEFAULT_JOINTS, flag="--joints",
                                      help="comma-separated COCO-17 names of the E controlled joints")
    # --- main subject (DESIGN §1.1 step 1)
    subject_method: str = setting("viterbi", flag="--subject-method", choices=SUBJECT_METHODS,
                                  help="main-subject selection: 'viterbi' (exact DP + box QP) or "
                                       "'literal' (the paper's bilinear NLP, IPOPT)")
    min_person_confidence: float = 0.05  # detections below this are ignored, [0, 1)
    move_cost: float = 100.0  # continuity: cost per (box change / box size - free_move)^2 per frame, >= 0
    free_move: float = 0.0  # box change per frame (at 24 fps, relative to the box diagonal) that costs nothing, >= 0
    miss_cost: float = 1.0  # cost of a frame where the subject is not visible, > 0
    reentry_cost: float = 2.0  # cost of re-appearing after an absence longer than max_bridge_s, >= 0
    continuity: str = "box"  # continuity measure: 'box' (|box change| / box size) or 'iou' (1 - IoU)
    confidence_cost: float = 0.2  # cost of a detection of confidence c is confidence_cost * (1 - c), >= 0
    #: after selection, re-admit a left-out detection overlapping the chosen box this much (1 = off)
    extend_min_iou: float = 0.5
    max_bridge_s: float = setting(0.5, flag="--max-bridge", unit="s", range=">= 0",
                                  help="longest detector dropout bridged as 'visible'")
    cut_threshold: float = 0.25  # shot-change score that can start a new shot, (0, 1]; 1 = never cut
    cut_ratio: float = 3.0  # ... if also this many times the median score of its +-5 neighbours, >= 1
    #: lambda of the box QP's first-difference term at 24 fps (data weights: confidences), > 0
    box_smoothness: float = setting(0.02, flag="--box-smoothness", range="> 0",
                                    help="box QP first-difference weight at 24 fps")
    box_accel_smoothness: float = setting(0.1, flag="--box-accel-smoothness", range=">= 0",
                                          help="box QP second-difference weight (lambda2) at 24 fps")
    # --- joints (DESIGN §1.1 step 3)
    joint_smoothness: float = setting(0.1, flag="--joint-smoothness", range="> 0",
                                      help="joint QP first-difference (the paper's) weight at 24 fps")
    joint_accel_smoothness: float = setting(3.0, flag="--joint-accel-smoothness", range=">= 0",
                                            help="joint QP second-difference weight at 24 fps; 0 = the paper's QP")
    min_joint_confidence: float = 0.1  # joints below this confidence count as missing, [0, 1)
    #: a skeleton whose shoulders sit closer than this many head widths (ear to ear) to the ears ...
    body_neck_min: float = 0.45
    #: ... and are closer together than this many head widths has its body joints dropped (anatomy.py); 0 = off
    body_span_min: float = 2.0
    #: a joint with a target in fewer consecutive frames than this has none there [s], >= 0 (0 = off)
    joint_min_run_s: float = 0.25
    #: a skeleton whose hips are nearer its shoulders than this many shoulder spans has its body dropped,
    #: a smoothed row its hips and legs; 0 = off
    body_torso_min: float = 0.7
    # --- focus (DESIGN §1.1 step 4)
    focus_method: str = setting("hmm", flag="--focus-method", choices=FOCUS_METHODS,
                                help="focus smoothing: 'hmm' (ours), 'viterbi', 'l2' (quadratic + threshold), "
                                     "'literal'; see docs/smoother.md")
    focus_pixel_threshold: float = 0.5  # focus-map probability above which a pixel counts as in focus, (0, 1)
    #: HMM: fit the in/out levels of b per region from the sequence (see focus.fit_levels)
    focus_adaptive_levels: bool = False
    focus_switch_prob: float = 0.02  # HMM: probability per frame (at 24 fps) that a region changes state, (0, 0.5)
    focus_noise: float = 0.25  # HMM: std of the measured fraction b around its state (0 or 1), > 0
    focus_smoothness: float = 4.0  # 'l2' method: lambda at 24 fps, > 0
    theta: float = setting(0.5, flag="--theta", range="(0, 1)", help="a region is in focus when B > theta")
    # a shot where no region reaches theta is judged relative to its sharpest region (focus.soft_shot)
    focus_soft_floor: float = 0.1  # ... if that region reads at least this, (0, 1]; 1 = off
    focus_min_run_s: float = 0.1  # a region labelled for a shorter run of frames has no label there [s], >= 0
    # foreground band (below the feet) exists when >= this fraction of the height (shared.focus_regions)
    foreground_min_rows: float = FOREGROUND_MIN_ROWS
    #: b ignores a border band of each region this wide (fraction of the map width), [0, 0.2]
    focus_region_margin: float = 0.015
    mu_m: float = setting(1.0, flag="--mu", unit="m", range="> 0",
                          help="depth-of-field margin mu written into the instructions")
    # --- timing
    default_fps: float = 24.0  # used when the measurements carry no frame rate [Hz], > 0
    # --- streaming service
    window_s: float = setting(10.0, flag="--window", unit="s", range="> 0",
                              help="streaming window: the newest frames each published instructions cover")
    history_s: float = setting(60.0, flag="--history", unit="s", range="> 0",
                               help="history used by each window solve, >= window_s")
    publish_period_s: float = setting(0.25, flag="--publish-period", unit="s", range="[0, 0.5]",
                                      help="at most one window per period (the lag bound); 0 = no windows, "
                                           "only the whole sequence at the end of stream")
    end_idle_s: float = setting(3.0, flag="--end-idle", unit="s", range=">= 0",
                                help="end of stream after this long without measurements; 0 = only on command")

    def validate(self) -> "SmootherConfig":
        if not self.joints:
            raise self._bad("joints", "a non-empty list of COCO-17 names")
        for j in self.joints:
            if j not in COCO17_NAMES:
                raise ConfigError(f"smoother config: joints contains {j!r}, not a COCO-17 name; allowed: "
                                  + ", ".join(COCO17_NAMES))
        for name, ok, allowed in self._checks():
            if not ok:
                raise self._bad(name, allowed)
        return self

    def _bad(self, name: str, allowed: str) -> ConfigError:
        return ConfigError(f"smoother config: {name}={getattr(self, name)!r} is invalid; allowed: {allowed}")

    def _checks(self) -> list[tuple[str, bool, str]]:
        """(field, whether its value is allowed, what is allowed), in the order they are reported."""
        v = self.__dict__
        nonneg = ("move_cost", "free_move", "reentry_cost", "confidence_cost", "max_bridge_s",
                  "joint_accel_smoothness", "box_accel_smoothness", "body_neck_min", "body_span_min",
                  "body_torso_min")
        positive = ("miss_cost", "box_smoothness", "joint_smoothness", "focus_noise", "focus_smoothness",
                    "mu_m", "default_fps", "window_s")
        return [
            ("joints", len(set(self.joints)) == len(self.joints), "distinct names"),
            ("subject_method", self.subject_method in SUBJECT_METHODS, " | ".join(SUBJECT_METHODS)),
            ("focus_method", self.focus_method in FOCUS_METHODS, " | ".join(FOCUS_METHODS)),
            *((n, 0.0 <= v[n] < 1.0, "0 <= value < 1") for n in ("min_person_confidence", "min_joint_confidence")),
            ("extend_min_iou", 0.0 < self.extend_min_iou <= 1.0, "0 < value <= 1"),
            ("continuity", self.continuity in ("box", "iou"), "box | iou"),
            *((n, v[n] >= 0.0, ">= 0") for n in nonneg),
            *((n, v[n] > 0.0, "> 0") for n in positive),
            *((n, 0.0 < v[n] < 1.0, "0 < value < 1") for n in ("focus_pixel_threshold", "theta")),
            ("cut_threshold", 0.0 < self.cut_threshold <= 1.0, "0 < value <= 1 (1 = never cut)"),
            ("cut_ratio", self.cut_ratio >= 1.0, ">= 1"),
            ("focus_soft_floor", 0.0 < self.focus_soft_floor <= 1.0, "0 < value <= 1 (1 = off)"),
            ("focus_min_run_s", self.focus_min_run_s >= 0.0, ">= 0 (0 = off)"),
            ("joint_min_run_s", self.joint_min_run_s >= 0.0, ">= 0 (0 = off)"),
            ("focus_switch_prob", 0.0 < self.focus_switch_prob < 0.5, "0 < value < 0.5"),
            ("focus_region_margin", 0.0 <= self.focus_region_margin <= 0.2, "0 <= value <= 0.2"),
            ("foreground_min_rows", 0.0 <= self.foreground_min_rows < 1.0, "0 <= value < 1"),
            ("history_s", self.history_s >= self.window_s, f">= window_s ({self.window_s})"),
            ("publish_period_s", 0.0 <= self.publish_period_s <= 0.5,
             "0 <= value <= 0.5 (the lag bound; 0 = no windows)"),
            ("end_idle_s", self.end_idle_s >= 0.0, ">= 0"),
        ]

    def replace(self, **changes: object) -> "SmootherConfig":
        return dataclasses.replace(self, **changes).validate()

    def lam(self, value: float, fps: float, order: int = 1) -> float:
        """A smoothness weight given at 24 fps, scaled to `fps` (differences of `order` shrink as
        1/fps^order, so their squares as 1/fps^(2 order))."""
        return float(value) * (float(fps) / REFERENCE_FPS) ** (2 * order)
