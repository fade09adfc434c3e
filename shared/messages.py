"""Every message of the cinetransfer dataflow, as frozen typed dataclasses.

This module is the single source of truth for what travels on the bus. The codec
(`cinetransfer.shared.codec`) encodes and validates exactly these classes; docs/messages.md
is generated from the docstrings below (`cinetransfer docs messages`).

Conventions (apply to every message):
- `stamp_ns`: time of the underlying measurement (not the send time), ns since the Unix epoch.
- `seq`: sender's sequence number, starting at 0, +1 per message on that key.
- `valid`: False when the sender's own inputs were unhealthy; receivers must not act on the
  content as if it were fresh (they may still display it).
- Frames of reference: `world` is right-handed, z up, metres, origin at the rig's home point
  (x east, y north when georeferenced). `image` coordinates are pixels with the origin at the
  top-left, x right, y down; `normalised` image coordinates are pixels divided by image width
  and height, so (0,0) is top-left and (1,1) bottom-right.
- Camera attitude is given as yaw (about world z, 0 = looking along +x, counter-clockwise
  positive), pitch (positive = looking up) and roll (about the optical axis), all radians.
- NaN means "not set" only where a field's doc says so; every other float must be finite.

Schema evolution: only add fields (with defaults); never reuse a removed name; bump
`SCHEMA_VERSION` of a class when its meaning changes.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

#: Keypoint set used by Skeleton.keypoints_px and by SubjectState.joints_m (COCO-17 order).
COCO17_NAMES: tuple[str, ...] = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hip", "right_hip",
    "left_knee", "right_knee", "left_ankle", "right_ankle",
)

#: Focus regions, in the order used by every (K, 3) focus array.
FOCUS_REGIONS: tuple[str, ...] = ("foreground", "subject", "background")


def array(dtype: str, shape: tuple[int | None, ...], *, allow_nan: bool = False, doc: str = "",
          optional: bool = False, since: int = 1) -> Any:
    """A numpy-array dataclass field with the dtype/shape/finiteness the codec enforces.

    `shape` entries of None match any length. `allow_nan` permits NaN (meaning "not set") but
    never ±inf. `optional` lets the field be None. `since`: as for `doc`.
    """
    meta = {"dtype": dtype, "shape": shape, "allow_nan": allow_nan, "doc": doc, "optional": optional,
            "since": since}
    if optional:
        return field(default=None, metadata=meta)
    return field(default_factory=lambda: np.zeros([0 if s is None else s for s in shape], dtype=dtype),
                 metadata=meta)


def doc(text: str, default: Any = dataclasses.MISSING, *, default_factory: Any = dataclasses.MISSING,
        since: int = 1) -> Any:
    """A scalar field carrying its documentation (unit, frame, range, 'not set' value).

    A float field may hold NaN only when its doc says what NaN means ("NaN = ...").
    `since`: the schema version that added the field; a payload of an older version (down to
    the class's MIN_SCHEMA_VERSION) decodes with the field's default.
    """
    return field(default=default, default_factory=default_factory, metadata={"doc": text, "since": since})


@dataclass(frozen=True, eq=False)
class LensState:
    """Optical state of the camera lens when a frame was taken / as commanded."""

    focal_length_mm: float = doc("focal length f [mm], > 0; NaN = unknown", float("nan"))
    focus_distance_m: float = doc("focus distance s [m], > 0; NaN = unknown", float("nan"))
    f_number: float = doc("aperture f-number A (dimensionless), >= 1; NaN = unknown", float("nan"))
    sensor_width_mm: float = doc("sensor width [mm]; NaN = unknown", float("nan"))
    sensor_height_mm: float = doc("sensor height [mm]; NaN = unknown", float("nan"))
    coc_mm: float = doc("circle of confusion used for depth of field [mm]; NaN = unknown", float("nan"))


@dataclass(frozen=True, eq=False)
class Frame:
    """One camera or video frame. On the wire the image is raw BGR bytes (zero-copy decode) or JPEG."""

    SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("capture time [ns since epoch]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("sender healthy", True)
    source: str = doc("where the frame came from (file path, device, 'sim:<scene>')", "")
    index: int = doc("frame index within the source (0-based)", 0)
    fps: float = doc("nominal frame rate of the source [Hz]; NaN = unknown", float("nan"))
    image: np.ndarray = array("uint8", (None, None, 3), doc="BGR image, shape (H, W, 3)")
    lens: LensState | None = doc("lens state the frame was taken with; None = unknown", None)


@dataclass(frozen=True, eq=False)
class PersonDetection:
    """One person found in a frame."""

    box_xyxy: np.ndarray = array("float32", (4,), doc="bounding box (x0, y0, x1, y1) [image px]")
    confidence: float = doc("detection confidence in [0, 1]", 0.0)
    mask_origin_xy: np.ndarray = array("int32", (2,), doc="top-left (x, y) [px] of the mask crop")
    mask: np.ndarray = array("bool", (None, None),
                             doc="instance mask cropped to its own box, shape (h, w); "
                                 "pixel (x, y) of the frame is mask[y - oy, x - ox]")
    track_id: int = doc("tracker id if the detector tracks, else -1", -1)

    def full_mask(self, width: int, height: int) -> np.ndarray:
        """The mask pasted into a (height, width) boolean image."""
        out = np.zeros((height, width), dtype=bool)
        ox, oy = int(self.mask_origin_xy[0]), int(self.mask_origin_xy[1])
        h, w = self.mask.shape
        x0, y0 = max(ox, 0), max(oy, 0)
        x1, y1 = min(ox + w, width), min(oy + h, height)
        if x1 > x0 and y1 > y0:
            out[y0:y1, x0:x1] = self.mask[y0 - oy:y1 - oy, x0 - ox:x1 - ox]
        return out


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Body joints of one person (COCO-17 order, see COCO17_NAMES)."""

    keypoints_px: np.ndarray = array("float32", (None, 2), allow_nan=True,
                                     doc="joint (x, y) [image px], shape (J, 2); NaN = not found")
    confidences: np.ndarray = array("float32", (None,), doc="per-joint confidence in [0, 1], shape (J,)")
    keypoint_set: str = doc("name of the keypoint set; 'coco17'", "coco17")
    person_index: int = doc("index into Measurement.people of the same person; -1 = unknown", -1)


@dataclass(frozen=True, eq=False)
class CameraMotion:
    """How the camera moved from the previous frame of the source to this one, measured on the
    background's image motion with the people masked out (shared/camera_motion.py)."""

    rotation_rad: np.ndarray = array("float64", (3,), allow_nan=True,
                                     doc="pan (to the camera's left), tilt (up), roll (clockwise as the camera "
                                         "sees it) since the previous frame [rad]; NaN = unknown")
    log_zoom: float = doc("ln(focal length now / before) (> 0: zooming in); NaN = unknown", float("nan"))
    translation_dir: np.ndarray = array("float64", (3,), allow_nan=True,
                                        doc="direction of the camera's translation, unit vector in the camera "
                                            "frame (x right, y down, z forward); zeros = none seen (no "
                                            "parallax); NaN = unknown")
    focal_px: float = doc("focal length [px of the frame] the rates were measured with (the frame's lens, else "
                          "the assumed field of view); NaN = unknown", float("nan"))
    points: int = doc("background points tracked", 0)
    explained: float = doc("share of the points that rotation + zoom explains; NaN = too few points",
                           float("nan"))


@dataclass(frozen=True, eq=False)
class Measurement:
    """Everything the detector measured in one frame (DESIGN §1.1 'for every frame')."""

    SCHEMA_VERSION: ClassVar[int] = 3  # 2: shot_change; 3: camera_motion
    MIN_SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("capture time of the frame [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("detector healthy", True)
    source: str = doc("source of the frame", "")
    frame_index: int = doc("index of the frame within its source", 0)
    fps: float = doc("source frame rate [Hz]; NaN = unknown", float("nan"))
    width: int = doc("frame width [px]", 0)
    height: int = doc("frame height [px]", 0)
    people: list[PersonDetection] = doc("every person found (may be empty)", default_factory=list)
    skeletons: list[Skeleton] = doc("every skeleton found (may be empty)", default_factory=list)
    focus_map: np.ndarray = array("uint8", (None, None), optional=True,
                                  doc="per-pixel in-focus probability x255, shape (h, w) at a "
                                      "resolution that may be lower than the frame's; None = not computed")
    lens: LensState | None = doc("lens state of the frame, if known", None)
    detector: str = doc("backend that produced this ('mediapipe', 'torchvision', ...)", "")
    shot_change: float = doc("colour-histogram distance to the previous frame of the source in [0, 1] "
                             "(a hard cut scores near 1); NaN = first frame or not computed",
                             float("nan"), since=2)
    camera_motion: CameraMotion | None = doc("the camera's motion since the previous frame of the source; None = "
                                             "first frame, a gap, or not measured", None, since=3)


@dataclass(frozen=True, eq=False)
class SourceInfo:
    """Metadata of the source video an instruction set was extracted from."""

    path: str = doc("file name or URL of the source", "")
    width: int = doc("source width [px]", 0)
    height: int = doc("source height [px]", 0)
    fps: float = doc("source frame rate [Hz]", 0.0)
    n_frames: int = doc("frames in the source", 0)
    sha256: str = doc("hash of the source file; '' = unknown", "")


@dataclass(frozen=True, eq=False)
class Instructions:
    """Recording instructions (DESIGN §1.2): per-frame image targets and focus booleans.

    K frames starting at `first_frame`; frame k lasts `frame_duration_s`. An edited source is
    several shots: `shot_start` marks the rows where each begins (a drone films each as a take).
    """

    SCHEMA_VERSION: ClassVar[int] = 3  # 2: shot_start; 3: camera motion
    MIN_SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time of the newest measurement used [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("smoother healthy", True)
    source: SourceInfo = doc("the source video", default_factory=SourceInfo)
    fps: float = doc("frame rate of the instructions [Hz]", 0.0)
    frame_duration_s: float = doc("duration of one instruction frame [s] (= 1/fps)", 0.0)
    first_frame: int = doc("source frame index of row 0", 0)
    final: bool = doc("True: whole sequence; False: a streaming window", True)
    joint_names: list[str] = doc("names of the E controlled joints (COCO-17 names)", default_factory=list)
    image_targets: np.ndarray = array("float32", (None, None, 2), allow_nan=True,
                                      doc="normalised (x, y) target of each controlled joint, shape "
                                          "(K, E, 2); NaN = not controlled in that frame")
    subject_visible: np.ndarray = array("bool", (None,), doc="main subject visible, shape (K,)")
    subject_box: np.ndarray = array("float32", (None, 4), allow_nan=True,
                                    doc="smoothed main-subject box (x0, y0, x1, y1), normalised, "
                                        "shape (K, 4); NaN = not visible")
    focus_raw: np.ndarray = array("float32", (None, 3), allow_nan=True,
                                  doc="fraction of focused pixels b per region (foreground, subject, "
                                      "background), shape (K, 3); NaN = region absent")
    focus_smoothed: np.ndarray = array("float32", (None, 3), allow_nan=True,
                                       doc="optimised B per region in [0, 1], shape (K, 3); NaN = no label (region "
                                           "absent, or never measured in its shot)")
    focus_in: np.ndarray = array("bool", (None, 3), doc="region in focus (B > theta), shape (K, 3)")
    theta: float = doc("focus threshold on B", 0.5)
    mu_m: float = doc("depth-of-field margin mu [m] (DESIGN §1.2)", 1.0)
    shot_start: np.ndarray = array("bool", (None,), optional=True, since=2,
                                          doc="row k starts a new shot of the source (a cut), shape (K,); "
                                              "row 0 is always a start; null = one shot")
    camera_motion_class: list[str] | None = doc(
        "the source camera's move in each row, shape (K,): 'static', or moves of 'pan', 'tilt', 'roll', 'zoom_in', "
        "'zoom_out', 'dolly_in', 'dolly_out', 'truck', 'pedestal', 'orbit', 'dolly_zoom' joined with '+'; '' = "
        "unknown; None = no camera-motion style (the planner ignores it)", None, since=3)
    pan_rate_dps: np.ndarray = array("float32", (None,), optional=True, allow_nan=True, since=3,
                                     doc="smoothed pan rate, positive to the camera's left (yaw up), shape (K,) "
                                         "[deg/s]; NaN = unknown")
    tilt_rate_dps: np.ndarray = array("float32", (None,), optional=True, allow_nan=True, since=3,
                                      doc="smoothed tilt rate, positive up, shape (K,) [deg/s]; NaN = unknown")
    roll_rate_dps: np.ndarray = array("float32", (None,), optional=True, allow_nan=True, since=3,
                                      doc="smoothed roll rate, positive clockwise as the camera sees it, shape "
                                          "(K,) [deg/s]; NaN = unknown")
    zoom_rate: np.ndarray = array("float32", (None,), optional=True, allow_nan=True, since=3,
                                  doc="smoothed d ln(focal length)/dt, shape (K,) [1/s]; NaN = unknown")
    translation_dir: np.ndarray = array("float32", (None, 3), optional=True, allow_nan=True, since=3,
                                        doc="direction of the camera's translation, unit vector in the camera frame "
                                            "(x right, y down, z forward), shape (K, 3); zeros = none seen; "
                                            "NaN = unknown")


@dataclass(frozen=True, eq=False)
class Setpoint:
    """What the planner wants the vehicle, gimbal and lens to do next (world frame)."""

    SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time the plan was computed for [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("planner healthy; False = do not fly this (bridge holds)", True)
    mode: str = doc("'track' (follow this setpoint) or 'hold' (hover in place)", "track")
    position_m: np.ndarray = array("float64", (3,), doc="position [m], world")
    velocity_mps: np.ndarray = array("float64", (3,), doc="velocity [m/s], world")
    acceleration_mps2: np.ndarray = array("float64", (3,), doc="feed-forward acceleration [m/s^2], world")
    camera_ypr_rad: np.ndarray = array("float64", (3,), doc="camera yaw, pitch, roll [rad], world")
    lens: LensState = doc("commanded focal length, focus distance, f-number", default_factory=LensState)
    instruction_frame: int = doc("instruction frame k being followed; -1 = none", -1)
    horizon_t_s: np.ndarray = array("float64", (None,), doc="times of the planned states from stamp [s], (N,)")
    horizon_position_m: np.ndarray = array("float64", (None, 3), doc="planned positions [m], world, (N, 3)")
    horizon_camera_ypr_rad: np.ndarray = array("float64", (None, 3), doc="planned camera yaw/pitch/roll, (N, 3)")
    horizon_lens: np.ndarray = array("float64", (None, 3),
                                     doc="planned (focal length mm, focus m, f-number), (N, 3)")
    solver_status: str = doc("status of the solve that produced this", "")


@dataclass(frozen=True, eq=False)
class VehicleState:
    """Where the vehicle, its gimbal and its lens are (world frame)."""

    SCHEMA_VERSION: ClassVar[int] = 3  # 2: envelope_breach; 3: lens_unsupported
    MIN_SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time of the state estimate [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("state estimate healthy", True)
    position_m: np.ndarray = array("float64", (3,), doc="position [m], world")
    velocity_mps: np.ndarray = array("float64", (3,), doc="velocity [m/s], world")
    attitude_ypr_rad: np.ndarray = array("float64", (3,), doc="vehicle body yaw, pitch, roll [rad]")
    camera_ypr_rad: np.ndarray = array("float64", (3,), doc="camera yaw, pitch, roll [rad], world")
    lens: LensState = doc("current lens state", default_factory=LensState)
    mode: str = doc("flight mode as the backend names it ('sim', 'OFFBOARD', 'GUIDED', 'HOLD', ...)", "")
    armed: bool = doc("motors armed", False)
    holding: bool = doc("the bridge is commanding a hold (watchdog, link loss or 'hold' setpoint)", False)
    backend: str = doc("'sim' or 'mavlink'", "")
    envelope_breach: bool = doc("the measured position is outside the bridge's geofence or altitude band; "
                                "the bridge is flying it back inside", False, since=2)
    lens_unsupported: list[str] = doc("lens axes the camera takes no command for ('focal_length_mm', "
                                      "'focus_distance_m', 'f_number'): the planner keeps them fixed",
                                      default_factory=list, since=3)


@dataclass(frozen=True, eq=False)
class SubjectState:
    """3-D joints of the filmed subject (simulator ground truth or onboard perception)."""

    SCHEMA_VERSION: ClassVar[int] = 2  # 2: heading_rad
    MIN_SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time of the estimate [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("estimate healthy", True)
    subject_id: str = doc("identifier of the subject", "")
    joint_names: list[str] = doc("names of the joints (COCO-17 names)", default_factory=lambda: list(COCO17_NAMES))
    joints_m: np.ndarray = array("float64", (None, 3), allow_nan=True,
                                 doc="joint positions [m], world, shape (J, 3); NaN = unknown joint")
    velocity_mps: np.ndarray = array("float64", (3,), doc="subject velocity [m/s], world (for prediction)")
    heading_rad: float = doc("yaw of the way the body faces [rad], world (0 = along +x, counter-clockwise "
                             "positive); NaN = unknown, or not fixed in the world (a cut-out that turns to "
                             "face the camera)", float("nan"), since=2)


@dataclass(frozen=True, eq=False)
class Command:
    """A control request to a node (e.g. start/pause/stop a recording)."""

    SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time the command was issued [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("always True for a real command", True)
    action: str = doc("'start', 'pause', 'resume', 'stop', 'hold'", "")
    args: dict[str, Any] = doc("action arguments (str/int/float/bool values)", default_factory=dict)


@dataclass(frozen=True, eq=False)
class Health:
    """Periodic statistics of one node, published on ct/{rig}/health/{node} at about 1 Hz."""

    SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time of the report [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("node healthy (inputs fresh, no recent errors)", True)
    node: str = doc("node name", "")
    uptime_s: float = doc("seconds since the node started", 0.0)
    received: int = doc("messages received (total)", 0)
    rejected: int = doc("messages rejected as malformed or of a wrong version (total)", 0)
    dropped: int = doc("messages dropped by bounded queues (total)", 0)
    published: int = doc("messages published (total)", 0)
    latency_ms_p50: float = doc("processing latency median over the last window [ms]; NaN = none", float("nan"))
    latency_ms_max: float = doc("processing latency max over the last window [ms]; NaN = none", float("nan"))
    last_error: str = doc("last error or rejection reason; '' = none", "")
    counters: dict[str, Any] = doc("node-specific counters and states (str/int/float/bool)", default_factory=dict)


@dataclass(frozen=True, eq=False)
class StreamEnd:
    """End of a stream (source frames, or the measurements made of them): what was sent and why
    it ended. Receivers finish the sequence once they hold `frames` items of it."""

    SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("time the stream ended [ns]", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("False: the stream ended on an error (see reason); what was sent is still good", True)
    source: SourceInfo = doc("the source the stream came from", default_factory=SourceInfo)
    frames: int = doc("items sent on the stream (frames or measurements)", 0)
    reason: str = doc("'end of file', 'stop requested', 'error: ...'", "")


@dataclass(frozen=True, eq=False)
class SimClock:
    """One step of the simulation clock (published by the simulator bridge, lockstep mode).

    In simulation the bridge owns time: it publishes the vehicle and subject state for time
    `stamp_ns`, then this tick, and (when a planner is alive) completes the step only once the
    planner's Setpoint stamped `stamp_ns` has arrived. Nodes that see ticks take "now" from them.
    """

    SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("simulation time of this step [ns] (epoch_ns + step * period)", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("simulator healthy", True)
    epoch_ns: int = doc("simulation time of step 0 since the last reset [ns]", 0)
    step: int = doc("steps since the last reset", 0)
    period_s: float = doc("simulated seconds per step (the control period)", 0.05)
    lockstep: bool = doc("True: the step waits for the planner's setpoint; False: free-running", True)
    pace: float = doc("simulated seconds per wall second the bridge aims at; 0 = as fast as possible", 1.0)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Exact truth of one simulated camera frame (published by the simulator only).

    Lets fidelity be computed exactly as well as by running extraction on the rendered video.
    """

    SCHEMA_VERSION: ClassVar[int] = 2  # 2: focal_length_mm, lens_limits, region_inverse_depth
    MIN_SCHEMA_VERSION: ClassVar[int] = 1
    stamp_ns: int = doc("capture time of the frame this describes [ns] (= Frame.stamp_ns)", 0)
    seq: int = doc("sequence number", 0)
    valid: bool = doc("simulator healthy", True)
    frame_index: int = doc("index of the frame (= Frame.index)", 0)
    joint_names: list[str] = doc("names of the joints (COCO-17)", default_factory=lambda: list(COCO17_NAMES))
    joints_norm: np.ndarray = array("float32", (None, 2), allow_nan=True,
                                    doc="exact normalised image position of each joint, (J, 2); "
                                        "NaN = behind the camera")
    joints_visible: np.ndarray = array("bool", (None,), doc="joint inside the image and in front, (J,)")
    subject_distance_m: float = doc("camera-to-subject distance along the optical axis [m]", 0.0)
    dof_near_m: float = doc("near limit of the depth of field [m]", 0.0)
    dof_far_m: float = doc("far limit of the depth of field [m]; NaN = infinite", float("nan"))
    region_present: np.ndarray = array("bool", (3,), doc="foreground/subject/background visible in frame")
    region_in_focus: np.ndarray = array("bool", (3,), doc="foreground/subject/background in focus")
    region_focus_fraction: np.ndarray = array("float32", (3,), allow_nan=True,
                                              doc="fraction of each region's pixels in focus; NaN = absent")
    focal_length_mm: float = doc("focal length the frame was filmed at [mm]; NaN = not recorded",
                                 float("nan"), since=2)
    lens_limits: np.ndarray = array("float32", (None,), since=2,
                                    doc="the vehicle's lens range: [nearest focus m, farthest focus m, smallest "
                                        "f-number, largest f-number], (4,); empty = not recorded")
    region_inverse_depth: np.ndarray = array(
        "float32", (3, None), allow_nan=True, since=2,
        doc="each region's depth as 1/m (0 = at infinity, the sky) at its 2.5, 7.5, ..., 97.5 % points: an "
            "equal-weight sample of its pixels, (3, 20); NaN row = no such pixels (a band below the feet too "
            "short to be a foreground keeps its depths); (3, 0) = not recorded")


#: Every message type that can be sent on its own, by wire name.
MESSAGE_TYPES: dict[str, type] = {
    cls.__name__: cls
    for cls in (Frame, Measurement, Instructions, Setpoint, VehicleState, SubjectState, Command, Health,
                GroundTruth, SimClock, StreamEnd)
}

#: Types that appear only inside other messages.
NESTED_TYPES: dict[str, type] = {
    cls.__name__: cls for cls in (LensState, PersonDetection, Skeleton, SourceInfo, CameraMotion)
}


def now_ns() -> int:
    """Wall-clock time [ns since epoch], the clock every stamp_ns uses."""
    import time

    return time.time_ns()
