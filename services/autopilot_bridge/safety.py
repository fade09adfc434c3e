"""The safety layer every backend shares: pure functions and one small stateful checker.

No Zenoh, no clock, no globals: time and the current vehicle/subject state are passed in.

What it enforces (limits in `SafetyConfig`):
- reject a setpoint with NaN/inf in position, velocity, acceleration or camera attitude, or
  with an unknown mode (lens NaN means "keep the current value", per the schema);
- clamp the position to the geofence (cylinder or box around home) and the altitude band;
- keep a minimum horizontal distance to the subject: push the position out radially;
  if the geofence then pulls it back inside that distance the setpoint is rejected;
- clamp the velocity feed-forward to the speed limit and the acceleration feed-forward to the
  acceleration limit, and directionally at the envelope: its outward component (through the
  geofence or the altitude band) is at most what the vehicle can still brake to zero before
  the boundary at the acceleration limit, so zero at or over it (a clamped position with an
  outward feed-forward used to park the vehicle 2 m outside the fence); a keep-out obstacle's
  clearance is such a boundary too, its outward direction the way to the obstacle's nearest point
  (shared/obstacles.towards); likewise no outward acceleration feed-forward within the braking
  distance of the fence or the band; `limit_motion` also
  moves the commanded position towards the requested one no faster than the speed limit and
  changes the commanded velocity no faster than the acceleration limit (so a jump in the plan
  becomes a bounded-speed transfer);
- clamp gimbal pitch/roll to their band and wrap yaw to (-pi, pi];
- clamp focal length, focus distance and f-number to the lens ranges;
- `envelope_breach` / `return_point`: the measured vehicle position against the same envelope,
  and where to fly back to when it is outside (the bridge does that every tick); the envelope
  includes the keep-out obstacles (`obstacles_m`, shared/obstacles.py): a vehicle nearer than
  `min_obstacle_distance_m` to one's surface is outside it;
- `check_command_args`: every argument of a bridge command (take-off altitude) validated and
  bounded by the same numbers; a bad one is a rejection, never an exception.

Every rejection and clamp increments a named counter in `SafetyLayer.counters`; the service
exports them in its Health message.
"""
from __future__ import annotations

import collections
import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np

from cinetransfer.services.autopilot_bridge.config import SafetyConfig
from cinetransfer.shared import messages as M
from cinetransfer.shared.angles import wrap_angle
from cinetransfer.shared.obstacles import Obstacle, intrusion_m, obstacles_from, push_clear, towards

MODES = ("track", "hold")

#: counter names, in the order Health shows them
COUNTER_NAMES = (
    "sp_checked", "sp_accepted", "sp_rejected_nonfinite", "sp_rejected_mode",
    "sp_rejected_subject_conflict", "clamp_geofence", "clamp_altitude", "clamp_subject_distance", "clamp_obstacle",
    "clamp_speed", "clamp_accel", "clamp_position_rate", "clamp_velocity_rate", "clamp_gimbal",
    "clamp_lens", "clamp_velocity_outward", "clamp_accel_outward",
)


# ----------------------------------------------------------------------------- pure helpers
def clamp_norm(v: np.ndarray, max_norm: float) -> tuple[np.ndarray, bool]:
    """`v` scaled down to norm <= max_norm; (vector, whether it was clamped)."""
    n = float(np.linalg.norm(v))
    if n <= max_norm or n == 0.0:
        return v, False
    return v * (max_norm / n), True


def clamp_climb(v: np.ndarray, max_climb: float) -> tuple[np.ndarray, bool]:
    """`v` with its vertical component clamped to +-max_climb; (vector, whether it was clamped)."""
    if abs(float(v[2])) <= max_climb:
        return v, False
    out = np.array(v, dtype=float)
    out[2] = math.copysign(max_climb, out[2])
    return out, True


def clamp_geofence(p: np.ndarray, cfg: SafetyConfig) -> tuple[np.ndarray, bool]:
    """Position with x/y clamped into the geofence around home (z untouched)."""
    home = np.asarray(cfg.home_m, dtype=float)
    d = p[:2] - home[:2]
    if cfg.geofence_shape == "cylinder":
        d2, hit = clamp_norm(d, cfg.geofence_radius_m)
    else:
        hx, hy = cfg.geofence_half_extent_m
        d2 = np.array([min(max(d[0], -hx), hx), min(max(d[1], -hy), hy)])
        hit = bool(np.any(d2 != d))
    if not hit:
        return p, False
    out = p.copy()
    out[:2] = home[:2] + d2
    return out, True


def inside_geofence(p: np.ndarray, cfg: SafetyConfig, tol: float = 1e-6) -> bool:
    """Whether `p` is inside the geofence and the altitude band."""
    home = np.asarray(cfg.home_m, dtype=float)
    d = p[:2] - home[:2]
    if cfg.geofence_shape == "cylinder":
        ok = float(np.linalg.norm(d)) <= cfg.geofence_radius_m + tol
    else:
        hx, hy = cfg.geofence_half_extent_m
        ok = abs(d[0]) <= hx + tol and abs(d[1]) <= hy + tol
    alt = p[2] - home[2]
    return ok and cfg.altitude_min_m - tol <= alt <= cfg.altitude_max_m + tol


def clamp_altitude(p: np.ndarray, cfg: SafetyConfig) -> tuple[np.ndarray, bool]:
    """Position with z clamped into the altitude band above home."""
    z0 = cfg.home_m[2]
    z = min(max(p[2], z0 + cfg.altitude_min_m), z0 + cfg.altitude_max_m)
    if z == p[2]:
        return p, False
    out = p.copy()
    out[2] = z
    return out, True


def push_from_subject(p: np.ndarray, subject_xy: np.ndarray, min_dist_m: float,
                      fallback_xy: np.ndarray | None = None) -> tuple[np.ndarray, bool]:
    """Move `p` radially (horizontally) away from the subject to at least `min_dist_m`.

    When `p` sits exactly on the subject the direction comes from `fallback_xy` (e.g. the
    vehicle's position), else +x.
    """
    if min_dist_m <= 0:
        return p, False
    d = p[:2] - subject_xy
    n = float(np.linalg.norm(d))
    if n >= min_dist_m:
        return p, False
    if n < 1e-9:
        d = (fallback_xy - subject_xy) if fallback_xy is not None else np.array([1.0, 0.0])
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            d, n = np.array([1.0, 0.0]), 1.0
    out = p.copy()
    out[:2] = subject_xy + d * (min_dist_m / n)
    return out, True


def _outward_limit(dist_m: float, max_accel: float) -> float:
    """Largest speed towards a boundary `dist_m` away that can still stop before it."""
    return math.sqrt(2.0 * max_accel * max(dist_m, 0.0))


def clamp_outward_velocity(p: np.ndarray, v: np.ndarray, cfg: SafetyConfig) -> tuple[np.ndarray, bool]:
    """Velocity `v` at position `p` with its outward component (through the geofence or the
    altitude band, or into a keep-out obstacle's clearance) cut to the braking speed for the
    distance left: none at or over a boundary. Inward and tangential components are untouched,
    so tracking along the fence or round an obstacle still works."""
    v = np.array(v, dtype=float)
    hit = False
    a = cfg.accel_max_mps2
    for n, gap in _keep_outs_near(p, cfg):  # first: the fence and the band win (as in the position's clamps)
        into = float(v @ n)
        lim = _outward_limit(gap, a)
        if into > lim:
            v -= (into - lim) * n
            hit = True
    home = np.asarray(cfg.home_m, dtype=float)
    d = np.asarray(p[:2], float) - home[:2]
    if cfg.geofence_shape == "cylinder":
        r = float(np.linalg.norm(d))
        if r > 1e-9:
            n = d / r
            out = float(v[:2] @ n)
            lim = _outward_limit(cfg.geofence_radius_m - r, a)
            if out > lim:
                v[:2] -= (out - lim) * n
                hit = True
    else:
        for i, half in enumerate(cfg.geofence_half_extent_m):
            sign = 1.0 if d[i] >= 0 else -1.0
            out = sign * v[i]
            lim = _outward_limit(half - abs(d[i]), a)
            if out > lim:
                v[i] = sign * lim
                hit = True
    alt = float(p[2]) - home[2]
    up_lim = _outward_limit(cfg.altitude_max_m - alt, a)
    down_lim = _outward_limit(alt - cfg.altitude_min_m, a)
    if v[2] > up_lim:
        v[2], hit = up_lim, True
    elif -v[2] > down_lim:
        v[2], hit = -down_lim, True
    return v, hit


def _braking_reach_m(cfg: SafetyConfig) -> float:
    """The braking distance at full speed [m]: speed_max² / 2·accel_max; a boundary farther than this
    bounds nothing (the vehicle can stop short of it from any speed the limits allow)."""
    return cfg.speed_max_mps ** 2 / (2.0 * cfg.accel_max_mps2)


def _keep_outs_near(p: np.ndarray, cfg: SafetyConfig) -> list[tuple[np.ndarray, float]]:
    """(unit vector into the keep-out, distance [m] to it: shared/obstacles.towards less the clearance) of
    every keep-out within the braking distance at full speed (speed_max² / 2·accel_max) of `p`: a farther
    one can be stopped short of from any speed the limits allow, so it bounds nothing."""
    reach = _braking_reach_m(cfg)
    c = cfg.min_obstacle_distance_m
    out = []
    for k in _obstacles(cfg):
        n, d = towards(k, p)
        if d - c < reach and d > 0.0:
            out.append((np.array(n), d - c))
    return out


def clamp_outward_accel(p: np.ndarray, a: np.ndarray, cfg: SafetyConfig) -> tuple[np.ndarray, bool]:
    """Acceleration feed-forward `a` at position `p` without an outward component wherever `p` is
    within the braking distance at full speed (speed_max² / 2·accel_max) of a boundary (the fence,
    the altitude band): there, pushing outward only stores up an overshoot. Not at a keep-out: the
    camera moves fly round them within that distance, where this rule would strip their feed-forward
    at any speed; the velocity clamp bounds the approach (clamp_outward_velocity)."""
    a = np.array(a, dtype=float)
    hit = False
    reach = _braking_reach_m(cfg)
    home = np.asarray(cfg.home_m, dtype=float)
    d = np.asarray(p[:2], float) - home[:2]
    if cfg.geofence_shape == "cylinder":
        r = float(np.linalg.norm(d))
        if r > 1e-9 and cfg.geofence_radius_m - r < reach:
            n = d / r
            out = float(a[:2] @ n)
            if out > 0:
                a[:2] -= out * n
                hit = True
    else:
        for i, half in enumerate(cfg.geofence_half_extent_m):
            sign = 1.0 if d[i] >= 0 else -1.0
            if half - abs(d[i]) < reach and sign * a[i] > 0:
                a[i], hit = 0.0, True
    alt = float(p[2]) - home[2]
    if (cfg.altitude_max_m - alt < reach and a[2] > 0) or (alt - cfg.altitude_min_m < reach and a[2] < 0):
        a[2], hit = 0.0, True
    return a, hit


def envelope_breach(p: np.ndarray, cfg: SafetyConfig, tol_m: float | None = None) -> bool:
    """Whether the measured position `p` is outside the geofence or above the altitude band by
    more than `tol_m` (default `cfg.breach_tolerance_m`). Non-finite positions count as a breach.

    Below the band is not a breach: a vehicle on the ground, taking off or landing is there
    legitimately (the floor bounds what may be *commanded*), and "fly back up" is no safe
    reaction near the ground."""
    p = np.asarray(p, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        return True
    tol = cfg.breach_tolerance_m if tol_m is None else tol_m
    q = p.copy()
    q[2] = max(q[2], cfg.home_m[2] + cfg.altitude_min_m + max(0.0, -tol))  # the floor is not checked
    return not inside_geofence(q, cfg, tol) or intrusion_m(_obstacles(cfg), p, cfg.min_obstacle_distance_m) > tol


def _obstacles(cfg: SafetyConfig) -> tuple[Obstacle, ...]:
    return _parsed_obstacles(cfg.obstacles_m)


@functools.lru_cache(maxsize=8)
def _parsed_obstacles(values: tuple[tuple[float, ...], ...]) -> tuple[Obstacle, ...]:
    """The keep-outs of a (checked, hashable) settings value, parsed once: every tick and every setpoint ask."""
    return obstacles_from(values)


def return_point(p: np.ndarray, cfg: SafetyConfig, margin_m: float | None = None) -> np.ndarray:
    """The point nearest to `p` that lies `margin_m` (default `cfg.breach_return_margin_m`)
    inside the envelope; where a band is narrower than twice the margin, its middle."""
    m = cfg.breach_return_margin_m if margin_m is None else margin_m
    home = np.asarray(cfg.home_m, dtype=float)
    out = np.array(p, dtype=float)
    d = out[:2] - home[:2]
    if cfg.geofence_shape == "cylinder":
        d2, _ = clamp_norm(d, max(cfg.geofence_radius_m - m, 0.0))
    else:
        d2 = np.array([min(max(d[i], -max(h - m, 0.0)), max(h - m, 0.0))
                       for i, h in enumerate(cfg.geofence_half_extent_m)])
    out[:2] = home[:2] + d2
    lo, hi = cfg.altitude_min_m + m, cfg.altitude_max_m - m
    if lo > hi:
        lo = hi = 0.5 * (cfg.altitude_min_m + cfg.altitude_max_m)
    out[2] = home[2] + min(max(out[2] - home[2], lo), hi)
    # then out of every keep-out, with the margin if it fits, else with the clearance alone; a return point
    # that no push clears inside the fence is left where the fence puts it (the fence wins)
    for clearance in (cfg.min_obstacle_distance_m + m, cfg.min_obstacle_distance_m):
        clear, ok = push_clear(_obstacles(cfg), out, clearance)
        if ok and inside_geofence(clear, cfg):
            return clear
    return out


def _number(args: dict, name: str) -> float | None:
    v = args.get(name)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return float(v)


#: arguments each bridge command accepts (anything else is a rejection)
COMMAND_ARGS: dict[str, tuple[str, ...]] = {"takeoff": ("altitude_m",)}


def check_command_args(action: str, args: dict, cfg: SafetyConfig) -> tuple[dict | None, str]:
    """(validated arguments, '') or (None, why) for one bridge command.

    `takeoff altitude_m` [m above home] must be a finite number inside the altitude band
    (`altitude_min_m`..`altitude_max_m`, the numbers every setpoint is clamped to).
    """
    allowed = COMMAND_ARGS.get(action, ())
    extra = sorted(str(k) for k in args if k not in allowed)
    if extra:
        return None, f"command {action!r} takes no argument {', '.join(extra)} (allowed: {allowed or 'none'})"
    out: dict = {}
    if action == "takeoff" and "altitude_m" in args:
        alt = _number(args, "altitude_m")
        if alt is None:
            return None, f"takeoff altitude_m = {args['altitude_m']!r:.40}: not a finite number"
        if not cfg.altitude_min_m <= alt <= cfg.altitude_max_m:
            return None, (f"takeoff altitude_m = {alt:g} outside the altitude band "
                          f"[{cfg.altitude_min_m:g}, {cfg.altitude_max_m:g}] m")
        out["altitude_m"] = alt
    return out, ""


def subject_centre_xy(subject: M.SubjectState | None) -> np.ndarray | None:
    """Horizontal centre of the subject's known joints, or None."""
    if subject is None or subject.joints_m.size == 0:
        return None
    j = np.asarray(subject.joints_m, dtype=float)
    ok = np.all(np.isfinite(j), axis=1)
    if not ok.any():
        return None
    return j[ok, :2].mean(axis=0)


def _finite_array(a: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(np.asarray(a, dtype=float))))


@dataclass(frozen=True)
class SafetyResult:
    """Outcome of checking one setpoint."""

    setpoint: M.Setpoint | None  #: the safe setpoint, or None if rejected
    reason: str = ""  #: why it was rejected ('' when accepted)
    clamps: tuple[str, ...] = ()  #: names of the clamps applied

    @property
    def accepted(self) -> bool:
        return self.setpoint is not None


@dataclass(frozen=True)
class MotionCommand:
    """Position/velocity the backend is told to track this tick (after rate limiting)."""

    position_m: np.ndarray
    velocity_mps: np.ndarray
    clamps: tuple[str, ...] = ()


def _note(clamps: list[str], hit: bool, counter: str) -> None:
    if hit:
        clamps.append(counter)


class SafetyLayer:
    """Checks setpoints against `SafetyConfig` and counts every rejection and clamp."""

    def __init__(self, cfg: SafetyConfig) -> None:
        self.cfg = cfg
        self.counters: collections.Counter[str] = collections.Counter({k: 0 for k in COUNTER_NAMES})

    def _reject(self, reason: str, counter: str) -> SafetyResult:
        self.counters[counter] += 1
        return SafetyResult(None, reason)

    # ------------------------------------------------------------------ per setpoint
    def check(self, sp: M.Setpoint, *, subject_xy: np.ndarray | None = None,
              vehicle_xy: np.ndarray | None = None, lens_now: M.LensState | None = None) -> SafetyResult:
        """Validate and clamp one setpoint (static limits: no time involved).

        `subject_xy`: horizontal centre of the subject (None = unknown: the distance rule is
        skipped); `vehicle_xy`: where the vehicle is (direction of the push when the setpoint
        sits on the subject); `lens_now`: lens values used where the setpoint's are NaN.
        """
        self.counters["sp_checked"] += 1
        bad = self._invalid(sp)
        if bad is not None:
            return self._reject(*bad)
        clamps: list[str] = []
        p = self._position(sp, subject_xy, vehicle_xy, clamps)
        if p is None:
            return self._reject("no point inside the geofence keeps the minimum subject distance and every "
                                "keep-out's clearance", "sp_rejected_subject_conflict")
        v, a = self._feed_forward(sp, p, clamps)
        ypr = self._gimbal(sp, clamps)
        # -- lens (NaN = keep the current value)
        lens, hit = self.clamp_lens(sp.lens, lens_now)
        _note(clamps, hit, "clamp_lens")
        for c in clamps:
            self.counters[c] += 1
        self.counters["sp_accepted"] += 1
        out = dataclasses.replace(sp, position_m=p, velocity_mps=v, acceleration_mps2=a, camera_ypr_rad=ypr,
                                  lens=lens)
        return SafetyResult(out, "", tuple(clamps))

    @staticmethod
    def _invalid(sp: M.Setpoint) -> tuple[str, str] | None:
        """(reason, counter) when the setpoint is unusable (unknown mode, non-finite values), else None."""
        if sp.mode not in MODES:
            return f"unknown setpoint mode {sp.mode!r}", "sp_rejected_mode"
        for name in ("position_m", "velocity_mps", "acceleration_mps2", "camera_ypr_rad"):
            a = getattr(sp, name)
            if np.shape(a) != (3,) or not _finite_array(a):
                return f"setpoint {name} is not 3 finite numbers: {a!r}", "sp_rejected_nonfinite"
        for name in ("focal_length_mm", "focus_distance_m", "f_number"):
            v = getattr(sp.lens, name)
            if isinstance(v, float) and math.isinf(v):
                return f"setpoint lens.{name} is infinite", "sp_rejected_nonfinite"
        return None

    def _position(self, sp: M.Setpoint, subject_xy: np.ndarray | None, vehicle_xy: np.ndarray | None,
                  clamps: list[str]) -> np.ndarray | None:
        """Subject distance, keep-outs, then geofence and altitude (the fence wins); None when the fence
        puts it back too near the subject or into a keep-out (a setpoint is never forwarded into one)."""
        cfg = self.cfg
        p = np.array(sp.position_m, dtype=float)
        keep_away = subject_xy is not None and cfg.min_subject_distance_m > 0
        if keep_away:
            p, hit = push_from_subject(p, np.asarray(subject_xy, float), cfg.min_subject_distance_m, vehicle_xy)
            _note(clamps, hit, "clamp_subject_distance")
        obstacles = _obstacles(cfg)
        if obstacles:
            q, _ = push_clear(obstacles, p, cfg.min_obstacle_distance_m)
            _note(clamps, bool(np.any(q != p)), "clamp_obstacle")
            p = q
        p, hit = clamp_geofence(p, cfg)
        _note(clamps, hit, "clamp_geofence")
        p, hit = clamp_altitude(p, cfg)
        _note(clamps, hit, "clamp_altitude")
        if keep_away and float(np.linalg.norm(p[:2] - subject_xy)) < cfg.min_subject_distance_m - 1e-6:
            return None
        if obstacles and intrusion_m(obstacles, p, cfg.min_obstacle_distance_m) > 1e-6:
            return None
        return p

    def _feed_forward(self, sp: M.Setpoint, p: np.ndarray, clamps: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration feed-forward within the limits, and not outward at the envelope."""
        cfg = self.cfg
        v, hit = clamp_norm(np.array(sp.velocity_mps, dtype=float), cfg.speed_max_mps)
        v, hit_z = clamp_climb(v, cfg.climb_max_mps)
        _note(clamps, hit or hit_z, "clamp_speed")
        v, hit = clamp_outward_velocity(p, v, cfg)
        _note(clamps, hit, "clamp_velocity_outward")
        a, hit = clamp_norm(np.array(sp.acceleration_mps2, dtype=float), cfg.accel_max_mps2)
        _note(clamps, hit, "clamp_accel")
        a, hit = clamp_outward_accel(p, a, cfg)
        _note(clamps, hit, "clamp_accel_outward")
        return v, a

    def _gimbal(self, sp: M.Setpoint, clamps: list[str]) -> np.ndarray:
        cfg = self.cfg
        yaw, pitch, roll = (float(x) for x in sp.camera_ypr_rad)
        pitch2 = min(max(pitch, cfg.pitch_min_rad), cfg.pitch_max_rad)
        roll2 = min(max(roll, -cfg.roll_max_rad), cfg.roll_max_rad)
        _note(clamps, pitch2 != pitch or roll2 != roll, "clamp_gimbal")
        return np.array([wrap_angle(yaw), pitch2, roll2])

    def clamp_lens(self, lens: M.LensState, lens_now: M.LensState | None) -> tuple[M.LensState, bool]:
        cfg = self.cfg
        hit = False

        def one(v: float, now: float, lo: float, hi: float) -> float:
            nonlocal hit
            if math.isnan(v):
                v = now
            if math.isnan(v):
                return v
            c = min(max(v, lo), hi)
            hit = hit or c != v
            return c

        now = lens_now or M.LensState()
        out = dataclasses.replace(
            lens,
            focal_length_mm=one(lens.focal_length_mm, now.focal_length_mm, cfg.focal_length_min_mm,
                                cfg.focal_length_max_mm),
            focus_distance_m=one(lens.focus_distance_m, now.focus_distance_m, cfg.focus_distance_min_m,
                                 cfg.focus_distance_max_m),
            f_number=one(lens.f_number, now.f_number, cfg.f_number_min, cfg.f_number_max),
        )
        return out, hit

    # ------------------------------------------------------------------ per tick
    def limit_motion(self, *, target_pos: np.ndarray, target_vel: np.ndarray, prev_pos: np.ndarray,
                     prev_vel: np.ndarray, dt_s: float) -> MotionCommand:
        """Move the commanded position/velocity towards the target within speed/accel limits.

        The commanded position advances by at most `speed_max_mps * dt_s` per tick (vertically by
        `climb_max_mps * dt_s`) and the commanded velocity changes by at most `accel_max_mps2 * dt_s`.
        """
        cfg = self.cfg
        dt = max(float(dt_s), 0.0)
        clamps: list[str] = []
        step, hit = clamp_norm(np.asarray(target_pos, float) - prev_pos, cfg.speed_max_mps * dt)
        step, hit_z = clamp_climb(step, cfg.climb_max_mps * dt)
        hit = hit or hit_z
        pos = prev_pos + step
        if hit:
            clamps.append("clamp_position_rate")
        dv, hit_v = clamp_norm(np.asarray(target_vel, float) - prev_vel, cfg.accel_max_mps2 * dt)
        vel = prev_vel + dv
        if hit_v:
            clamps.append("clamp_velocity_rate")
        # The target's feed-forward was clamped at the target; here it is again at the commanded
        # position, which may be nearer the boundary than the target.
        vel, hit_o = clamp_outward_velocity(pos, vel, cfg)
        if hit_o:
            clamps.append("clamp_velocity_outward")
        for c in clamps:
            self.counters[c] += 1
        return MotionCommand(pos, vel, tuple(clamps))
