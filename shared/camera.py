"""Camera and thin-lens model as pure numpy functions (DESIGN §1.3).

Units: focal length and circle of confusion in mm, distances in metres, angles in radians.

Frames:
- world: right-handed, z up.
- camera: x forward (optical axis), y left, z up (CineMPC's body convention).
- normalised image: u right, v down, (0, 0) top-left, (1, 1) bottom-right, (0.5, 0.5) centre.

Camera attitude is (yaw, pitch, roll): yaw about world z (0 looks along +x), pitch positive
looking up, roll about the optical axis; R = Rz(yaw) Ry(-pitch) Rx(roll) maps camera to world.

The planner re-implements projection and depth of field symbolically in casadi; its tests
check it against these functions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: CineMPC's "Digital Film 16:9" sensor [mm].
SENSOR_WIDTH_MM = 23.76
SENSOR_HEIGHT_MM = 13.365

#: Gaussian sigma per blur-circle diameter (a uniform disc of diameter d rendered as a Gaussian of
#: per-axis std d/4): how the simulator draws defocus, and how a blur sigma reads as a circle.
SIGMA_PER_DIAMETER = 0.25
#: Where "in focus" ends: the defocus sigma, as a fraction of the frame width, at which the
#: detector's focus estimator flips (mean in-focus probability of a blurred textured frame 0.5).
#: Measured on the simulator's backdrop, hedge and lawn textures and two DAVIS frames at 640, 960
#: and 1280 px: 0.79-1.10 px at the estimator's 640 px work width, median 0.9 (docs/planner.md
#: "One definition of in focus"; tests/unit/test_focus_definition.py keeps the measurement).
FOCUS_FLIP_SIGMA_PER_WIDTH = 0.9 / 640


#: a region (foreground, subject, background) is "in focus" when at least this share of its pixels
#: lies inside the depth of field: the simulator's truth and the report's reachability use it.
REGION_IN_FOCUS_SHARE = 0.5


def coc_mm_for_sensor(sensor_width_mm: float) -> float:
    """The circle of confusion [mm] of a sensor `sensor_width_mm` wide: the blur disc whose sigma
    is the focus estimator's flip, whatever the output resolution (the estimator works at a fixed
    fraction of the frame width). The one definition of "in focus": the planner's depth-of-field
    targets, the simulator's truth and the report all use it."""
    return FOCUS_FLIP_SIGMA_PER_WIDTH / SIGMA_PER_DIAMETER * sensor_width_mm


#: the circle of confusion of CineMPC's sensor [mm] (0.134)
COC_MM = coc_mm_for_sensor(SENSOR_WIDTH_MM)

#: How closely the lens holds a wanted setting: the autopilot bridge sends a lens change only when it
#: exceeds this (focus: relative, times max(1, the sent value in m)), so the lens settles anywhere
#: within it of what the planner asks. The report's reach search asks a setting to give the labels
#: over this whole hold, not on a knife edge (report.focus_reach).
LENS_HOLD = {"focal_length_mm": 0.5, "focus_distance_m": 0.02, "f_number": 0.05}


@dataclass(frozen=True)
class Sensor:
    width_mm: float = SENSOR_WIDTH_MM
    height_mm: float = SENSOR_HEIGHT_MM
    coc_mm: float = COC_MM


def rotation_ypr(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Camera-to-world rotation matrix for camera attitude (yaw, pitch, roll) [rad]."""
    cy, sy = math.cos(yaw), math.sin(yaw)
    cp, sp = math.cos(-pitch), math.sin(-pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def world_to_camera(points_w: np.ndarray, cam_pos_w: np.ndarray, cam_ypr: np.ndarray) -> np.ndarray:
    """Points (..., 3) from world to camera coordinates (x forward, y left, z up)."""
    r = rotation_ypr(*np.asarray(cam_ypr, dtype=float))
    return (np.asarray(points_w, dtype=float) - np.asarray(cam_pos_w, dtype=float)) @ r


def project_normalised(points_c: np.ndarray, focal_length_mm: float,
                       sensor: Sensor = Sensor()) -> np.ndarray:
    """Pinhole projection of camera-frame points (..., 3) to normalised image coords (..., 2).

    u = 1/2 - f y / (x w_s),  v = 1/2 - f z / (x h_s). Points behind the camera (x <= 0) give NaN.
    """
    p = np.asarray(points_c, dtype=float)
    x = p[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = 0.5 - focal_length_mm * p[..., 1] / (x * sensor.width_mm)
        v = 0.5 - focal_length_mm * p[..., 2] / (x * sensor.height_mm)
    out = np.stack([u, v], axis=-1)
    out[x <= 0] = np.nan
    return out


def project_world(points_w: np.ndarray, cam_pos_w: np.ndarray, cam_ypr: np.ndarray,
                  focal_length_mm: float, sensor: Sensor = Sensor()) -> np.ndarray:
    """World points (..., 3) to normalised image coordinates (..., 2)."""
    return project_normalised(world_to_camera(points_w, cam_pos_w, cam_ypr), focal_length_mm, sensor)


def hyperfocal_m(focal_length_mm: float, f_number: float, coc_mm: float = COC_MM) -> float:
    """Hyperfocal distance H = f^2 / (A c) + f, in metres."""
    f = focal_length_mm
    return (f * f / (f_number * coc_mm) + f) / 1000.0


def dof_limits_m(focal_length_mm: float, f_number: float, focus_m: float,
                 coc_mm: float = COC_MM) -> tuple[float, float]:
    """Near and far limits (D_n, D_f) of the depth of field [m].

    D_n = s (H - f) / (H + s - 2 f);  D_f = s (H - f) / (H - s) for s < H, else +inf.
    """
    h = hyperfocal_m(focal_length_mm, f_number, coc_mm)
    f = focal_length_mm / 1000.0
    s = focus_m
    near = s * (h - f) / (h + s - 2.0 * f)
    far = s * (h - f) / (h - s) if s < h else math.inf
    return near, far


def blur_diameter_mm(distance_m: np.ndarray | float, focal_length_mm: float, f_number: float,
                     focus_m: float) -> np.ndarray | float:
    """Diameter on the sensor [mm] of the blur circle of a point at `distance_m` (thin lens).

    c(d) = f^2 / (A (s - f)) * |d - s| / d; equals the circle of confusion c exactly at D_n
    and D_f.
    """
    f = focal_length_mm / 1000.0
    d = np.asarray(distance_m, dtype=float)
    c_m = (f * f / (f_number * (focus_m - f))) * np.abs(d - focus_m) / d
    out = c_m * 1000.0
    return float(out) if np.ndim(out) == 0 else out


def in_focus(distance_m: np.ndarray | float, focal_length_mm: float, f_number: float, focus_m: float,
             coc_mm: float = COC_MM) -> np.ndarray | bool:
    """Whether points at `distance_m` lie inside the depth of field."""
    near, far = dof_limits_m(focal_length_mm, f_number, focus_m, coc_mm)
    d = np.asarray(distance_m, dtype=float)
    out = (d >= near) & (d <= far)
    return bool(out) if np.ndim(out) == 0 else out


def realisable_labels(b_fg: bool, b_subject: bool, b_bg: bool) -> tuple[bool, bool, bool]:
    """The focus labels one depth of field can give, from those asked (foreground, subject, background).

    The depth of field is one interval of depth: a sharp foreground and a sharp background with a
    soft subject between them is the one combination no lens gives. The foreground then gives way,
    in the order in which the report grants labels (subject, background, foreground:
    report.focus_reach.PRIORITY), so the planner plans what the report judges reachable. Before,
    such a row (a source's foreground read sharp for a few frames of a "subject soft, background
    sharp" shot) asked for everything sharp, the subject included.
    """
    if b_fg and b_bg and not b_subject:
        return False, False, True
    return bool(b_fg), bool(b_subject), bool(b_bg)


def desired_dof_limits(b_fg: bool, b_subject: bool, b_bg: bool, distance_m: float,
                       mu_m: float, *, defocus_when_none: bool = False) -> tuple[float, float]:
    """Target (D_n*, D_f*) from the focus booleans (DESIGN §1.2), as far as they are realisable
    (realisable_labels).

    +inf for D_n* / -inf for D_f* means "not controlled". DESIGN's table leaves everything
    uncontrolled when no region is in focus; with `defocus_when_none` that case instead asks
    for the depth of field to end mu in front of the subject (D_f* = d - mu), so that a
    source shot where nothing is sharp is imitated rather than ignored.
    """
    b_fg, b_subject, b_bg = realisable_labels(b_fg, b_subject, b_bg)
    if defocus_when_none and not (b_fg or b_subject or b_bg):
        return math.inf, distance_m - mu_m
    if b_fg:
        near = 0.0
    elif b_subject:
        near = distance_m - mu_m
    elif b_bg:
        near = distance_m + mu_m
    else:
        near = math.inf
    if b_bg:
        far = math.inf
    elif b_subject:
        far = distance_m + mu_m
    elif b_fg:
        far = distance_m - mu_m
    else:
        far = -math.inf
    return near, far
