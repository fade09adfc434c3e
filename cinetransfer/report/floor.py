"""How close could any camera have come? The joint error floor of a simulated run.

The simulator films a billboard: a real person's cut-out that turns about the vertical axis to face
the camera (sim/subject.py), posed as the footage has him at that instant. Seen by a pinhole camera
without roll, the billboard's joints (X right, Y up, metres in its plane) land, to first order
(weak perspective: the body small against its distance), at

    x = a X + tx,   y = ty - b Y        (normalised image coordinates, y down)

with a > 0 the scale (focal length over distance), and 0 <= b <= a W/H: the vertical scale shrinks
by the cosine of the angle the camera looks up or down at him (W/H turns pixels square). Any camera
position, aim and focal length gives some (a, b, tx, ty), so the least joint error over all of them
is a lower bound of what any flight could reach with this subject: per frame, the minimum of the
summed Euclidean errors over (a, b, tx, ty) — a small second-order cone program (cvxpy), left/right
matched either way. The bound ignores dynamics, limits, the scene and the focus; a camera that
rolls could do better (the report says whether the flight rolled).

In the 3-D world the subject is a body, not a billboard: a camera without roll looking along
azimuth az and elevation el sees his joints J (world, metres) at X = J . r, Y = J . u (r its
horizontal right axis, u its up axis), with b = a W/H exactly (square pixels). The floor there is
the least error over a grid of view directions (every VIEW_STEP_DEG in azimuth, elevations
VIEW_ELEVATIONS_DEG): per frame the VIEW_CANDIDATES directions of least squared error (closed
form) are solved as cone programs and the least kept.

The floor uses the joint-frames the report's truth joint error uses (a source target and a joint
the simulator shows), so "floor 0.028, flown 0.047" reads: 0.019 of the error is the flight's, the
rest is the subject's body, which cannot take the source person's pose.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from cinetransfer.shared.facing import mirror_permutation

if TYPE_CHECKING:  # the simulator is imported only where a floor is computed
    from cinetransfer.services.autopilot_bridge.sim.scene import Scene


@dataclass(frozen=True)
class Floor:
    per_frame: np.ndarray  # (N,) least summed joint error of each frame; NaN where nothing is compared
    counts: np.ndarray  # (N,) compared joints of each frame
    model: str = ""  # how it was reached (MODEL or MODEL_3D)

    def mean(self, rows: slice = slice(None)) -> float:
        """Mean least error per compared joint-frame over `rows` (NaN if none)."""
        k = int(self.counts[rows].sum())
        return float(np.nansum(self.per_frame[rows])) / k if k else float("nan")


def _least_errors(q: np.ndarray, p: np.ndarray, w: np.ndarray, aspect: float, square: bool = False) -> np.ndarray:
    """Per frame, the least summed joint error over (a, b, tx, ty) (the module doc), for all N
    frames in one cone program (cvxpy): the frames share nothing, so one solve of their sum gives
    each frame's own minimum at the cost of one problem set-up instead of N. q (N, E, 2) billboard
    joints (X, Y) [m], p (N, E, 2) normalised targets, w (N, E) 1 = compared, 0 = not (that joint's
    residual row is multiplied out: w x, w y, w t). `square`: b = aspect a (a 3-D body: its
    foreshortening is already in Y)."""
    from cinetransfer.whole_import import import_whole

    cp = import_whole("cvxpy")  # imported beside other threads' imports (transfer.warm_imports)

    n, e = w.shape
    q = np.nan_to_num(q) * w[..., None]
    p = np.nan_to_num(p) * w[..., None]
    a, b, t = cp.Variable(n), cp.Variable(n), cp.Variable((n, 2))
    ones = np.ones((1, e))
    x = cp.multiply(a[:, None] @ ones, q[..., 0]) + cp.multiply(w, t[:, 0:1] @ ones) - p[..., 0]
    y = cp.multiply(w, t[:, 1:2] @ ones) - cp.multiply(b[:, None] @ ones, q[..., 1]) - p[..., 1]
    cost = cp.sum(cp.norm(cp.vstack([cp.vec(x, order="C"), cp.vec(y, order="C")]), 2, axis=0))
    limits = [a >= 0, b == aspect * a] if square else [a >= 0, b >= 0, b <= aspect * a]
    problem = cp.Problem(cp.Minimize(cost), limits)
    problem.solve()
    if problem.status not in ("optimal", "optimal_inaccurate"):
        raise ValueError(f"floor fit failed: {problem.status}")
    av, bv, tv = a.value[:, None], b.value[:, None], t.value
    rx = av * q[..., 0] + w * tv[:, 0:1] - p[..., 0]
    ry = w * tv[:, 1:2] - bv * q[..., 1] - p[..., 1]
    return np.maximum(np.hypot(rx, ry).sum(axis=1), 0.0)


def joint_error_floor(targets: np.ndarray, compared: np.ndarray, billboard: np.ndarray,
                      joint_names: Sequence[str], aspect: float, square: bool = False) -> Floor:
    """targets (N, E, 2) normalised source targets, compared (N, E) bool (joint-frames the truth
    error counts), billboard (N, E, 2) the subject's joints in his plane [m] (X right, Y up;
    NaN = unknown), aspect = image width / height; `square` as _least_errors."""
    n, e = compared.shape
    perm = mirror_permutation(joint_names)
    per = np.full(n, np.nan)
    counts = np.zeros(n, dtype=int)
    w = (compared & np.all(np.isfinite(billboard), axis=2)).astype(float)
    rows = np.flatnonzero(w.any(axis=1))
    if rows.size == 0:
        return Floor(per, counts, MODEL)
    per[rows] = _least_errors(billboard[rows], targets[rows], w[rows], aspect, square)
    counts[rows] = w[rows].sum(axis=1).astype(int)
    if not np.array_equal(perm, np.arange(e)):  # left/right either way, where both see the same joints
        w_m = (compared & np.all(np.isfinite(billboard[:, perm]), axis=2)).astype(float)
        both = rows[np.all(w_m[rows] == w[rows], axis=1)]
        if both.size:
            per[both] = np.minimum(per[both], _least_errors(billboard[both][:, perm], targets[both], w[both], aspect,
                                                                   square))
    return Floor(per, counts, MODEL)


def _coco_index(joint_names: Sequence[str]) -> list[int]:
    """Each joint's row in the simulator's COCO-17 joints (-1: not a COCO-17 joint)."""
    from cinetransfer.shared.messages import COCO17_NAMES

    return [list(COCO17_NAMES).index(n) if n in COCO17_NAMES else -1 for n in joint_names]


def _aspect(sc: Scene) -> float:
    return float(sc.camera.width) / float(sc.camera.height)


def billboard_joints(sc: Scene, stamps_ns: Sequence[int], epoch_ns: int,
                     joint_names: Sequence[str]) -> tuple[np.ndarray, float]:
    """((N, E, 2) the filmed subject's joints in his billboard's plane [m] (X right, Y up) at each
    simulation stamp, as the simulator poses him; the rendered image's width / height). `sc`: the
    run's loaded scene (sim.scene.load_scene, with the run's library person)."""
    from cinetransfer.services.autopilot_bridge.sim.subject import Subject

    sub = Subject(sc.subject, sc.ground.z_m if sc.ground is not None else 0.0)
    idx = _coco_index(joint_names)
    out = np.full((len(stamps_ns), len(joint_names), 2), np.nan)
    for i, stamp in enumerate(stamps_ns):
        t = (int(stamp) - int(epoch_ns)) * 1e-9
        pose = sub.script.pose_at(t)
        frame = sub.frame_at(t, pose.action, float(np.hypot(*pose.velocity_mps[:2])))
        ax, ay = frame.anchor_px
        for e, j in enumerate(idx):
            if j >= 0:
                out[i, e] = ((frame.joints_px[j, 0] - ax) * sub.m_per_px, (ay - frame.joints_px[j, 1]) * sub.m_per_px)
    return out, _aspect(sc)


def body_joints(sc: Scene, stamps_ns: Sequence[int], epoch_ns: int,
                joint_names: Sequence[str]) -> tuple[np.ndarray, float]:
    """((N, E, 3) the filmed 3-D body's joints [m, world] at each simulation stamp, as the 3-D world
    poses him; the rendered image's width / height). `sc` as billboard_joints."""
    from cinetransfer.services.autopilot_bridge.sim.actor import Actor

    actor = Actor(sc.subject, sc.ground.z_m if sc.ground is not None else 0.0)
    idx = _coco_index(joint_names)
    out = np.full((len(stamps_ns), len(joint_names), 3), np.nan)
    for i, stamp in enumerate(stamps_ns):
        joints = actor.joints_at((int(stamp) - int(epoch_ns)) * 1e-9)
        for e, j in enumerate(idx):
            if j >= 0:
                out[i, e] = joints[j]
    return out, _aspect(sc)


#: the 3-D floor's grid of view directions (module doc)
VIEW_STEP_DEG = 5.0
VIEW_ELEVATIONS_DEG = (-30.0, -15.0, 0.0, 15.0, 30.0, 45.0, 60.0, 75.0)
VIEW_CANDIDATES = 3


def view_axes(azimuth_rad: np.ndarray, elevation_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(D, 3) right and (D, 3) up axes of cameras without roll looking along azimuth (from +x
    towards +y) and elevation (positive: looking down)."""
    az, el = np.asarray(azimuth_rad, float), np.asarray(elevation_rad, float)
    right = np.stack([np.sin(az), -np.cos(az), np.zeros_like(az)], axis=1)
    up = np.stack([np.sin(el) * np.cos(az), np.sin(el) * np.sin(az), np.cos(el)], axis=1)
    return right, up


def _view_grid() -> tuple[np.ndarray, np.ndarray]:
    az = np.radians(np.arange(0.0, 360.0, VIEW_STEP_DEG))
    el = np.radians(np.array(VIEW_ELEVATIONS_DEG))
    return view_axes(np.repeat(az, el.size), np.tile(el, az.size))


def best_views(joints: np.ndarray, targets: np.ndarray, w: np.ndarray, aspect: float, k: int) -> np.ndarray:
    """(k, N, E, 2) the joints (N, E, 3) seen from each frame's k grid directions of least squared
    error: x = a X + tx, y = ty - aspect a Y, a >= 0, least squares in closed form per direction."""
    right, up = _view_grid()
    j = np.nan_to_num(joints)
    X, Y = j @ right.T, j @ up.T  # (N, E, D)
    wn = w / np.maximum(w.sum(axis=1, keepdims=True), 1.0)
    px, py = np.nan_to_num(targets[..., 0]), np.nan_to_num(targets[..., 1])

    def centred(v: np.ndarray) -> np.ndarray:
        m = (wn[..., None] * v).sum(axis=1, keepdims=True) if v.ndim == 3 else (wn * v).sum(axis=1, keepdims=True)
        return v - m

    Xc, Yc, pxc, pyc = centred(X), centred(Y), centred(px)[..., None], centred(py)[..., None]
    num = (w[..., None] * (Xc * pxc - aspect * Yc * pyc)).sum(axis=1)
    den = (w[..., None] * (Xc ** 2 + aspect ** 2 * Yc ** 2)).sum(axis=1)
    a = np.maximum(num / np.maximum(den, 1e-12), 0.0)  # (N, D)
    sse = (w[..., None] * ((a[:, None] * Xc - pxc) ** 2 + (aspect * a[:, None] * Yc + pyc) ** 2)).sum(axis=1)
    order = np.argsort(sse, axis=1, kind="stable")[:, :k]  # (N, k)
    rows = np.arange(joints.shape[0])[:, None]
    return np.stack([np.stack([X[rows, :, order[:, [c]]][:, 0], Y[rows, :, order[:, [c]]][:, 0]], axis=-1)
                     for c in range(order.shape[1])])


def body_floor(targets: np.ndarray, compared: np.ndarray, joints: np.ndarray, joint_names: Sequence[str],
               aspect: float) -> Floor:
    """The floor (module doc, 3-D world) of targets (N, E, 2) against a body's joints (N, E, 3) [m]."""
    w = (compared & np.all(np.isfinite(joints), axis=2)).astype(float)
    best = None
    for plane in best_views(joints, targets, w, aspect, VIEW_CANDIDATES):
        plane = np.where(np.isfinite(joints[..., :2]), plane, np.nan)
        fl = joint_error_floor(targets, compared, plane, joint_names, aspect, square=True)
        best = fl if best is None else Floor(np.fmin(best.per_frame, fl.per_frame), best.counts, MODEL_3D)
    return Floor(best.per_frame, best.counts, MODEL_3D)


#: how the floor is reached (the report states it next to the number)
MODEL = ("the least truth joint error of any camera (anywhere, aimed anyhow, any focal length, no roll; no "
         "dynamics, limits or scene) with this subject's pose at each frame; weak perspective, which misses the "
         "simulator's own projection by ~0.002 (docs/report.md)")
MODEL_3D = ("the least truth joint error of any camera without roll (looking from any of a grid of directions: "
            f"every {VIEW_STEP_DEG:g} deg round, elevations {VIEW_ELEVATIONS_DEG[0]:g} to {VIEW_ELEVATIONS_DEG[-1]:g} "
            "deg; any distance, any focal length) at this 3-D body's pose at each frame; weak perspective, no "
            "dynamics, limits or scene (docs/report.md)")


def run_floor(source, truths: Sequence, meta: dict, *, aligned_by_index: bool) -> tuple[Floor | None, str]:
    """(the floor of a simulated run's truth joint error, why not) from its source instructions,
    truths and meta (scene, subject, epoch_ns); None with a reason when it cannot be computed."""
    from cinetransfer.report import fidelity as F

    if not truths:
        return None, "no ground truth"
    if not meta.get("scene") or meta.get("epoch_ns") is None:
        return None, "not a simulated run with a known scene and clock (meta: scene, epoch_ns)"
    if not aligned_by_index:
        return None, "source and output frame rates differ"
    names = list(source.joint_names)
    n = int(source.image_targets.shape[0])
    S, T = F.instructions_track(source, names), F.truth_track(truths, names, n)
    off = F.truth_frame_offset(truths)
    stamps = np.zeros(n, dtype=np.int64)
    for t in truths:
        if 0 <= int(t.frame_index) - off < n:
            stamps[int(t.frame_index) - off] = int(t.stamp_ns)
    try:
        from cinetransfer.services.autopilot_bridge.sim.scene import load_scene

        sc = load_scene(str(meta["scene"]), subject=meta.get("subject"))
        three_d = sc.world == "3d"
        joints, aspect = (body_joints if three_d else billboard_joints)(sc, stamps, int(meta["epoch_ns"]), names)
    except Exception as e:  # noqa: BLE001 - a scene file moved since the run: the report goes on without it
        return None, f"the run's scene could not be loaded ({type(e).__name__}: {e})"
    if three_d:
        return body_floor(S.xy, S.ok & T.ok, joints, names, aspect), ""
    return joint_error_floor(S.xy, S.ok & T.ok, joints, names, aspect), ""
