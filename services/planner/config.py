"""Parameters of the planner (CineMPC in casadi), as frozen dataclasses validated at start-up.

Three groups, kept apart as STYLE §5 asks:

- `Structure`: what the solver is built from (horizon, step, joints, roll, solver options). A
  change rebuilds (or loads from cache) the NLP.
- `Bounds` and `Weights`: runtime parameters. They enter the NLP as bounds / parameter values, so
  they can change between two solves without a rebuild (`Planner.set_bounds`, `set_weights`).
- the rest of `PlannerConfig`: timing and the failure policy of the core and the service.

Defaults of `Bounds` are the default vehicle profile's (deploy/vehicles/cinempc.yaml: CineMPC's
camera, DESIGN §4); `with_vehicle` takes bounds and sensor from any profile (shared/vehicle.py).
Cost weights are per second of horizon (each stage cost is multiplied by the step dt), so the
same weights work for any horizon length and step.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

from cinetransfer.shared.camera import COC_MM, SENSOR_HEIGHT_MM, SENSOR_WIDTH_MM
from cinetransfer.shared.errors import ConfigError
from cinetransfer.shared.nodeconfig import renamed_aliases, setting
from cinetransfer.shared.paths import cache_dir
from cinetransfer.shared.limits import (EnvelopeLimits, GimbalLimits, GimbalRateLimits, LensLimits, LensRateLimits,
                                        MotionLimits, vehicle_fields)
from cinetransfer.shared.obstacles import obstacles_setting
from cinetransfer.shared.surfaces import surfaces_setting
from cinetransfer.shared.vehicle import VehicleProfile


def _bad(section: str, name: str, value: Any, allowed: str) -> ConfigError:
    return ConfigError(f"planner config: {section}{name}={value!r} is invalid; allowed: {allowed}")


@dataclass(frozen=True)
class Bounds(LensRateLimits, LensLimits, GimbalRateLimits, GimbalLimits, EnvelopeLimits, MotionLimits):
    """Limits of the vehicle, gimbal and lens (runtime parameters: no rebuild when changed).

    Every field is a limit of the vehicle profile, declared once in shared/limits.py under the
    profile's name; the defaults are the default profile's.

    Velocity and acceleration are bounded per world axis (hard; the vertical speed at the climb
    rate); the speed also in norm (soft), the norm being what the safety layer bounds. The speed
    norm, the altitude band and the minimum distance to the subject are soft constraints with an
    exact (L1) penalty: they hold whenever they can, and a vehicle that starts outside them is
    brought back instead of making the problem infeasible. Every other limit is hard.
    """

    #: the settings keys of earlier versions, still accepted in settings files -> the field
    SETTING_ALIASES: ClassVar[dict[str, str]] = {
        "min_distance_m": "min_subject_distance_m", "yaw_rate_max_radps": "yaw_rate_radps",
        "pitch_rate_max_radps": "pitch_rate_radps", "roll_rate_max_radps": "roll_rate_radps",
        "focal_min_mm": "focal_length_min_mm", "focal_max_mm": "focal_length_max_mm",
        "focal_rate_max_mmps": "focal_rate_mmps", "focus_min_m": "focus_distance_min_m",
        "focus_max_m": "focus_distance_max_m", "focus_rate_max_mps": "focus_rate_mps",
        "fnumber_min": "f_number_min", "fnumber_max": "f_number_max", "fnumber_rate_max_ps": "f_number_rate_ps"}

    @classmethod
    def from_vehicle(cls, v: VehicleProfile) -> "Bounds":
        """The vehicle's limits (shared/vehicle.py): the same numbers the safety layer and the simulator use."""
        return cls(**vehicle_fields(cls, v)).validate()

    def validate(self) -> "Bounds":
        s = "bounds."
        for name in ("speed_max_mps", "accel_max_mps2", "climb_max_mps", "yaw_rate_radps", "pitch_rate_radps",
                     "roll_rate_radps", "focal_rate_mmps", "focus_rate_mps", "f_number_rate_ps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise _bad(s, name, v, "a finite value > 0")
        if not (math.isfinite(self.altitude_min_m) and math.isfinite(self.altitude_max_m)
                and self.altitude_max_m > self.altitude_min_m):
            raise _bad(s, "altitude_max_m", self.altitude_max_m, "finite and > altitude_min_m")
        for name in ("min_subject_distance_m", "min_obstacle_distance_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise _bad(s, name, getattr(self, name), ">= 0")
        if not (-math.pi / 2 <= self.pitch_min_rad < self.pitch_max_rad <= math.pi / 2):
            raise _bad(s, "pitch_min_rad/pitch_max_rad", (self.pitch_min_rad, self.pitch_max_rad),
                       "-pi/2 <= min < max <= pi/2")
        if not (0 <= self.roll_max_rad < math.pi / 2):
            raise _bad(s, "roll_max_rad", self.roll_max_rad, "0 <= value < pi/2")
        f_lo, f_hi, s_lo, s_hi = (self.focal_length_min_mm, self.focal_length_max_mm, self.focus_distance_min_m,
                                  self.focus_distance_max_m)
        if not (0 < f_lo < f_hi and math.isfinite(f_hi)):
            raise _bad(s, "focal_length_min_mm/focal_length_max_mm", (f_lo, f_hi), "0 < min < max")
        if not (f_lo / 1000.0 < s_lo < s_hi and math.isfinite(s_hi)):
            raise _bad(s, "focus_distance_min_m/focus_distance_max_m", (s_lo, s_hi),
                       "focal length < min < max (metres)")
        if not (1.0 <= self.f_number_min < self.f_number_max and math.isfinite(self.f_number_max)):
            raise _bad(s, "f_number_min/f_number_max", (self.f_number_min, self.f_number_max), "1 <= min < max")
        return self


@dataclass(frozen=True)
class Weights:
    """Cost weights (runtime parameters). Every stage term is multiplied by dt: units are per s.

    Image errors are in normalised image units (fraction of the width / height); depth-of-field
    errors are dimensionless (d * (1/D - 1/D*), roughly the relative error of the limit, d the
    camera-subject distance); input terms use each input divided by its bound.
    """

    image: float = 200.0  # per joint, per (normalised unit)^2 per s; 0.02 error ~ 0.08/s
    look: float = 1.0  # keeps the subject centre ahead of the camera: (1 - cos angle) per s
    dof_near: float = 5.0  # (d (1/D_n - 1/D_n*))^2 per s
    dof_far: float = 5.0  # (d (1/D_f - 1/D_f*))^2 per s; one-sided when D_f* is infinite
    accel: float = 0.05  # (a / a_max)^2 per s (per axis)
    camera_rate: float = 0.05  # (omega / omega_max)^2 per s (per angle)
    lens_rate: float = 0.05  # (rate / rate_max)^2 per s for focal length, focus, f-number
    accel_change: float = 0.5  # ((a_k - a_{k-1}) / a_max)^2 per s: jerk smoothness
    camera_rate_change: float = 0.5  # ((omega_k - omega_{k-1}) / omega_max)^2 per s
    lens_rate_change: float = 0.2  # ((r_k - r_{k-1}) / r_max)^2 per s
    velocity: float = 0.5  # ((v - v_subject) / v_max)^2 per s: keeps the camera from sliding along
    #                        the dolly/zoom family of equally good framings (and the tracking lag that brings)
    level: float = 10.0  # roll^2 per s [1/rad^2], with control_roll: the horizon stays level unless a
    #                      tilted pose is worth it (17 deg of roll costs as much as ~0.035 error per joint)
    soft_constraint: float = 1000.0  # per (metre of violation) per s, plus the same per m^2: floor, ceiling, distance
    # camera-motion style and side of the subject (docs/planner.md, "Camera motion" and "Side of the subject");
    # each is 0 in a stage the style asks nothing of, so a static style flies as without them
    side_of_subject: float = 10.0  # (1 - cos(bearing of the camera round the subject - wanted bearing)) per s
    motion_rate: float = 20.0  # (camera angular rate - source's [rad/s])^2 per s, per pan / tilt / roll
    held_rate: float = 200.0  # added to motion_rate on a truck's or orbit's row whose source lost its subject: there
    #                          nothing framed holds the heading, and at 20 the camera turned to meet its velocity
    zoom_rate: float = 100.0  # (d ln f/dt - source's [1/s])^2 per s
    translation_dir: float = 5.0  # (velocity off the source's direction of travel / v_max)^2 per s
    travel_rate: float = 100.0  # (shortfall under the source's measured speed along its direction / v_max)^2 per
    #                             s, a pedestal's (with translation_dir's own: 105); at 5 alone the climb ran slow
    dolly_zoom: float = 100.0  # (d ln(subject distance)/dt - source's zoom rate [1/s])^2 per s, in a dolly zoom
    bearing_rate: float = 100.0  # (d(camera's bearing round the subject)/dt - source's [rad/s])^2 per s, truck/orbit
    motion_still: float = 20.0  # (v off the optical axis / v_max)^2 per s in a row that turns or zooms the camera in
    #                              place (pan, tilt, roll, zoom): sideways it stands still, along the axis the framing
    #                              keeps the size (docs/planner.md, "Stand still sideways"); static rows take it too
    zoom_still: float = 20.0  # (v along the optical axis / v_max)^2 per s in a row that zooms in place: moving
    #                            there reads as a dolly-zoom; times the share the framing error allows (zoom_hold.py),
    #                            held in full it cost the framing from a start off the source's pose (docs/planner.md)
    zoom_headroom: float = 100.0  # (ln f beyond the focal length that leaves room for the zoom to come)^2 per s

    def validate(self) -> "Weights":
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not (math.isfinite(v) and v >= 0):
                raise _bad("weights.", f.name, v, "a finite value >= 0")
        return self

    def as_vector(self) -> list[float]:
        return [float(getattr(self, f.name)) for f in dataclasses.fields(self)]


WEIGHT_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(Weights))

SOLVERS = ("ipopt", "sqp_rti")
QP_SOLVERS = ("qrqp", "osqp", "qpoases", "piqp", "hpipm", "daqp", "proxqp")


def default_cache_dir() -> str:
    """Where generated solver code is compiled and kept (shared/paths.cache_dir()/planner)."""
    return str(cache_dir("planner"))


@dataclass(frozen=True)
class Structure:
    """Structural options: changing any of these builds another NLP."""

    horizon_steps: int = setting(15, flag="--horizon", range="[1, 100]", metavar="N", help="N, stages of the horizon")
    dt_s: float = setting(0.1, flag="--dt", unit="s", range="(0, 1]", metavar="S",
                          help="step of the horizon; N * dt = horizon length")
    max_joints: int = 8  # E_max: controlled joints the NLP holds (extra ones are ignored and counted)
    control_roll: bool = False  # camera roll as a state with a rate input (else fixed at 0)
    sensor_width_mm: float = SENSOR_WIDTH_MM  # for the projection (CineMPC's 16:9 "Digital Film")
    sensor_height_mm: float = SENSOR_HEIGHT_MM
    coc_mm: float = COC_MM  # circle of confusion for the depth of field [mm]
    solver: str = "sqp_rti"  # "sqp_rti": SQP real-time iteration (Gauss-Newton QPs); "ipopt": the reference NLP solver
    qp_solver: str = "hpipm"  # QP solver of sqp_rti (a casadi conic plugin, QP_SOLVERS)
    sqp_iter: int = 1  # SQP iterations per warm-started solve (1 = real-time iteration), >= 1
    sqp_iter_cold: int = 30  # SQP iterations of a cold solve (stops earlier when converged), >= 1
    sqp_step_tol: float = 1e-6  # an SQP step smaller than this (relative, inf-norm) is converged
    sqp_input_copies: bool = False  # HPIPM: True = exact Gauss-Newton Hessian (inputs copied into the QP states)
    #                                (stages of 19 + 11 variables); False: warm iterations drop the input-change
    #                                cost's cross-stage Hessian terms (11 + 11: ~35 % faster, same optimum, but
    #                                a larger steady framing error in the benchmark)
    expand: bool = True  # expand the MX graph to SX (CineMPC-like baseline: False)
    codegen: bool = setting(False, flag="--codegen",
                            help="generate and compile the NLP in C once (cached under the cache dir)")
    cache_dir: str = setting(default_factory=default_cache_dir, flag="--cache-dir", metavar="DIR",
                             help="where generated solvers are cached")
    compiler: str = "gcc"  # C compiler for codegen
    compile_flags: tuple[str, ...] = ("-O1", "-fPIC", "-shared")
    max_iter: int = 60  # IPOPT iterations per warm-started solve, >= 1
    max_iter_cold: int = 200  # IPOPT iterations of a cold solve, >= 1
    tol: float = 1e-5  # IPOPT tolerance
    warm_start: bool = True  # initial guess from the shifted last solution (baseline: False = cold)
    far_margin_inv_m: float = 0.01  # 'far limit at infinity' aims at 1/D_f <= -this [1/m] (s a bit past H)
    near_foreground_m: float = 1.0  # 'foreground in focus' aims at D_n = this [m] (D_n* = 0 is unreachable)
    # margins either side of coc_mm, the one definition of in focus (where the focus estimator flips;
    # docs/planner.md "One definition of in focus"): a region kept in focus is planned inside the depth
    # of field of coc_mm x sharp_coc_ratio (0.05 mm on CineMPC's sensor), a subject kept out beyond
    # that of coc_mm x defocus_coc_ratio (0.2 mm): blur that is seen ("Visible defocus")
    sharp_coc_ratio: float = 0.375
    defocus_coc_ratio: float = 1.5
    defocus_when_none: bool = True  # no region in focus -> D_f* = d - mu (DESIGN's table: uncontrolled)
    pinhole_half_angle_deg: float = 60.0  # J_im is the exact pinhole error within this angle of the axis,
    #                                       extended monotonically beyond (cost.project_extended), (30, 80)

    @property
    def plan_coc_mm(self) -> float:
        """The circle of confusion the planner's depth-of-field limits are computed for [mm]."""
        return self.coc_mm * self.sharp_coc_ratio

    @property
    def nx(self) -> int:
        return 12 if self.control_roll else 11

    @property
    def nu(self) -> int:
        return 9 if self.control_roll else 8

    def validate(self) -> "Structure":
        for name, ok, allowed in self._checks():
            if not ok:
                raise _bad("structure.", name, getattr(self, name), allowed)
        return self

    def _checks(self) -> list[tuple[str, bool, str]]:
        """(field, whether its value is allowed, what is allowed), in the order they are reported."""
        def count(v: Any, lo: int, hi: float = math.inf) -> bool:
            return isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi

        def positive(v: Any) -> bool:
            return isinstance(v, (int, float)) and math.isfinite(v) and v > 0

        return [
            ("horizon_steps", count(self.horizon_steps, 1, 100), "an integer in 1..100"),
            ("dt_s", 0 < self.dt_s <= 1.0, "0 < dt <= 1 s"),
            ("max_joints", count(self.max_joints, 1, 33), "an integer in 1..33"),
            *((n, positive(getattr(self, n)), "a finite value > 0")
              for n in ("sensor_width_mm", "sensor_height_mm", "coc_mm")),
            ("solver", self.solver in SOLVERS, " | ".join(SOLVERS)),
            ("qp_solver", self.qp_solver in QP_SOLVERS, " | ".join(QP_SOLVERS)),
            ("expand", self.expand or self.solver != "sqp_rti", "True with solver sqp_rti"),
            *((n, count(getattr(self, n), 1), "an integer >= 1") for n in ("sqp_iter", "sqp_iter_cold")),
            ("sqp_step_tol", 0 < self.sqp_step_tol < 1, "0 < value < 1"),
            ("codegen", self.expand or not self.codegen, "False when expand is False"),
            *((n, count(getattr(self, n), 1), "an integer >= 1") for n in ("max_iter", "max_iter_cold")),
            ("tol", 0 < self.tol < 1, "0 < tol < 1"),
            ("far_margin_inv_m", self.far_margin_inv_m >= 0, ">= 0"),
            ("near_foreground_m", self.near_foreground_m > 0, "> 0"),
            ("sharp_coc_ratio", 0 < self.sharp_coc_ratio <= 1, "0 < value <= 1"),
            ("defocus_coc_ratio", 1 <= self.defocus_coc_ratio <= 20, "1 <= value <= 20"),
            ("pinhole_half_angle_deg", 30.0 < self.pinhole_half_angle_deg < 80.0, "30 < value < 80"),
        ]


@dataclass(frozen=True)
class PlannerConfig:
    """Everything the planner core and service need."""

    structure: Structure = field(default_factory=Structure)
    bounds: Bounds = field(default_factory=Bounds)
    weights: Weights = field(default_factory=Weights)
    rate_hz: float = setting(20.0, flag="--rate", unit="Hz", range="(0, 200]", metavar="HZ",
                             help="setpoints published per second (one solve each)")
    max_solve_time_s: float = setting(0.04, flag="--max-solve-time", unit="s", range="> 0", metavar="S",
                                      help="IPOPT wall-time budget per warm-started solve (<= 1 / rate_hz)")
    max_cold_solve_time_s: float = 0.25  # budget of a cold solve (first one, after a hold) [s], >= the above
    accept_suboptimal: bool = True  # a solve stopped by max_iter / time with a feasible iterate is used
    feasibility_tol: float = 1e-4  # constraint violation under which such an iterate counts as feasible
    tail_max_s: float = 1.0  # after a failure, fly the last good plan at most this long [s], then hold
    setpoint_lead_s: float = 0.1  # the setpoint is the plan at now + lead [s] (covers tracking lag), >= 0
    max_input_age_s: float = 0.5  # vehicle/subject state older than this is stale -> hold [s], > 0
    clamp_tolerance: float = 0.05  # measured state outside a hard bound by <= this fraction of the range is clamped
    autostart: bool = setting(False, flag="--autostart",
                              help="start recording when the first instructions arrive (else wait for a 'start' "
                                   "command)")
    mu_default_m: float = 1.0  # DoF margin when the instructions carry none (mu <= 0) [m]
    #: how far beyond the subject's centre the near limit keeps him out when only the background is to be
    #: sharp [m]; 0 = mu. His own depth (0.3 m: a body's back) filmed parkour's lawn right behind him sharp
    #: (truth background 0.65 -> 0.90); the first keep_out_settle_s after a rack's switch keep mu
    subject_keep_out_m: float = 0.3
    #: how long after a switch to "only the background sharp" (a rack focus) the rows keep the subject out by
    #: mu rather than subject_keep_out_m [s]: with the nearer limit the focus left him later (core.keep_out_rows)
    keep_out_settle_s: float = 1.5
    #: how far ahead (within the take) a style row wanting the subject soft before a sharp background
    #: raises the minimum subject distance to the standoff that choice needs (separation.py) [s]; 0 = off
    separation_lookahead_s: float = 6.0
    #: the style's zoom and distance terms (zoom rate, dolly-zoom, standing still along the axis) give way
    #: round a rack focus (the subject's label switching): from zoom_yield_lead_s before the switch [s] to
    #: keep_out_settle_s after it, while the lens travels (core.lens_for_focus_rows; docs/planner.md,
    #: "Which gives way")
    zoom_yields_to_focus: bool = True
    zoom_yield_lead_s: float = 1.5
    #: the weight of the soft subject's near limit, as a factor of dof_near, on the rows of keep_out_settle_s after
    #: a rack away from him inside a shot (core.rack_settle_rows): there the focus travels at its rate while the
    #: framing pulls the focal length shorter, which widens the field and gives his blur back. 1 = off (as any
    #: other row), the default: 2 met parkour's runner by both measures but the report's rates bound then
    #: excused fewer background frames (docs/planner.md, "The rack's focal length held while its focus travels")
    rack_settle_near_weight: float = 1.0
    #: the subject's blur [circles of the one circle] asked where a shot has settled on only the background sharp
    #: (after keep_out_settle_s): the visible circle's 1.5 (defocus_coc_ratio). Less starts the sharp zone nearer
    #: behind him, but the estimator then read the far runner sharp (docs/planner.md, "Which gives way")
    settled_subject_blur: float = 1.5
    #: ask less of that blur (down to focus_field.LEAST_SOFT_SUBJECT_BLUR) where the ground behind him, as the
    #: camera's height and pitch show it, needs the sharp zone nearer (core.Planner._settled_blur): parkour's lawn
    #: 6-8 m behind the runner, half of the truth's background
    settled_blur_from_ground: bool = True
    #: with only the subject sharp before a present background, the focus stands a quarter of the one circle in
    #: front of him where the ground below his feet lies inside the field anyway (focus_field.focus_ahead_inv_m):
    #: centred on him, parkour's backdrop stayed under the 1.5 circles the estimator reads as soft. Not in a shot
    #: that racks away from him, which rack_ahead_max_circles moves instead (core.Planner._centred_before_rack;
    #: docs/planner.md, "Only the subject sharp: the focus in front of him")
    subject_only_focus_ahead: bool = True
    #: a rack away from the subject (his label sharp -> soft inside a shot) is planned ahead, each stage as the
    #: switch's row once half the focus's travel from him to one circle behind takes longer than the time left,
    #: at most rack_lead_max_s [s] ahead, where he then stays soft at least rack_lead_min_hold_s [s]
    #: (core.rack_switch_ahead, Planner._subject_travel_s): started at the switch, that travel left the parkour
    #: runner sharp for 22 frames after it (docs/planner.md, "A rack away from the subject, planned ahead").
    #: 0 = off. Ungated, the dancer's distant background, asked soft before her switch, went sharp early (1.00 ->
    #: 0.80); gated by the background (rack_lead_background_gate) the parkour runner's truth went 0.88 -> 0.95 and
    #: the dancer's background stayed 1.00
    rack_lead_max_s: float = 1.5
    rack_lead_min_hold_s: float = 1.0
    #: before a rack away from the subject (only him sharp, the shot switching him soft later) the focus stands in
    #: front of him until the ground behind him is focus_field.SOFT_BAND_BLUR circles soft, but at most this many
    #: circles of the one circle in front (focus_field.rack_ahead_inv_m, core.Planner._rack_ahead_inv_m; 0 = centred
    #: on him, as before): centred, parkour's lawn 6-10 m behind the runner lay inside the field (truth background
    #: 0.57); 0.4 at the aperture planned for (1.2 x the widest) is about 0.5 circles wide open: he reads sharp
    rack_ahead_max_circles: float = 0.4
    #: the lead no longer than the focus may travel before the background enters the field of the one circle
    #: (core.Planner._rack_lead_s, focus_field.rack_lead_cap_s): the background soft up to the switch, as asked
    rack_lead_background_gate: bool = True
    #: the lead stages at most this long before a rack from the subject onto the background [s] keep him sharp
    #: (core.held_lead_dof: the focus travels on as the stages past the switch ask, the f-number rises) instead
    #: of planning him soft already; 0 = off
    rack_lead_hold_s: float = 0.25
    #: a row whose source has no label for the subject (core.unmeasured_subject_rows) asks nothing of his depth:
    #: the near limit is free unless the foreground is asked sharp, and a far limit at infinity aims at the ground
    #: behind him the camera sees. With his held label asked of the lens, tos_clip01's take 3 stopped down to f/9
    #: (docs/planner.md, "An unmeasured subject asks no limit")
    unmeasured_subject_near_free: bool = True
    #: a later shot flown inside a take (shorter than --min-take) asks its focus choice of the lens only from the
    #: last labelled row of the shot followed now (core.later_shot_previewed): previewed over the horizon, tos_clip01's
    #: one- and two-row shots 192-203 stopped the rows before them down where their shot asks the background soft
    #: (docs/planner.md, "A later shot in the take waits for the cut")
    later_shot_after_choice: bool = True
    #: a shot shorter than this [s] (a flash cut, --min-take's default) holds no choice back from the shots after it
    later_shot_hold_min_s: float = 0.5
    #: with only the subject sharp before a present, soft background, his near limit stays two-sided even where
    #: the source shows no foreground (core.pins_field_before_soft_background): one-sided, the far limit alone
    #: left the aperture free and tos_clip01's take 3 stopped down f/4.4 -> f/8.2 with the background sharp
    #: (docs/planner.md, "A soft background pins the field")
    soft_background_pins_near: bool = True
    #: how far behind the subject the background stands [m]; inf = unknown, and then a row wanting the
    #: subject sharp before a soft background asks for no standoff. Given, such a row raises the minimum
    #: subject distance until the depth of field ends before it (separation.py). Off by default: the
    #: standoff slows a rack focus (the same reciprocal move is more metres of focus from further back)
    #: and focus_hedge's 3-D lawn reads soft without it (docs/planner.md)
    background_behind_m: float = setting(math.inf, flag="--background-behind", unit="m", range="> 0",
                                         metavar="M", help="how far behind the subject the background stands, "
                                         "for a standoff that keeps it soft behind a sharp subject (inf: unknown, "
                                         "no standoff)")
    #: per-joint factors on the image term, ((COCO-17 name, factor >= 0), ...); unnamed joints 1.
    #: How the planner trades joint targets it cannot all meet (another body): docs/planner.md.
    joint_weights: tuple[tuple[str, float], ...] = ()
    #: how a style row's left/right targets meet the subject: "image_side" (a row whose person faces
    #: the other way from the subject as seen now is met by image side, shared/facing.py: the
    #: planner frames the side it sees) or "name" (left by left, and the camera flies round to the
    #: side the style shows: a back-view shot from behind, a front-view one from the front; needs the
    #: subject's heading, SubjectState.heading_rad: without one, by image side). docs/planner.md,
    #: "Side of the subject".
    left_right: str = "name"
    #: keep-out obstacles, each [x_m, y_m, radius_m, z_min_m, z_max_m] in the world frame (shared/obstacles.py): the
    #: plan keeps the camera bounds.min_obstacle_distance_m from the surfaces of the nearest ones (obstacles.py). A
    #: runtime parameter; the transfer gives the scene's own (services/autopilot_bridge/sim/obstacles.py)
    obstacles_m: tuple[tuple[float, ...], ...] = ()
    #: the scene's known upright surfaces, each [x0_m, y0_m, x1_m, y1_m, z_min_m, z_max_m] in the world frame and
    #: optionally the focus estimator's flip on its texture [circles] (shared/surfaces.py): with the ground, how deep
    #: what the foreground band and the background show lies, and from what blur each reads soft
    #: (scene_depth.py), for "only the subject sharp" (focus_field.three_label_focus_inv_m). A runtime parameter;
    #: the transfer gives the scene's own fixed layers (services/autopilot_bridge/sim/surfaces.py)
    surfaces_m: tuple[tuple[float, ...], ...] = ()
    #: the ground's height in the scene's map [m] (with surfaces_m); NaN: not given, and the map's ground is taken
    #: below the subject's soles, which in a jump (parkour, frames 18-34) raised it over the backdrop's foot and
    #: made the background's median the lawn 31 m away instead of the backdrop 40 m away
    ground_z_m: float = math.nan

    def joint_weight(self, name: str) -> float:
        return dict(self.joint_weights).get(name, 1.0)

    def validate(self) -> "PlannerConfig":
        self.structure.validate()
        self.bounds.validate()
        self.weights.validate()
        if not (0 < self.rate_hz <= 200):
            raise _bad("", "rate_hz", self.rate_hz, "0 < rate <= 200 Hz")
        for name in ("max_solve_time_s", "max_cold_solve_time_s", "max_input_age_s", "mu_default_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise _bad("", name, v, "a finite value > 0")
        from cinetransfer.shared.messages import COCO17_NAMES

        for name, v in self.joint_weights:
            if name not in COCO17_NAMES or not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise _bad("", "joint_weights", (name, v), f"a COCO-17 name ({', '.join(COCO17_NAMES)}) "
                           "and a finite factor >= 0")
        if not (self.background_behind_m > 0):  # inf is allowed: an unknown background
            raise _bad("", "background_behind_m", self.background_behind_m, "a value > 0 (inf: unknown)")
        for name in ("tail_max_s", "setpoint_lead_s", "clamp_tolerance", "feasibility_tol", "separation_lookahead_s",
                     "subject_keep_out_m", "keep_out_settle_s", "zoom_yield_lead_s", "rack_lead_max_s",
                     "rack_lead_min_hold_s", "rack_ahead_max_circles", "rack_lead_hold_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise _bad("", name, v, "a finite value >= 0")
        if not (math.isfinite(self.rack_settle_near_weight) and self.rack_settle_near_weight >= 1.0):
            raise _bad("", "rack_settle_near_weight", self.rack_settle_near_weight, "a finite factor >= 1")
        if not (math.isfinite(self.settled_subject_blur) and self.settled_subject_blur > 1.0):
            raise _bad("", "settled_subject_blur", self.settled_subject_blur, "a finite value > 1 (soft)")
        if self.left_right not in LEFT_RIGHT:
            raise _bad("", "left_right", self.left_right, " | ".join(LEFT_RIGHT))
        object.__setattr__(self, "obstacles_m", obstacles_setting(self.obstacles_m, "planner config: obstacles_m"))
        object.__setattr__(self, "surfaces_m", surfaces_setting(self.surfaces_m, "planner config: surfaces_m"))
        return self


LEFT_RIGHT = ("image_side", "name")


def with_vehicle(cfg: PlannerConfig, v: VehicleProfile) -> PlannerConfig:
    """`cfg` with the bounds and the camera sensor of vehicle profile `v`."""
    structure = dataclasses.replace(cfg.structure, sensor_width_mm=v.camera.sensor_width_mm,
                                    sensor_height_mm=v.camera.sensor_height_mm, coc_mm=v.camera.coc_mm)
    return dataclasses.replace(cfg, bounds=Bounds.from_vehicle(v), structure=structure).validate()


def replace(cfg: PlannerConfig, **changes: Any) -> PlannerConfig:
    """A copy with changes; dotted names reach into the groups: replace(c, **{'structure.dt_s': 0.2})."""
    groups: dict[str, dict[str, Any]] = {}
    top: dict[str, Any] = {}
    for k, v in changes.items():
        if "." in k:
            g, name = k.split(".", 1)
            groups.setdefault(g, {})[name] = v
        else:
            top[k] = v
    for g, upd in groups.items():
        if g not in ("structure", "bounds", "weights"):
            raise ConfigError(f"planner config: no group {g!r} (structure, bounds, weights)")
        top[g] = dataclasses.replace(getattr(cfg, g), **upd)
    return dataclasses.replace(cfg, **top)


def joint_weights_from(d: dict[Any, Any]) -> tuple[tuple[str, float], ...]:
    """`joint_weights` as a file writes it ({name: factor}), sorted by name."""
    try:
        return tuple(sorted((str(k), float(v)) for k, v in d.items()))
    except (TypeError, ValueError):
        raise ConfigError(f"planner config: joint_weights={d!r} is invalid; allowed: COCO-17 name: number") from None


def from_dict(d: dict[str, Any], vehicle: VehicleProfile | None = None) -> PlannerConfig:
    """Config from a nested dict (e.g. a YAML 'planner' section); unknown keys are errors.

    With `vehicle`, the bounds and the sensor start from that profile and the dict overrides them."""
    d = dict(d or {})
    base = with_vehicle(PlannerConfig(), vehicle) if vehicle is not None else PlannerConfig()
    kw: dict[str, Any] = {}
    for g, cls in (("structure", Structure), ("bounds", Bounds), ("weights", Weights)):
        sub = d.pop(g, {}) or {}
        if not isinstance(sub, dict):
            raise ConfigError(f"planner config: {g} must be a mapping")
        sub = renamed_aliases(cls, dict(sub), "planner", f"{g}.")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(sub) - names
        if unknown:
            raise ConfigError(f"planner config: unknown {g} fields {sorted(unknown)}; allowed: {sorted(names)}")
        if "compile_flags" in sub:
            sub["compile_flags"] = tuple(sub["compile_flags"])
        kw[g] = dataclasses.replace(getattr(base, g), **sub)
    if isinstance(d.get("joint_weights"), dict):
        d["joint_weights"] = joint_weights_from(d["joint_weights"])
    names = {f.name for f in dataclasses.fields(PlannerConfig)}
    unknown = set(d) - names
    if unknown:
        raise ConfigError(f"planner config: unknown fields {sorted(unknown)}; allowed: {sorted(names)}")
    try:
        return PlannerConfig(**kw, **d).validate()
    except TypeError as e:  # a value of the wrong kind (the comparison names no field)
        raise ConfigError(f"planner config: {e}") from None
