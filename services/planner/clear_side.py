"""From which side of a waiting subject to start a truck: one whose path misses the keep-outs (pure numpy).

The framing fixes where the subject is in the image, not the camera's bearing round him (the horizontal
direction from the subject to the camera); the pre-roll leaves the camera at whatever bearing its start
gives. A truck flown from there may run into a keep-out obstacle: beside the courtyard's tree_3 (25 deg
off the truck's direction) the camera stood at the clearance's edge and panned after the walker instead.
Before such a take the planner asks a bearing from which the take's travel stays clear (`clear_bearing`):
the nearest to where the camera stands, searched in STEP_RAD steps each way up to MAX_TURN_RAD, each way
only as far as the camera turns round him without entering a keep-out. The travel
is straight, in the camera's frame (`truck_travel`: the style's direction, as long as the source's swing
round its subject times the subject's distance), with the subject taken to stand where he waits (where a
walker goes is not known before he walks). Only trucks are drawn so: an orbit's path curves round the
subject, a dolly's runs along the axis towards or away from him.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from cinetransfer.services.planner.side_of_subject import FREE_ANGLE_RAD, carrot
from cinetransfer.shared.obstacles import Obstacle, intrusion_m

STEP_RAD = math.radians(5.0)
MAX_TURN_RAD = math.radians(90.0)
TRUCK = "truck"


def truck_travel(classes: Sequence[frozenset[str] | None], travel: np.ndarray, swing_radps: np.ndarray,
                 fps: float, distance_m: float) -> np.ndarray:
    """(2,) the camera's travel [m] over the truck rows given, in its frame at the start (forward, left):
    per row the style's direction of travel (planner camera frame, x forward, y left) times the sideways
    speed the row's swing round the subject asks (|rate| x the subject's distance) over one row; rows that
    are no truck or carry no finite swing add nothing."""
    out = np.zeros(2)
    if not (fps > 0 and math.isfinite(distance_m)):
        return out
    for cls, d, w in zip(classes, np.asarray(travel, float), np.asarray(swing_radps, float)):
        if cls is not None and TRUCK in cls and math.isfinite(w) and np.isfinite(d[:2]).all():
            out += d[:2] * abs(w) * distance_m / fps
    return out


def segment_clear(start_xy: Sequence[float], travel_xy: Sequence[float], z_m: float,
                  obstacles: Sequence[Obstacle], clearance_m: float) -> bool:
    """Whether the straight path from `start_xy` by `travel_xy` (world, m) at height `z_m` keeps every
    obstacle's clearance: the path's point nearest each axis lies outside that obstacle's keep-out
    (shared.obstacles.intrusion_m; `stands_clear` for a path of no travel)."""
    a, v = np.asarray(start_xy, float)[:2], np.asarray(travel_xy, float)[:2]
    vv = float(v @ v)
    for k in obstacles:
        t = 0.0 if vv < 1e-12 else min(1.0, max(0.0, float((np.array([k.x_m, k.y_m]) - a) @ v) / vv))
        if not stands_clear(a + t * v, z_m, (k,), clearance_m):
            return False
    return True


def stands_clear(xy: Sequence[float], z_m: float, obstacles: Sequence[Obstacle], clearance_m: float) -> bool:
    """Whether a camera at `xy` (world, m) and height `z_m` keeps every obstacle's clearance."""
    return intrusion_m(obstacles, (float(xy[0]), float(xy[1]), z_m), clearance_m) <= 0.0


def travel_in_world(bearing_rad: float, travel_cam: Sequence[float]) -> np.ndarray:
    """(2,) a travel (forward, left) of a camera at `bearing_rad` round the subject, looking at him, in the world."""
    fwd = np.array([-math.cos(bearing_rad), -math.sin(bearing_rad)])
    left = np.array([-fwd[1], fwd[0]])
    return float(travel_cam[0]) * fwd + float(travel_cam[1]) * left


def clear_bearing(subject_xy: Sequence[float], camera_xy: Sequence[float], z_m: float, travel_cam: Sequence[float],
                  obstacles: Sequence[Obstacle], clearance_m: float, *, step_rad: float = STEP_RAD,
                  max_turn_rad: float = MAX_TURN_RAD) -> float:
    """The bearing round the subject, at the camera's distance from him, nearest to the camera's own from
    which `travel_cam` (truck_travel) stays clear (segment_clear); at equal turns the way of increasing
    bearing first. A way is searched only as far as the camera can turn round him without entering a
    keep-out (a bearing beyond an obstacle would have it fly round it, or stand at its edge). The camera's
    own bearing when its travel is clear; NaN when no bearing within `max_turn_rad` is (or it stands on him)."""
    s, p = np.asarray(subject_xy, float)[:2], np.asarray(camera_xy, float)[:2]
    d = float(np.linalg.norm(p - s))
    if d < 1e-6:
        return math.nan
    b0 = math.atan2(p[1] - s[1], p[0] - s[0])
    if segment_clear(p, travel_in_world(b0, travel_cam), z_m, obstacles, clearance_m):
        return b0
    open_ways = [1.0, -1.0]
    for i in range(1, int(math.floor(max_turn_rad / step_rad + 1e-9)) + 1):
        for way in list(open_ways):
            b = b0 + way * i * step_rad
            start = s + d * np.array([math.cos(b), math.sin(b)])
            if not stands_clear(start, z_m, obstacles, clearance_m):
                open_ways.remove(way)
            elif segment_clear(start, travel_in_world(b, travel_cam), z_m, obstacles, clearance_m):
                return b
    return math.nan


def side_wanted_for(bearing_now: float, clear: float) -> float:
    """The wanted bearing to hand the side-of-subject term (side_of_subject.py) so that it draws the camera
    from `bearing_now` round to `clear`: the term is free within FREE_ANGLE_RAD of what it is asked, so it
    is asked that far beyond `clear`, at most MAX_STEP_RAD from now (carrot); NaN when the camera is there."""
    turn = math.remainder(clear - bearing_now, 2 * math.pi)
    if not (math.isfinite(turn) and abs(turn) > 1e-9):
        return math.nan
    return carrot(bearing_now, clear + math.copysign(FREE_ANGLE_RAD, turn))
