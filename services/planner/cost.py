"""Cost terms of the MPC, written with casadi operations (they work on SX, MX and plain floats).

Conventions are those of `cinetransfer.shared.camera` (its tests check these against it):
- camera frame x forward, y left, z up; R = Rz(yaw) Ry(-pitch) Rx(roll) maps camera to world,
  so a world point P seen from camera position C is p_c = R^T (P - C);
- normalised image u = 1/2 - f y / (x w_s), v = 1/2 - f z / (x h_s) with f, w_s, h_s in mm;
- thin lens: H = f^2 / (A c) + f, D_n = s (H - f) / (H + s - 2 f), D_f = s (H - f) / (H - s).

Depth of field in reciprocal form (DESIGN §4 pitfall). With every length in metres,
    1 / D_n = 1/s + (s - f) / (s (H - f)),   1 / D_f = 1/s - (s - f) / (s (H - f)),
and H - f = f^2 / (A c). Both are smooth for every s > f: 1/D_f just crosses 0 at s = H (the far
limit reaches infinity) and is negative beyond (still infinite). So the cost on 1/D_n and 1/D_f
never blows up, and a far target at infinity is a one-sided term max(0, 1/D_f + margin)^2.
The errors are scaled by the subject distance d, so d (1/D - 1/D*) is about the relative error.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as ca

from cinetransfer.services.planner import camera_motion as CM
from cinetransfer.services.planner import constraints as C
from cinetransfer.services.planner import obstacles as OB
from cinetransfer.services.planner.config import WEIGHT_NAMES, Structure
from cinetransfer.services.planner.model import Layout
from cinetransfer.services.planner.side_of_subject import FREE_ANGLE_RAD as SIDE_FREE_RAD


def rotation_ypr(yaw, pitch, roll=0.0):  # noqa: ANN001, ANN201 - casadi or float
    """Camera-to-world rotation R = Rz(yaw) Ry(-pitch) Rx(roll) (as shared.camera.rotation_ypr)."""
    cy, sy = ca.cos(yaw), ca.sin(yaw)
    cp, sp = ca.cos(-pitch), ca.sin(-pitch)
    cr, sr = ca.cos(roll), ca.sin(roll)
    rz = ca.vertcat(ca.horzcat(cy, -sy, 0), ca.horzcat(sy, cy, 0), ca.horzcat(0, 0, 1))
    ry = ca.vertcat(ca.horzcat(cp, 0, sp), ca.horzcat(0, 1, 0), ca.horzcat(-sp, 0, cp))
    rx = ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, cr, -sr), ca.horzcat(0, sr, cr))
    return ca.mtimes([rz, ry, rx])


def world_to_camera(point_w, cam_pos_w, yaw, pitch, roll=0.0):  # noqa: ANN001, ANN201
    """A world point (3-vector) in camera coordinates (x forward, y left, z up)."""
    r = rotation_ypr(yaw, pitch, roll)
    return ca.mtimes(r.T, point_w - cam_pos_w)


def soft_depth(x, floor_m, smooth_m=0.2):  # noqa: ANN001, ANN201
    """Smooth stand-in for the depth x that never falls below floor_m: floor + softplus(x - floor).

    Equals x to within 0.1 % once x >= floor + 5 smooth_m (e.g. 2 m for floor 1 m), and tends to
    floor_m for points near or behind the camera. So the pinhole cost stays bounded there instead
    of exploding as 1/x (which made the optimiser fly through the subject to get it in front):
    behind the camera the image term goes flat and the look term turns the camera round.
    """
    z = x - floor_m
    return floor_m + ca.fmax(z, 0) + smooth_m * ca.log(1 + ca.exp(-ca.fabs(z) / smooth_m))


def project(point_c, focal_mm, sensor_w_mm, sensor_h_mm, depth_floor=None):  # noqa: ANN001, ANN201
    """Normalised image coordinates (u, v) of a camera-frame point (exact pinhole if depth_floor is None).

    With depth_floor the depth is replaced by soft_depth(x, depth_floor) (see there).
    """
    x = point_c[0] if depth_floor is None else soft_depth(point_c[0], depth_floor)
    u = 0.5 - focal_mm * point_c[1] / (x * sensor_w_mm)
    v = 0.5 - focal_mm * point_c[2] / (x * sensor_h_mm)
    return u, v


def project_extended(point_c, focal_mm, sensor_w_mm, sensor_h_mm, theta0_rad=math.pi / 3):  # noqa: ANN001, ANN201
    """Pinhole projection within theta0 of the optical axis, extended monotonically beyond.

    A point at angle theta from the axis and azimuth phi (in the image plane) lies at image
    radius (in units of f/w_s, f/h_s) h(theta) along phi. The pinhole has h = tan(theta), which
    explodes at 90 deg and is undefined behind the camera: a cost built on it either blows up
    (and the cheapest 'fix' is to fly through the subject) or, with a bounded depth, maps a joint
    straight behind the camera near the centre, so the mirrored target becomes a false minimum.
    Here h(theta) = tan(theta) up to theta0 (exact pinhole: every point of the image is inside,
    the widest diagonal half-angle at f >= 20 mm is < 40 deg) and continues linearly (C1) to
    theta = pi. The map from directions to the image plane is then one-to-one and bounded, so
    the image error of a joint has a single minimum, at its target, wherever the camera points.
    """
    x, y, z = point_c[0], point_c[1], point_c[2]
    rho = ca.sqrt(y * y + z * z + 1e-12)
    n = ca.sqrt(x * x + rho * rho)
    c0 = math.cos(theta0_rad)
    inside = x >= c0 * n
    x_safe = ca.fmax(x, 0.5 * c0 * n)  # inactive where this branch is used (x >= c0 n)
    theta = ca.atan2(rho, x)
    g_out = (math.tan(theta0_rad) + (theta - theta0_rad) / (c0 * c0)) / rho  # rho >= 1e-6
    g = ca.if_else(inside, 1 / x_safe, g_out)
    return 0.5 - focal_mm * y * g / sensor_w_mm, 0.5 - focal_mm * z * g / sensor_h_mm


def joint_image_error(point_c, u_t, v_t, focal_mm, sensor_w_mm, sensor_h_mm, *,  # noqa: ANN001, ANN201
                      theta0_rad=math.pi / 3):
    """Squared normalised image error (u - u*)^2 + (v - v*)^2 of one joint (J_im term).

    Exactly the pinhole error for joints within theta0 of the optical axis (project_extended).
    """
    u, v = project_extended(point_c, focal_mm, sensor_w_mm, sensor_h_mm, theta0_rad)
    return (u - u_t) ** 2 + (v - v_t) ** 2


def hyperfocal_m(focal_mm, fnumber, coc_mm):  # noqa: ANN001, ANN201
    """H = f^2 / (A c) + f [m] for f and c in mm."""
    return (focal_mm * focal_mm / (fnumber * coc_mm) + focal_mm) / 1000.0


def inverse_dof_limits(focal_mm, fnumber, focus_m, coc_mm):  # noqa: ANN001, ANN201
    """(1/D_n, 1/D_f) [1/m]; smooth for every focus distance above the focal length.

    1/D_f <= 0 means the far limit is at infinity (s >= H).
    """
    f_m = focal_mm / 1000.0
    h_minus_f = focal_mm * focal_mm / (fnumber * coc_mm) / 1000.0
    spread = (focus_m - f_m) / (focus_m * h_minus_f)
    return 1.0 / focus_m + spread, 1.0 / focus_m - spread


def far_limit_for_circle(inv_near, inv_far, ratio):  # noqa: ANN001, ANN201
    """1/D_f of the same lens for a circle of confusion `ratio` times larger.

    In inverse depth the limits sit symmetrically about 1/s at 1/s +- spread, and the spread is
    proportional to the circle of confusion (inverse_dof_limits), so this is exact.
    """
    return 0.5 * (inv_near + inv_far) - ratio * 0.5 * (inv_near - inv_far)


def near_limit_for_circle(inv_near, inv_far, ratio):  # noqa: ANN001, ANN201
    """1/D_n of the same lens for a circle of confusion `ratio` times larger (as far_limit_for_circle)."""
    return 0.5 * (inv_near + inv_far) + ratio * 0.5 * (inv_near - inv_far)


def subject_softness(b_subject: float, theta: float) -> float:
    """How far the source's smoothed subject focus B lies below the threshold theta, as a fraction
    of theta (0 at or above it, 1 at B = 0); a subject absent from the source (NaN) counts as
    plainly soft."""
    if not math.isfinite(b_subject):
        return 1.0
    return min(max((theta - b_subject) / theta, 0.0), 1.0) if theta > 0 else 0.0


#: how far above the threshold theta a smoothed B has to lie for its "sharp" label to be asked in full
#: (label_sharpness): a label within it is borderline, a coin flip of the smoother's window
BORDERLINE_LABEL_BAND = 0.1


def label_sharpness(b: float, theta: float, band: float = BORDERLINE_LABEL_BAND) -> float:
    """How plainly the source's smoothed B reads sharp: 0 at or below the threshold theta, rising linearly to 1
    at theta + `band`; 1 with no B known (NaN) or no band. The weight of a limit asked for a sharp label: the
    one-frame foreground label of tos_clip01's row 184 (B 0.505, its raw 0.09-0.11) asked the near limit at 1 m
    with the subject 10 m away, the deepest field of its take, from the end of 35 rows asking him sharp before a
    soft background."""
    if not math.isfinite(b) or band <= 0:
        return 1.0
    return min(max((b - theta) / band, 0.0), 1.0)


def far_keeps_subject_out(b_fg: bool, b_subject: bool, b_bg: bool) -> bool:
    """The far limit's target keeps the subject out of focus (D_f* = d - mu: only the foreground,
    or nothing, in focus; shared.camera.desired_dof_limits)."""
    return not (b_subject or b_bg)


def near_keeps_subject_out(b_fg: bool, b_subject: bool, b_bg: bool) -> bool:
    """The near limit's target keeps the subject out of focus (D_n* = d + mu: only the background
    in focus; shared.camera.desired_dof_limits)."""
    return b_bg and not (b_fg or b_subject)


def defocus_ratio(keeps_out: bool, ratio: float, softness: float) -> float:
    """Circle-of-confusion ratio of a stage's far limit: 1 + (ratio - 1) softness where the limit
    keeps the subject out, so that its blur is one a viewer (and the detector's focus estimator)
    sees, and a borderline label (softness near 0, subject_softness) does not swing the lens as far
    as a plainly blurred subject; 1 elsewhere (a limit that keeps a region in focus uses the
    sharpness criterion itself)."""
    return 1.0 + (ratio - 1.0) * min(max(softness, 0.0), 1.0) if keeps_out else 1.0


def switched_out(keeps_out: Sequence[bool], now_row: int, row: int) -> bool:
    """Whether the style has already switched the subject out at the row followed now: every
    instruction row from `now_row` to a stage's `row` keeps it out (`keeps_out`, per row).

    Visible defocus is asked of such stages only. A switch still ahead is previewed with the
    sharpness limit alone, whose least-squares plan crosses it on time; previewed with the larger
    circle, the larger lens move is met half-way before the switch (the subject left the depth of
    field 0.1-0.25 s early in the closed-loop dolly zoom), so the extra blur follows the switch.
    """
    return all(keeps_out[j] for j in range(now_row, row + 1))


def dof_cost(inv_near, inv_far, distance_m, *, w_near, g_near, w_far, g_far, far_one_sided,  # noqa: ANN001, ANN201
             near_one_sided=0):
    """(d r_n)^2 w_n + (d r_f)^2 w_f with r_n = 1/D_n - g_n, or min(0, that) if one-sided, and
    r_f = 1/D_f - g_f, or max(0, that) if one-sided.

    g_* are the reciprocal targets 1/D*; w_* = 0 leaves a limit uncontrolled; far_one_sided in
    {0, 1} selects 'far limit at or beyond the target' (used for D_f* = infinity with g_f < 0);
    near_one_sided 'near limit at or nearer than the target' (no foreground to keep blurred).
    """
    e_n, e_f = dof_residuals(inv_near, inv_far, distance_m, g_near=g_near, g_far=g_far, far_one_sided=far_one_sided,
                             near_one_sided=near_one_sided)
    return w_near * e_n * e_n + w_far * e_f * e_f


def look_cost(point_c):  # noqa: ANN001, ANN201
    """1 - cos(angle between the optical axis and the point): 0 when centred, 2 when behind."""
    n = ca.sqrt(point_c[0] ** 2 + point_c[1] ** 2 + point_c[2] ** 2 + 1e-6)
    return 1.0 - point_c[0] / n


def bearing_cos(rel_xy, wanted_xy):  # noqa: ANN001, ANN201
    """cos(angle between the camera's bearing round the subject, the horizontal direction of
    `rel_xy` = camera minus subject, and the unit `wanted_xy`)."""
    n = ca.sqrt(rel_xy[0] ** 2 + rel_xy[1] ** 2 + 1e-6)
    return (rel_xy[0] * wanted_xy[0] + rel_xy[1] * wanted_xy[1]) / n


def bearing_shortfall(rel_xy, wanted_xy, free_rad):  # noqa: ANN001, ANN201
    """max(0, cos(free_rad) - bearing_cos): 0 within `free_rad` of the wanted bearing (any view
    that close shows the same side), growing beyond; the side-of-subject cost is its square."""
    return ca.fmax(math.cos(free_rad) - bearing_cos(rel_xy, wanted_xy), 0)


def log_rate(rate, value):  # noqa: ANN001, ANN201
    """d ln(value)/dt of a quantity changing at `rate` (the zoom rate of a focal length)."""
    return rate / value


def distance_log_rate(rel, rel_vel):  # noqa: ANN001, ANN201
    """d ln|rel|/dt = rel . rel_vel / |rel|^2 (the rate at which the subject distance grows, relative)."""
    return (rel[0] * rel_vel[0] + rel[1] * rel_vel[1] + rel[2] * rel_vel[2]) / (
        rel[0] ** 2 + rel[1] ** 2 + rel[2] ** 2 + 1e-6)


def bearing_rate(rel, rel_vel):  # noqa: ANN001, ANN201
    """d(bearing of the camera round the subject)/dt in the horizontal plane [rad/s] for the camera's
    offset `rel` from the subject and its velocity relative to him: (rel x rel_vel)_z / |rel_xy|^2."""
    return (rel[0] * rel_vel[1] - rel[1] * rel_vel[0]) / (rel[0] ** 2 + rel[1] ** 2 + 1e-6)


def headroom_shortfall(f_mm, log_floor, log_ceiling):  # noqa: ANN001, ANN201
    """(ln f below the floor, ln f above the ceiling), each 0 inside: how far the focal length
    stands from leaving the lens room for the zoom still to come."""
    log_f = ca.log(ca.fmax(f_mm, 1e-3))
    return ca.vertcat(ca.fmax(log_floor - log_f, 0), ca.fmax(log_f - log_ceiling, 0))


def travel_residual(vel, direction, v_scale, least=0):  # noqa: ANN001, ANN201
    """(velocity off the direction, velocity short of `least` along it) / v_max for a unit world
    `direction`: nothing for travel along it at any speed from `least` [m/s] on (the style gives a
    direction, not a speed)."""
    along = vel[0] * direction[0] + vel[1] * direction[1] + vel[2] * direction[2]
    return ca.vertcat(sideways_velocity(vel, direction, v_scale), ca.fmin(along - least, 0) * v_scale)


def level_rail(axis, level):  # noqa: ANN001, ANN201
    """The unit world direction a camera that stands still sideways may travel along: its optical
    `axis`, or with `level` 1 (a dolly's or a dolly-zoom's row) the axis levelled, as a dolly's rails
    are. The rendered dollies travel parallel to the ground; along the axis of a camera pitched down
    3-4 deg the output's dolly-zoom in sank 2.5-3.4 deg (the dolly-zoom out climbed 3-4.6 deg), where
    the extraction's ground, which takes the camera to move parallel to it, read the zoom short."""
    flat = ca.vertcat(axis[0], axis[1], 0) / ca.sqrt(axis[0] ** 2 + axis[1] ** 2 + 1e-12)
    return axis + level * (flat - axis)


def along_velocity(vel, forward, v_scale):  # noqa: ANN001, ANN201
    """The velocity along the unit world direction `forward` / v_max (a zoom flown while moving
    along the optical axis reads as a dolly-zoom)."""
    return (vel[0] * forward[0] + vel[1] * forward[1] + vel[2] * forward[2]) * v_scale


def sideways_velocity(vel, forward, v_scale):  # noqa: ANN001, ANN201
    """The velocity off the unit world direction `forward` / v_max. Off the optical axis it is what
    reads as truck, pedestal or orbit; travel along the axis is left to the framing."""
    return (vel - along_velocity(vel, forward, 1.0) * forward) * v_scale


def reciprocal_targets(near_m: float, far_m: float, *, near_foreground_m: float, far_margin_inv_m: float,
                       fg_absent: bool = False) -> tuple[float, float, float, float, float, float]:
    """Map desired limits (D_n*, D_f*) from shared.camera.desired_dof_limits to cost parameters.

    Returns (w_near_mask, g_near, w_far_mask, g_far, far_one_sided, near_one_sided):
    - D_n* = +inf: near uncontrolled (mask 0); D_n* = 0 (foreground in focus) is unreachable and
      aims at near_foreground_m instead; otherwise g_n = 1 / D_n* (D_n* clamped to >= 0.1 m),
      one-sided when the source shows no foreground (`fg_absent`): nothing in front of the
      subject is to be kept out of focus, so a nearer limit costs nothing (else a foreground that
      comes and goes pulled the focus between the 1 m target and the subject's, and the pull
      crossed the hyperfocal distance);
    - D_f* = -inf: far uncontrolled; D_f* = +inf: one-sided 1/D_f <= -far_margin_inv_m;
      otherwise g_f = 1 / D_f* (clamped to >= 0.1 m). An absent background stays two-sided: made
      one-sided likewise, tos_clip01 -> focus_hedge lost subject focus (truth 0.943 -> 0.924).
    """
    import math

    near_one = 0.0
    if math.isinf(near_m) and near_m > 0:
        wn, gn = 0.0, 0.0
    elif near_m <= 0.0:
        wn, gn = 1.0, 1.0 / near_foreground_m
    else:
        wn, gn, near_one = 1.0, 1.0 / max(near_m, 0.1), float(fg_absent)
    if math.isinf(far_m) and far_m < 0:
        wf, gf, one = 0.0, 0.0, 0.0
    elif math.isinf(far_m):
        wf, gf, one = 1.0, -far_margin_inv_m, 1.0
    else:
        wf, gf, one = 1.0, 1.0 / max(far_m, 0.1), 0.0
    return wn, gn, wf, gf, one, near_one


# --- residual forms (Gauss-Newton Hessian of the SQP solver; the cost itself is built from the terms above)
def joint_image_residual(point_c, u_t, v_t, focal_mm, sensor_w_mm, sensor_h_mm, *,  # noqa: ANN001, ANN201
                         theta0_rad=math.pi / 3):
    """(u - u*, v - v*) of one joint: joint_image_error is the sum of their squares."""
    u, v = project_extended(point_c, focal_mm, sensor_w_mm, sensor_h_mm, theta0_rad)
    return u - u_t, v - v_t


def look_residual(point_c):  # noqa: ANN001, ANN201
    """r = p/|p| - e_x: 0.5 |r|^2 = 1 - cos(angle) = look_cost (up to its 1e-6 regularisation)."""
    n = ca.sqrt(point_c[0] ** 2 + point_c[1] ** 2 + point_c[2] ** 2 + 1e-6)
    return ca.vertcat(point_c[0] / n - 1.0, point_c[1] / n, point_c[2] / n)


def dof_residuals(inv_near, inv_far, distance_m, *, g_near, g_far, far_one_sided,  # noqa: ANN001, ANN201
                  near_one_sided=0):
    """(e_n, e_f) of dof_cost, which is w_near e_n^2 + w_far e_f^2."""
    r_n = inv_near - g_near
    r_n = near_one_sided * ca.fmin(r_n, 0) + (1 - near_one_sided) * r_n
    r_f = inv_far - g_far
    r_f = far_one_sided * ca.fmax(r_f, 0) + (1 - far_one_sided) * r_f
    return distance_m * r_n, distance_m * r_f


# --- the NLP's stages, built from the terms above (MpcSolver builds its NLP once from these)
N_DOF = 8  # per stage: w_near mask, g_near, w_far mask, g_far, far_one_sided, near_one_sided,
#           the far and the near limit's circle-of-confusion ratios (defocus_ratio)


class ParamLayout:
    """Offsets of the pieces of the parameter vector p."""

    def __init__(self, s: Structure) -> None:
        lay = Layout(s.control_roll)
        e, n = s.max_joints, s.horizon_steps
        sizes = [("u_prev", lay.nu), ("joints", 3 * e), ("centre", 3), ("subj_vel", 3),
                 ("targets", n * e * 2), ("mask", n * e), ("dof", n * N_DOF), ("dref", n), ("motion", n * CM.N_MOTION),
                 ("weights", len(WEIGHT_NAMES)), ("u_scale", lay.nu), ("v_scale", 1), ("soft", C.N_LIMITS),
                 ("obstacles", n * OB.STAGE_SIZE)]
        self.slices: dict[str, slice] = {}
        off = 0
        for name, size in sizes:
            self.slices[name] = slice(off, off + size)
            off += size
        self.size = off


@dataclass
class NlpTerms:
    """What the stages of the NLP add up to: cost, constraint rows (NLP and stage-wise QP forms),
    Gauss-Newton residuals, and the input-change residuals (exact; majorised)."""

    cost: object = 0
    g: list = field(default_factory=list)
    g_ocp: list = field(default_factory=list)
    resid: list = field(default_factory=list)
    du_exact: list = field(default_factory=list)
    du_major: list = field(default_factory=list)


@dataclass(frozen=True)
class NlpParams:
    """The pieces of the parameter vector p, as symbols (see ParamLayout)."""

    u_prev: object
    joints0: object  #: (3, E): column j = joint j
    centre0: object
    vel: object
    targets: object
    mask: object
    dof: object
    dref: object
    wts: dict
    u_scale: object
    v_scale: object
    soft: object  #: the soft constraints' limits (constraints.soft_limits)
    motion: object = 0  #: (N * N_MOTION) side of the subject and camera-motion style (camera_motion.py)
    obstacles: object = 0  #: (N * STAGE_SIZE) every stage's obstacle slots (obstacles.stage_obstacle_params)

    @classmethod
    def of(cls, p, sl: dict[str, slice], e: int) -> NlpParams:
        return cls(u_prev=p[sl["u_prev"]], joints0=ca.reshape(p[sl["joints"]], 3, e), centre0=p[sl["centre"]],
                   vel=p[sl["subj_vel"]], targets=p[sl["targets"]], mask=p[sl["mask"]], dof=p[sl["dof"]],
                   dref=p[sl["dref"]], wts={name: p[sl["weights"]][i] for i, name in enumerate(WEIGHT_NAMES)},
                   u_scale=p[sl["u_scale"]], v_scale=p[sl["v_scale"]][0], soft=p[sl["soft"]],
                   motion=p[sl["motion"]], obstacles=p[sl["obstacles"]])


class StageBuilder:
    """The stages of the NLP (dynamics, soft constraints, cost and the SQP's residuals) from the
    decision vector w and the parameter symbols, for a structure, its layout and dynamics matrices."""

    def __init__(self, s: Structure, layout: Layout, dt: float, ab_dm: tuple) -> None:
        self.s, self.layout, self.dt, self.e, self._ab_dm = s, layout, dt, s.max_joints, ab_dm

    def terms(self, w, par: NlpParams, v_copy, *, aug: bool, majorise: bool) -> NlpTerms:  # noqa: ANN001
        """Every stage's terms; `aug`: stage k >= 1 takes its previous input from v_copy (the SQP)."""
        lay, n = self.layout, self.s.horizon_steps
        nx, nu = lay.nx, lay.nu
        blk = nu + nx + C.N_SOFT
        terms = NlpTerms()
        x_prev = w[0:nx]
        u_last = par.u_prev
        for k in range(n):
            off = nx + k * blk
            u, x, slack = w[off:off + nu], w[off + nu:off + nu + nx], w[off + nu + nx:off + blk]
            self._add_stage(terms, k, par, x_prev=x_prev, u_last=u_last, u=u, x=x, slack=slack, majorise=majorise)
            x_prev, u_last = x, (v_copy[k * nu:(k + 1) * nu] if aug and k < n - 1 else u)
        return terms

    def _input_groups(self) -> tuple[list[int], list[int], list[int]]:
        """Indices of the input vector: accelerations, camera rates, lens rates."""
        lay = self.layout
        return list(range(0, 3)), list(range(3, lay.F_RATE)), list(range(lay.F_RATE, lay.nu))

    def _add_stage(self, terms: NlpTerms, k: int, par: NlpParams, *, x_prev, u_last, u, x, slack,
                   majorise: bool) -> None:
        """Stage k+1 of the NLP: its dynamics and soft constraints (in both forms), its cost and,
        for the SQP, its Gauss-Newton residuals."""
        s, lay, dt = self.s, self.layout, self.dt
        a_dm, b_dm = self._ab_dm
        tk = (k + 1) * dt
        terms.g.append(x - (ca.mtimes(a_dm, x_prev) + ca.mtimes(b_dm, u)))
        centre = par.centre0 + par.vel * tk
        slots = par.obstacles[k * OB.STAGE_SIZE:(k + 1) * OB.STAGE_SIZE]
        terms.g.append(C.soft_constraints(x, slack, centre, par.soft, slots))
        # the same rows in the stage-wise form of the QP (x_{k+1} through the dynamics; equal wherever
        # the dynamics hold, which every SQP iterate after the first satisfies exactly)
        x_pred = ca.mtimes(a_dm, x_prev) + ca.mtimes(b_dm, u)
        terms.g_ocp += [x_pred - x, C.soft_constraints(x_pred, slack, centre, par.soft, slots)]

        yaw, pitch, roll = lay.angles(x)
        cam = x[lay.P]
        r = rotation_ypr(yaw, pitch, roll)
        f_mm = x[lay.F]
        im = self._image_term(terms, k, par, r=r, cam=cam, f_mm=f_mm, tk=tk)
        cc = ca.mtimes(r.T, centre - cam)
        d = par.dof[k * N_DOF:(k + 1) * N_DOF]
        inv_n0, inv_f0 = inverse_dof_limits(f_mm, x[lay.A], x[lay.S], s.plan_coc_mm)
        inv_f = far_limit_for_circle(inv_n0, inv_f0, d[6])
        inv_n = near_limit_for_circle(inv_n0, inv_f0, d[7])
        wts = par.wts
        jdof = dof_cost(inv_n, inv_f, par.dref[k], w_near=d[0] * wts["dof_near"], g_near=d[1],
                          w_far=d[2] * wts["dof_far"], g_far=d[3], far_one_sided=d[4], near_one_sided=d[5])
        un = u * par.u_scale
        du_n = (u - u_last) * par.u_scale
        # relative to the subject: follow, don't wander; a camera the style turns or zooms in place stands still
        still = par.motion[k * CM.N_MOTION + CM.STILL]
        vn = (x[lay.V] - (1 - still) * par.vel) * par.v_scale
        acc_idx, cam_idx, lens_idx = self._input_groups()
        # the look gives way where the source's subject is out of its frame (camera_motion.LOOK_OFF)
        w_look = wts["look"] * (1 - par.motion[k * CM.N_MOTION + CM.LOOK_OFF])
        stage = (wts["image"] * im + w_look * look_cost(cc) + jdof
                 + wts["accel"] * ca.sumsqr(un[acc_idx]) + wts["camera_rate"] * ca.sumsqr(un[cam_idx])
                 + wts["lens_rate"] * ca.sumsqr(un[lens_idx])
                 + wts["accel_change"] * ca.sumsqr(du_n[acc_idx])
                 + wts["camera_rate_change"] * ca.sumsqr(du_n[cam_idx])
                 + wts["lens_rate_change"] * ca.sumsqr(du_n[lens_idx])
                 + wts["velocity"] * ca.sumsqr(vn)
                 + wts["soft_constraint"] * (ca.sum1(slack) + ca.sumsqr(slack))
                 + wts["level"] * roll * roll)
        stage += self._motion_terms(terms, k, par, x_prev=x_prev, x=x, u=u, r=r, cam=cam, centre=centre)
        terms.cost += dt * stage
        if s.solver != "ipopt":
            e_n, e_f = dof_residuals(inv_n, inv_f, par.dref[k], g_near=d[1], g_far=d[3], far_one_sided=d[4],
                                      near_one_sided=d[5])
            terms.resid += [ca.sqrt(0.5 * dt * w_look) * look_residual(cc),
                            ca.sqrt(dt * d[0] * wts["dof_near"]) * e_n, ca.sqrt(dt * d[2] * wts["dof_far"]) * e_f]
            if lay.control_roll:
                terms.resid.append(ca.sqrt(dt * wts["level"]) * roll)
            self._add_input_residuals(terms, wts, un=un, du_n=du_n, vn=vn, slack=slack,
                                      majorised=(u * par.u_scale, u_last * par.u_scale) if majorise and k > 0
                                      else None)

    def _motion_residuals(self, k: int, par: NlpParams, *, x_prev, x, u, r, cam, centre) -> list:  # noqa: ANN001
        """(weight, residual) pairs of stage k+1's side-of-subject and camera-motion terms, each
        weight already multiplied by its mask (0 where the style asks nothing of the stage). Each
        residual reads either the stage's input with the state it starts from, or the state it ends
        in: the stage-wise QP (HPIPM) couples nothing else."""
        lay, wts = self.layout, par.wts
        m = par.motion[k * CM.N_MOTION:(k + 1) * CM.N_MOTION]
        rel = cam - centre
        out = [(wts["side_of_subject"] * m[CM.SIDE_MASK], bearing_shortfall(rel, m[0:2], SIDE_FREE_RAD))]
        rate_idx = [lay.YAW_RATE, lay.PITCH_RATE] + ([lay.ROLL_RATE] if lay.control_roll else [])
        # where a truck or orbit has lost its subject the rates alone hold the heading (camera_motion.RATES_HELD)
        w_rate = wts["motion_rate"] + wts["held_rate"] * m[CM.RATES_HELD]
        for i, ui in enumerate(rate_idx):
            out.append((w_rate * m[CM.RATE_MASKS.start + i], u[ui] - m[CM.RATES.start + i]))
        f_mm = x_prev[lay.F]
        out.append((wts["zoom_rate"] * m[CM.ZOOM_MASK], log_rate(u[lay.F_RATE], f_mm) - m[CM.ZOOM]))
        rel_vel = x[lay.V] - par.vel
        out.append((wts["dolly_zoom"] * m[CM.DOLLY_ZOOM_MASK], distance_log_rate(rel, rel_vel) - m[CM.DISTANCE_RATE]))
        out.append((wts["bearing_rate"] * m[CM.BEARING_RATE_MASK], bearing_rate(rel, rel_vel) - m[CM.BEARING_RATE]))
        direction = ca.mtimes(r, m[CM.TRAVEL])  # the source camera's direction of travel, in the world
        least = m[CM.TRAVEL_MIN] * ca.norm_2(rel)  # a dolly travels at least at a rate the eye counts
        travel = travel_residual(x[lay.V], direction, par.v_scale, least)
        out.append((wts["translation_dir"] * m[CM.TRAVEL_MASK], travel))
        # a measured speed (a pedestal's) is the move itself, not a floor: its shortfall weighs more
        out.append((wts["travel_rate"] * m[CM.TRAVEL_MEASURED], travel[travel.shape[0] - 1]))
        # a camera that only turns or zooms does not slide sideways: held by J_v alone (0.5), the framing
        # trucked and orbited it after the walker and the pan was read as orbit or truck; held in every
        # direction, it lost the framing (docs/planner.md, "Stand still"); a dolly stands still off its level rails
        rail = level_rail(r[:, 0], m[CM.TRAVEL_MASK])
        out.append((wts["motion_still"] * m[CM.STILL], sideways_velocity(x[lay.V], rail, par.v_scale)))
        # a camera that only zooms holds its distance too: moved along the axis it reads as a dolly-zoom
        out.append((wts["zoom_still"] * m[CM.STILL_ALONG], along_velocity(x[lay.V], r[:, 0], par.v_scale)))
        # room on the lens for the zoom still to come: at the end of its range it cannot follow the style
        out.append((wts["zoom_headroom"] * m[CM.HEADROOM_MASK],
                     headroom_shortfall(x[lay.F], m[CM.LOG_FOCAL_FLOOR], m[CM.LOG_FOCAL_CEILING])))
        return out

    def _motion_terms(self, terms: NlpTerms, k: int, par: NlpParams, **at):  # noqa: ANN003, ANN202
        """Stage k+1's side-of-subject and camera-motion cost (per s); their residuals for the SQP."""
        cost = 0
        for w, res in self._motion_residuals(k, par, **at):
            cost += w * ca.sumsqr(res)
            if self.s.solver != "ipopt":
                terms.resid.append(ca.sqrt(self.dt * w) * res)
        return cost

    def _image_term(self, terms: NlpTerms, k: int, par: NlpParams, *, r, cam, f_mm, tk):
        """The image cost of stage k+1: the predicted joints projected through the planned camera,
        against their targets (weighted by the mask); for the SQP, their residuals too."""
        s, e, dt = self.s, self.e, self.dt
        im = 0
        for j in range(e):
            pj = par.joints0[:, j] + par.vel * tk
            pc = ca.mtimes(r.T, pj - cam)
            ti = (k * e + j) * 2
            err2 = joint_image_error(pc, par.targets[ti], par.targets[ti + 1], f_mm, s.sensor_width_mm,
                                       s.sensor_height_mm, theta0_rad=math.radians(s.pinhole_half_angle_deg))
            im += par.mask[k * e + j] * err2
            if s.solver != "ipopt":
                ru, rv = joint_image_residual(pc, par.targets[ti], par.targets[ti + 1], f_mm, s.sensor_width_mm,
                                                s.sensor_height_mm,
                                                theta0_rad=math.radians(s.pinhole_half_angle_deg))
                sw = ca.sqrt(dt * par.wts["image"] * par.mask[k * e + j])
                terms.resid += [sw * ru, sw * rv]
        return im

    def _add_input_residuals(self, terms: NlpTerms, wts: dict, *, un, du_n, vn, slack,
                             majorised: tuple | None) -> None:
        """Residuals of the input, velocity and slack costs; the input-change ones exact, and
        majorised (`majorised` = (u, u_last) scaled: each side on its own) for HPIPM's warm iterations."""
        dt = self.dt
        acc_idx, cam_idx, lens_idx = self._input_groups()
        terms_ = [("accel", un[acc_idx]), ("camera_rate", un[cam_idx]), ("lens_rate", un[lens_idx]),
                  ("velocity", vn), ("soft_constraint", slack)]
        exact = [("accel_change", du_n[acc_idx]), ("camera_rate_change", du_n[cam_idx]),
                 ("lens_rate_change", du_n[lens_idx])]
        major = exact
        if majorised is not None:
            major = [(name, vec[idx]) for name, idx in (("accel_change", acc_idx),
                                                        ("camera_rate_change", cam_idx),
                                                        ("lens_rate_change", lens_idx))
                     for vec in majorised]
        terms.resid += [ca.sqrt(dt * wts[name]) * vec for name, vec in terms_]
        terms.du_exact += [ca.sqrt(dt * wts[name]) * vec for name, vec in exact]
        terms.du_major += [ca.sqrt(dt * wts[name]) * vec for name, vec in major]
