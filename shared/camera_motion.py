"""Camera motion from image motion: the math (pure numpy; the detector tracks the points).

Image points are pixels relative to the principal point (the image centre), x right, y down; the
camera frame is x right, y down, z forward. Per frame the background's points move by the
instantaneous motion field of a camera that rotates, zooms and translates:

    u = p (f + x^2/f) + t (x y / f)   + r y + s x + (x Tz - f Tx) / Z
    v = p (x y / f)   + t (f + y^2/f) - r x + s y + (y Tz - f Ty) / Z

with p the pan (positive: the camera turns to its left, the scene moves right), t the tilt
(positive: up, the scene moves down), r the roll (positive: clockwise as the camera sees it, the
scene turns counter-clockwise) in rad per frame, s = d ln(focal length) per frame, T the
translation and Z each point's depth. Evaluated at the midpoint of each track the first-order
field is exact to second order.

The focal length in pixels of a source whose lens is unknown comes from `ASSUMED_HFOV_DEG`; a
wrong guess scales the rotation rates by about the ratio of the focal lengths (the classes and the
zoom rate do not depend on it).

Rotation + zoom is fitted robustly (RANSAC on two-point samples, then least squares on the
inliers). When that model leaves much of the background unexplained, parallax shows a
translation: rotation and translation direction are then fitted with each point's depth
eliminated (the residual must point along (x Tz - f Tx, y Tz - f Ty)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: horizontal field of view assumed for a source whose lens is unknown [deg]: about the simulated
#: camera's starting lens (30-35 mm on CineMPC's 23.76 mm sensor: 43-38 deg)
ASSUMED_HFOV_DEG = 40.0

#: the vocabulary of classes, in the order combinations are written ("pan+tilt")
CLASSES = ("static", "pan", "tilt", "roll", "zoom_in", "zoom_out", "dolly_in", "dolly_out", "truck",
           "pedestal", "orbit", "dolly_zoom")

#: |rate| from which a rotation counts as a move [deg/s]
ROTATION_MIN_DPS = 1.5
#: a pan or tilt beside a translation counts from this rate (deg/s): the translation's direction is
#: fitted freely, so a pan trades against its sideways part and a tilt against its vertical part
#: (the rotation-translation ambiguity); the rendered moves' outputs read them up to 1.5 (pan beside a
#: dolly or truck) and 2.7 (tilt beside a pedestal) deg/s off their poses, across ROTATION_MIN_DPS
ROTATION_BESIDE_TRANSLATION_DPS = 3.0
#: |d ln f / dt| from which a zoom counts as a move [1/s]
ZOOM_MIN_PER_S = 0.03
#: a point fits a model within this distance [px at the work width WORK_WIDTH]
INLIER_PX = 0.6
WORK_WIDTH = 320
#: rotation + zoom explains the frame when at least this share of the points fit it
EXPLAINED_SHARE = 0.8
#: fewest background points for a fit
MIN_POINTS = 12
#: ... and a translation is seen when rotation + translation explains this much larger a share
PARALLAX_GAIN = 0.15
#: ... or, short of EXPLAINED_SHARE, this much larger a share (`parallax_share_needed`)
PARALLAX_DOMINANT = 0.4
#: the parallax test runs over a baseline of this many frames at least (a slow dolly's parallax is a
#: fraction of a pixel per frame at the work width: over several frames it stands out of the noise)
MIN_SPAN = 4
#: ... over at least this many points tracked that long
MIN_BASELINE_POINTS = 40
#: ... with the inlier distance this much wider (the points' tracks drift a little over the frames)
LONG_INLIER_FACTOR = 2.0
#: a direction found by search replaces the first fit's when it explains this many times the points
SEARCH_MARGIN = 1.1
#: fit_rotation_translation's directions that explain within this share of the points of the best
#: are told apart by the least rotation (`_least_rotation`)
ROTATION_TIE = 0.1
#: a translation this close to the optical axis is a dolly (|t_z|), whose zoom the far points show
DOLLY_AXIS = 0.9
#: ... the share of the points taken as the far ones
FAR_SHARE = 0.1
#: a dolly is no dolly when its lower points scale less its way with a correlation below minus this
GROUND_DENIES = 0.2
#: ... but the dolly the other way is, with a zoom against it, when below its focus of expansion the lower
#: points scale more that way with a correlation of at least this (ground_backs_mirror)
GROUND_BACKS = 0.5
#: a dolly is no dolly when its parallax points lie to one side of its focus of expansion (their
#: mean direction from it at least this long) and fewer than IN_FRONT of them are in front of the camera
ONE_SIDED, IN_FRONT = 0.7, 0.9
#: the rotation given a translation direction is fitted again on the points within this many
#: inlier distances of it, this many times
TRIM_FACTOR = 2.0
TRIM_ROUNDS = 2
#: an edge track slides along its edge (the aperture problem) when its residual off rotation + zoom
#: over the baseline lies above the median of the corners nearest it by more than this many of their
#: robust standard deviations (1.4826 x the median absolute deviation: the Hampel identifier's usual 3)
#: and by more than the inlier distance (what the fit cannot tell apart anyway)
SLIDE_SIGMAS = 3.0
#: ... the corners nearest it: as many as the fewest points of a fit
SLIDE_NEIGHBOURS = MIN_POINTS


def focal_px(width: int, hfov_deg: float = ASSUMED_HFOV_DEG) -> float:
    """Focal length in pixels of an image `width` px wide with horizontal field of view `hfov_deg`."""
    return 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)


def hfov_deg(focal_mm: float, sensor_width_mm: float) -> float:
    """Horizontal field of view [deg] of a lens on a sensor."""
    return math.degrees(2.0 * math.atan(0.5 * sensor_width_mm / focal_mm))


def rotation_zoom_basis(pts: np.ndarray, f: float) -> np.ndarray:
    """(N, 2, 4) the motion field of unit pan, tilt, roll [rad] and log-zoom at points (N, 2)."""
    x, y = pts[:, 0], pts[:, 1]
    out = np.empty((len(pts), 2, 4))
    out[:, 0, 0], out[:, 1, 0] = f + x * x / f, x * y / f
    out[:, 0, 1], out[:, 1, 1] = x * y / f, f + y * y / f
    out[:, 0, 2], out[:, 1, 2] = y, -x
    out[:, 0, 3], out[:, 1, 3] = x, y
    return out


def edge_tracks(normals: np.ndarray | None, n: int) -> np.ndarray:
    """(n,) True for the tracks that are edges: those with a unit normal in `normals` (N, 2), whose
    rows of zeros are corners; all False without normals."""
    if normals is None:
        return np.zeros(n, dtype=bool)
    return np.any(np.asarray(normals) != 0.0, axis=1)


def project_normal(v: np.ndarray, normals: np.ndarray | None) -> np.ndarray:
    """`v` (N, 2) or (N, 2, k) with each edge track's vector replaced by its part along the edge's
    normal, n (n . v); a corner's unchanged. An edge track keeps only the motion across the edge
    (the aperture problem): a point-to-line residual, as in normal flow."""
    edge = edge_tracks(normals, len(v))
    if not edge.any():
        return v
    n = np.asarray(normals, dtype=float)[edge]
    out = np.array(v, dtype=float, copy=True)
    if out.ndim == 2:
        out[edge] = n * np.einsum("nk,nk->n", n, out[edge])[:, None]
    else:
        out[edge] = n[:, :, None] * np.einsum("nk,nkj->nj", n, out[edge])[:, None, :]
    return out


def sliding_edges(p0: np.ndarray, p1: np.ndarray, f: float, normals: np.ndarray, *, inlier_px: float) -> np.ndarray:
    """(N,) True for the edge tracks (a unit normal in `normals`) that slide along their edge over the
    baseline p0 -> p1 rather than follow the texture. Against the corners' rotation + zoom, such a
    track both falls short of the motion along its edge (or goes against it) by more than
    `inlier_px`, and has a 2-D residual that is an outlier among those of the SLIDE_NEIGHBOURS
    corners nearest it (SLIDE_SIGMAS robust standard deviations above their median, and more than
    `inlier_px`).

    Whatever moves a track beyond rotation + zoom and is the scene's own (a dolly's or a truck's
    parallax) moves the corners beside it alike, and a dolly's near paving moves further along its
    receding lines than the corners' zoom, not less: the output of a dolly out, the edge tracks on
    its nearest paving 2-5 px ahead of the zoom out, with no corner below them. Sliding tracks lose
    their motion along the edge or run the other way along the tiles' repeating lines: on the
    rendered zoom in, 6-8 px against the zoom where the corners beside them are off by 0.5-1 px.
    The structure tensor cannot tell the two (the same lesser eigenvalue)."""
    n = len(p0)
    edge = edge_tracks(normals, n)
    corner = np.flatnonzero(~edge)
    out = np.zeros(n, dtype=bool)
    if not edge.any() or len(corner) < SLIDE_NEIGHBOURS:
        return out
    q = fit_rotation_zoom(p0[corner], p1[corner], f, inlier_px=inlier_px)[0]
    mid = 0.5 * (p0 + p1)
    resid = np.linalg.norm(rotation_zoom_basis(mid, f) @ q - (p1 - p0), axis=1)
    e = np.flatnonzero(edge)
    dist = np.linalg.norm(mid[e][:, None, :] - mid[corner][None, :, :], axis=2)
    near = np.argpartition(dist, SLIDE_NEIGHBOURS - 1, axis=1)[:, :SLIDE_NEIGHBOURS]
    beside = resid[corner][near]  # (E, k)
    med = np.median(beside, axis=1)
    sigma = 1.4826 * np.median(np.abs(beside - med[:, None]), axis=1)
    along = np.column_stack([-normals[e, 1], normals[e, 0]])
    model = np.einsum("nk,nk->n", rotation_zoom_basis(mid[e], f) @ q, along)
    short = (np.einsum("nk,nk->n", (p1 - p0)[e], along) - model) * np.sign(model)
    lags = short < -inlier_px  # fell short of the model along the edge, or went against it
    out[e] = lags & (resid[e] > med + np.maximum(SLIDE_SIGMAS * sigma, inlier_px))
    return out


@dataclass(frozen=True)
class FrameMotion:
    """The camera's motion between two frames, per frame (not per second)."""

    rotation_rad: np.ndarray  #: (3,) pan, tilt, roll [rad]; NaN = unknown
    log_zoom: float  #: ln(f_now / f_before); NaN = unknown
    translation_dir: np.ndarray  #: (3,) unit vector, camera frame; zeros = none seen; NaN = unknown
    points: int  #: background points used
    explained: float  #: share of them rotation + zoom explains; NaN = too few points

    @staticmethod
    def unknown(points: int = 0) -> "FrameMotion":
        return FrameMotion(np.full(3, np.nan), math.nan, np.full(3, np.nan), int(points), math.nan)


def _solve(basis: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Least-squares parameters (4,) of the motion field `basis` (N, 2, 4) for `flow` (N, 2)."""
    a = basis.reshape(-1, 4)
    q, *_ = np.linalg.lstsq(a, flow.reshape(-1), rcond=None)
    return q


def fit_rotation_zoom(p0: np.ndarray, p1: np.ndarray, f: float, *, inlier_px: float, iters: int = 64,
                      rng: np.random.Generator | None = None,
                      normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pan, tilt, roll [rad] and log-zoom (4,) moving points p0 to p1 (N, 2, centred px), and the
    inlier mask (N,): RANSAC over two-point samples, then least squares on the best inliers.
    An edge track (a unit normal in `normals`, see project_normal) is fitted and judged by its
    motion across the edge alone; the samples are drawn from the corners when there are two."""
    rng = rng or np.random.default_rng(0)
    mid = 0.5 * (p0 + p1)
    flow = project_normal(p1 - p0, normals)
    basis = project_normal(rotation_zoom_basis(mid, f), normals)
    corner = np.flatnonzero(~edge_tracks(normals, len(p0)))
    pool = corner if len(corner) >= 2 else np.arange(len(p0))
    pairs = pool[rng.integers(0, len(pool), size=(iters, 2))]
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    a = basis[pairs].reshape(len(pairs), 4, 4)  # two points x (u, v) rows per hypothesis
    b = flow[pairs].reshape(len(pairs), 4)
    ok = np.abs(np.linalg.det(a)) > 1e-9
    hyps = np.linalg.solve(a[ok], b[ok][..., None])[..., 0] if ok.any() else np.zeros((0, 4))
    hyps = np.vstack([hyps, np.zeros((1, 4))])  # "nothing moved" is always a candidate
    # each hypothesis's miss |pred - flow| as norm(axis=2) computes it (the same sums and roots, bit
    # for bit) without its general-axis machinery: a fifth of this fit's CPU, run ~3 times a frame
    off = np.einsum("nkj,hj->hnk", basis, hyps) - flow[None]
    inl = np.sqrt(off[..., 0] * off[..., 0] + off[..., 1] * off[..., 1]) < inlier_px
    best = inl[int(np.argmax(inl.sum(axis=1)))]
    q = _solve(basis[best], flow[best]) if best.sum() >= 2 else np.zeros(4)
    inl = np.linalg.norm(basis @ q - flow, axis=1) < inlier_px
    if inl.sum() >= 2:
        q = _solve(basis[inl], flow[inl])
    return q, inl


def explained_share(p0: np.ndarray, p1: np.ndarray, f: float, q0: np.ndarray, *, inlier_px: float,
                    normals: np.ndarray | None = None) -> float:
    """Share of the points p0 -> p1 (a baseline of several frames) that rotation + zoom explains:
    the more of the parameters `q0` (4,) (the frame's own fit scaled to the baseline) refitted on
    their inliers once, and rotation + zoom fitted to the baseline by itself (RANSAC).

    The baseline's rotation is the sum of its frames' rotations, not the last frame's times the
    span: a hovering camera sways (its pan swings between -2 and +5 deg/s from frame to frame) and
    a pan speeds up, and the last frame's rate scaled to 8 frames then mispredicts every point by
    pixels (the output of a static take: 0-10 % explained where the baseline's own fit explains
    95-100 %), which the translation fit then took for parallax. Edge tracks: by their motion
    across the edge (`normals`, see project_normal)."""
    mid = 0.5 * (p0 + p1)
    flow = project_normal(p1 - p0, normals)
    basis = project_normal(rotation_zoom_basis(mid, f), normals)
    inl = np.linalg.norm(basis @ q0 - flow, axis=1) < inlier_px
    if inl.sum() >= 2:
        inl = np.linalg.norm(basis @ _solve(basis[inl], flow[inl]) - flow, axis=1) < inlier_px
    seeded = float(inl.mean())
    if seeded >= EXPLAINED_SHARE:  # the frame's own rates explain the baseline: no second RANSAC
        return seeded
    return max(seeded, float(fit_rotation_zoom(p0, p1, f, inlier_px=inlier_px, normals=normals)[1].mean()))


def parallax_share_needed(share: float) -> float:
    """The share of the points over the baseline that rotation + translation must explain to show a
    translation, where rotation + zoom explains `share`: EXPLAINED_SHARE and PARALLAX_GAIN more than
    `share`, or short of EXPLAINED_SHARE, PARALLAX_DOMINANT more.

    Past the rendered pedestal rotation + zoom explained 23-45 % of the points and the pedestal
    itself 76-78 %: the tracks on the paving's lines slide sideways along them as the camera rises
    (3-6 px over the 8 frames), which no depth explains, so rows 0-17 read tilt+roll. A gain that
    large is no tracking noise."""
    return max(share + PARALLAX_GAIN, min(EXPLAINED_SHARE, share + PARALLAX_DOMINANT))


def _translation_dir(mid: np.ndarray, resid: np.ndarray, f: float) -> np.ndarray:
    """Unit T (3,) that the residual flow (N, 2) points along, each point's depth eliminated: the
    null vector of the rows [f r_y, -f r_x, r_x y - r_y x]; signed so that the depths are positive."""
    x, y = mid[:, 0], mid[:, 1]
    rows = np.stack([f * resid[:, 1], -f * resid[:, 0], resid[:, 0] * y - resid[:, 1] * x], axis=1)
    t = np.linalg.svd(rows, full_matrices=False)[2][-1]
    d = np.stack([x * t[2] - f * t[0], y * t[2] - f * t[1]], axis=1)
    if np.sum(np.einsum("nk,nk->n", d, resid)) < 0:  # inverse depth = (r . d) / |d|^2 must be > 0
        t = -t
    return t / np.linalg.norm(t)


def _perpendicular(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, rot: np.ndarray, t: np.ndarray,
                   f: float) -> np.ndarray:
    """Each point's residual flow across its translation line (N,) [px]: zero when a depth explains it."""
    return _off_lines(flow, basis, rot, *_lines(mid, t, f))


def _lines(mid: np.ndarray, t: np.ndarray, f: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's translation line's direction d (N, 2) for the direction t, and |d| (N,) (at least 1e-9)."""
    d = np.stack([mid[:, 0] * t[2] - f * t[0], mid[:, 1] * t[2] - f * t[1]], axis=1)
    return d, np.maximum(np.linalg.norm(d, axis=1), 1e-9)


def _off_lines(flow: np.ndarray, basis: np.ndarray, rot: np.ndarray, d: np.ndarray, norm_d: np.ndarray) -> np.ndarray:
    """_perpendicular from the points' lines `_lines` (computed once for all the rotations tried along them)."""
    r = flow - basis @ rot
    return np.abs(r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]) / norm_d


def _hemisphere(n: int) -> tuple[np.ndarray, ...]:
    """n unit vectors spread evenly over the half sphere z >= 0 (t and -t draw the same lines)."""
    k = np.arange(n) + 0.5
    z = k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    r = np.sqrt(1.0 - z * z)
    return tuple(np.column_stack([r * np.cos(phi), r * np.sin(phi), z]))


_DIRECTIONS = _hemisphere(48)


def fit_rotation_translation(p0: np.ndarray, p1: np.ndarray, f: float, rot0: np.ndarray, *, inlier_px: float,
                             iters: int = 5, shown: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotation (3,) [rad], translation direction (3,) and inliers (N,) moving p0 to p1 with
    parallax: alternate the direction given the rotation and the rotation given the direction
    (linear in each), from `rot0`, dropping the points far off the model (moving things). When that
    explains at least the share `shown` of the points (a translation is seen), the alternation runs
    again from the optical axis, the search's direction is a third candidate, and of those that
    explain about as many points the one with the least rotation is kept (`_least_rotation`): it
    chooses the direction, never whether there is one. The depth of every point is eliminated, so a zoom and a
    dolly past a flat background are the same to it: call it only when rotation + zoom does not
    explain the points."""
    mid, flow = 0.5 * (p0 + p1), p1 - p0
    basis = rotation_zoom_basis(mid, f)[:, :, :3]
    rot = np.asarray(rot0, dtype=float).copy()
    t = _translation_dir(mid, flow - basis @ rot, f)
    # the rotation fitted first has taken up what of a sideways move looks like a pan: a coarse
    # search over directions (each with its own rotation) starts the alternation where it belongs
    best = _count_in_front(flow, basis, rot, t, _lines(mid, t, f), inlier_px)
    scores = _search_scores(mid, flow, basis, f, inlier_px)
    k = int(np.argmax(scores))  # the first of the best, as the search over _DIRECTIONS in order
    searched = bool(scores[k] > SEARCH_MARGIN * best)  # only a clearly better start: near ties keep the first fit's
    if searched:
        t = _DIRECTIONS[k]
    first = _alternate_on(mid, flow, basis, f, t, inlier_px, iters)
    if first[2].mean() < shown:
        # the alternation can walk away from a start that showed the translation (past the rendered
        # pedestal it went from the pedestal, 83 % of the points, to the optical axis, 65 %): the
        # search's direction is kept then, signed and polished
        if searched and scores[k] >= shown * len(mid):
            return polish_direction(mid, flow, basis, f, *_signed_direction(mid, flow, basis, f, _DIRECTIONS[k],
                                                                            inlier_px), inlier_px)
        return first
    # the alternation settles where it starts: past a dolly-zoom a start off to the side settled on
    # a truck with a pan that explains fewer points than the dolly; the one from the optical axis
    # is a candidate too, and so is the search's direction (past the rendered pedestal the
    # alternation from it walked off to a dolly out with a tilt)
    starts = [first, _alternate_on(mid, flow, basis, f, _OPTICAL_AXIS, inlier_px, iters)]
    if searched:
        starts.append(_signed_direction(mid, flow, basis, f, _DIRECTIONS[k], inlier_px))
    return _least_rotation(mid, flow, basis, f, [polish_direction(mid, flow, basis, f, *c, inlier_px) for c in starts],
                           inlier_px)


_OPTICAL_AXIS = np.array([0.0, 0.0, 1.0])
_DIRECTION_ARRAY = np.array(_DIRECTIONS)


def _least_rotation(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, f: float, fits: list[tuple],
                    inlier_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of the fits (rotation (3,), direction (3,), inliers (N,)), the one with the least rotation
    among those that explain (`_count_in_front`) within ROTATION_TIE of the points of the best; the
    first of equals.

    With each point's depth free, a rotation and a translation can stand in for each other (the
    narrow view's ambiguity), and the few tracks that slide on the paving's lines tip the count:
    past the rendered zoom in a dolly 21 deg off the axis with a pan of 3.3 deg/s explained 99 of
    100 points (94 along the axis with no pan) and read a dolly-zoom; past the pedestal a tilt of
    4 deg/s and a roll of -5 took up the rise; past the dolly-zoom out a truck with a pan
    explained 136 of 141 points, the dolly 127-129. The camera's own move is the one that needs
    the least rotation. Never a truck's mirror, though (`mirrors_truck`)."""
    counts = np.array([_count_in_front(flow, basis, r, t, _lines(mid, t, f), inlier_px) for r, t, _ in fits])
    best = fits[int(np.argmax(counts))][1]
    close = [i for i in np.flatnonzero(counts >= counts.max() - ROTATION_TIE * len(mid))
             if not mirrors_truck(fits[i][1], best)]
    return fits[int(min(close, key=lambda i: float(np.linalg.norm(fits[i][0]))))]


def mirrors_truck(t: np.ndarray, best: np.ndarray) -> bool:
    """Whether direction `t` goes against `best`, both off the optical axis (trucks or pedestals):
    the same flow read with the depths turned round, the far points near. A dolly against a truck
    is no mirror (past the dolly-zoom out it is the move).

    Where every point moves one way (an orbit: its pan outruns the truck's parallax on every point),
    a truck the other way with a smaller pan also puts every point in front: past the flown
    orbit_right the alternation from the optical axis settled there (0.91, -0.04, 0.41) with a
    rotation of 0.28 where the truck (-0.99, -0.01, 0.12) needed 1.69 deg over the baseline,
    explaining 124 of 130 points against 129; taken on 5 frames, the rows' mean direction
    cancelled and rows 17-23 read pan."""
    return max(abs(float(best[2])), abs(float(t[2]))) < DOLLY_AXIS and float(np.dot(t, best)) < 0.0


def _in_front_of_lines(inliers: np.ndarray, along: np.ndarray, t_z: np.ndarray, inlier_px: float) -> np.ndarray:
    """Of the points within inlier_px of their translation lines `inliers` (..., N), how many (...)
    have a depth in front of the camera (`_behind_camera`).

    Only off the optical axis (|t_z| < DOLLY_AXIS, (...)): past a truck and a pan the other way most
    points fit a truck the other way with a faster pan, but 38-49 % of them behind the camera
    (the rendered truck right: frame to frame it flipped between the two); a dolly-zoom's points fit
    the dolly's lines both ways (its zoom against the dolly, which this fit does not model, scales
    the far points the wrong way), so there every inlier counts."""
    return (inliers & ~_behind_camera(inliers, along, t_z, inlier_px)).sum(axis=-1)


def _behind_camera(inliers: np.ndarray, along: np.ndarray, t_z: np.ndarray, inlier_px: float) -> np.ndarray:
    """(..., N) the inliers whose depth is behind the camera, the direction's sign chosen as most of
    them ask: those whose residual along the line `along` (..., N) [px, positive: a positive depth for
    +t] is more than inlier_px the minority's way (one within it could be far away either way); none
    near the optical axis (|t_z| >= DOLLY_AXIS, (...), see `_in_front_of_lines`)."""
    minority = -_depth_side(inliers, along, inlier_px)[..., None]  # the side whose points are behind
    off_axis = (np.abs(np.asarray(t_z)) < DOLLY_AXIS)[..., None]
    return inliers & (along * minority > inlier_px) & off_axis


def _depth_side(inliers: np.ndarray, along: np.ndarray, inlier_px: float) -> np.ndarray:
    """(...) +1 where at least as many of the inliers (..., N) lie more than inlier_px along their lines
    `along` (..., N) the positive-depth way as the other (a tie counts as in front), else -1."""
    front = (inliers & (along > inlier_px)).sum(axis=-1)
    back = (inliers & (along < -inlier_px)).sum(axis=-1)
    return np.where(front >= back, 1.0, -1.0)


def _signed_direction(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, f: float, t: np.ndarray,
                      inlier_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rotation (3,), the direction t signed as most of its points' depths ask, and its inliers (N,):
    one of the search's _DIRECTIONS (all with t_z >= 0), with its own rotation (`_direction_fits`)."""
    rot, perp, along = _direction_fits(mid, flow, basis, f, inlier_px, t[None])
    inl = perp[0] < inlier_px
    return rot[0], t * _depth_side(inl, along[0], inlier_px), inl


#: polish_direction's first step [rad] and how many times it is halved
POLISH_STEP, POLISH_HALVINGS = 0.08, 4


def polish_direction(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray,
                     inliers: np.ndarray, inlier_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rotation (3,), direction (3,) and inliers (N,) of the alternation's result moved to the
    nearby direction that fits the points best: a pattern search round t (8 directions POLISH_STEP
    away, the step halved POLISH_HALVINGS times once t is the best), each direction with its own
    rotation (`_direction_fits`), scored by the points' distances to their lines capped at
    inlier_px (an outlier or a point behind the camera, `_in_front_of_lines`, counts as the cap).
    Only off the optical axis and never into the dolly's cone (|t_z| < DOLLY_AXIS): a dolly's
    direction is judged by the checks on a dolly (`ground_denies_dolly`, `sliding_tracks`), and
    polished out of the cone the rendered zoom out read a dolly-zoom on 17 rows.

    The alternation minimises an algebraic error, not the points' distances: past the rendered
    truck right it settled 8 deg off the truck, tilted down and forward, with a pan of 2-5 deg/s,
    a tilt and a roll that the direction's tilt takes up (the truck itself with no rotation fits
    the points as well or better), and the rows read orbit. Kept only when it explains at least
    as many points: it moves the direction, never decides whether there is one."""
    t_best, step = np.asarray(t, dtype=float), POLISH_STEP
    if abs(t_best[2]) >= DOLLY_AXIS:
        return rot, t, inliers
    cost_best = _capped_cost(*_direction_fits(mid, flow, basis, f, inlier_px, t_best[None])[1:], t_best[None],
                             inlier_px)[0]
    for _ in range(POLISH_HALVINGS + 1):
        while True:
            cand = _ring(t_best, step)
            cost = _capped_cost(*_direction_fits(mid, flow, basis, f, inlier_px, cand)[1:], cand, inlier_px)
            cost[np.abs(cand[:, 2]) >= DOLLY_AXIS] = np.inf  # into the dolly's cone: the dolly's checks judge that
            k = int(np.argmin(cost))
            if cost[k] >= cost_best - 1e-9:
                break
            t_best, cost_best = cand[k], cost[k]
        step *= 0.5
    r_new, perp, _ = _direction_fits(mid, flow, basis, f, inlier_px, t_best[None])
    inl_new = perp[0] < inlier_px
    if inl_new.sum() < inliers.sum():
        return rot, t, inliers
    return r_new[0], t_best, inl_new


def _ring(t: np.ndarray, angle: float, n: int = 8) -> np.ndarray:
    """n unit directions (n, 3) `angle` [rad] from the unit t, evenly round it."""
    e1 = np.cross(t, [0.0, 1.0, 0.0] if abs(t[1]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t, e1)
    phi = 2.0 * math.pi * np.arange(n) / n
    side = np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2
    return math.cos(angle) * t[None] + math.sin(angle) * side


def _capped_cost(perp: np.ndarray, along: np.ndarray, t: np.ndarray, inlier_px: float) -> np.ndarray:
    """Each direction's (K,) sum of its points' squared distances to their lines `perp` (K, N),
    capped at inlier_px; a point behind the camera (`_in_front_of_lines`, by `along`) at the cap."""
    inl = perp < inlier_px
    behind = _behind_camera(inl, along, t[:, 2], inlier_px)
    return np.where(inl & ~behind, perp * perp, inlier_px * inlier_px).sum(axis=1)


def _count_in_front(flow: np.ndarray, basis: np.ndarray, rot: np.ndarray, t: np.ndarray,
                    lines: tuple[np.ndarray, np.ndarray], inlier_px: float) -> int:
    """The points that the rotation `rot` and direction t explain (`_in_front_of_lines`), from the
    points' flows, rotation basis (N, 2, 3) and translation lines `_lines`."""
    d, norm_d = lines
    r = flow - basis @ rot
    inl = np.abs(r[:, 0] * d[:, 1] - r[:, 1] * d[:, 0]) / norm_d < inlier_px
    along = np.einsum("nk,nk->n", r, d) / norm_d
    return int(_in_front_of_lines(inl, along, np.asarray(t[2]), inlier_px))


def _search_scores(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, f: float, inlier_px: float) -> np.ndarray:
    """For each of _DIRECTIONS the points (K,) within inlier_px of it with its own rotation
    (rotation_given_direction over all the points, trimmed as there) and in front of the camera
    (`_in_front_of_lines`): all directions at once, `_direction_fits`."""
    _, perp, along = _direction_fits(mid, flow, basis, f, inlier_px, _DIRECTION_ARRAY)
    return _in_front_of_lines(perp < inlier_px, along, _DIRECTION_ARRAY[:, 2], inlier_px)


def _direction_fits(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, f: float, inlier_px: float,
                    t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each direction of t (K, 3) its rotation (K, 3) (rotation_given_direction over all the
    points, trimmed as there) and each point's residual flow across (K, N) and along (K, N) its
    translation line [px]: all directions at once, each least squares by an SVD of its rows (those
    off its trim zeroed)."""
    d = np.stack([mid[None, :, 0] * t[:, 2:3] - f * t[:, 0:1], mid[None, :, 1] * t[:, 2:3] - f * t[:, 1:2]], axis=2)
    a = basis[None, :, 0, :] * d[..., 1:2] - basis[None, :, 1, :] * d[..., 0:1]  # (K, N, 3)
    b = flow[None, :, 0] * d[..., 1] - flow[None, :, 1] * d[..., 0]  # (K, N)
    norm_d = np.maximum(np.linalg.norm(d, axis=2), 1e-9)

    def residual(rot: np.ndarray) -> np.ndarray:  # the flow off each direction's rotation (K, N, 2)
        return flow[None] - np.einsum("nkj,hj->hnk", basis, rot)

    def perpendicular(rot: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:  # _perpendicular, (K, N)
        r = residual(rot) if r is None else r
        return np.abs(r[..., 0] * d[..., 1] - r[..., 1] * d[..., 0]) / norm_d

    use = np.ones(b.shape, dtype=bool)
    rot = _masked_lstsq(a, b, use)
    live = np.ones(len(t), dtype=bool)
    for _ in range(TRIM_ROUNDS):
        keep = use & (perpendicular(rot) < TRIM_FACTOR * inlier_px)
        live &= keep.sum(axis=1) >= MIN_POINTS  # a direction with too few kept stops refitting
        if not live.any():
            break
        rot[live] = _masked_lstsq(a[live], b[live], keep[live])
    r = residual(rot)  # once for both distances (the einsum over every direction and point is the cost)
    return rot, perpendicular(rot, r), np.einsum("hnk,hnk->hn", r, d) / norm_d


def _masked_lstsq(a: np.ndarray, b: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Least squares x (K, 3) of each a[k][use[k]] x = b[k][use[k]] (a (K, N, 3), b and use (K, N)):
    the rows left out zeroed, the minimum-norm solution by SVD as numpy's lstsq (its cut-off on the
    singular values included)."""
    w = use.astype(float)
    u, s, vt = np.linalg.svd(a * w[..., None], full_matrices=False)
    cut = np.finfo(float).eps * np.maximum(use.sum(axis=1), a.shape[2])[:, None] * s[:, :1]
    inv = np.where(s > cut, 1.0 / np.where(s > 0, s, 1.0), 0.0)
    return np.einsum("hji,hj->hi", vt, inv * np.einsum("hnj,hn->hj", u, b * w))


def _alternate(p0: np.ndarray, p1: np.ndarray, f: float, t: np.ndarray, inlier_px: float,
               iters: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """fit_rotation_translation's alternation from the direction t: rotation (3,), direction (3,) and
    inliers (N,)."""
    mid = 0.5 * (p0 + p1)
    return _alternate_on(mid, p1 - p0, rotation_zoom_basis(mid, f)[:, :, :3], f, t, inlier_px, iters)


def _alternate_on(mid: np.ndarray, flow: np.ndarray, basis: np.ndarray, f: float, t: np.ndarray, inlier_px: float,
                  iters: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """_alternate over the points' midpoints, flows and rotation basis (N, 2, 3), computed once per fit."""
    use = np.ones(len(mid), dtype=bool)
    rot = np.zeros(3)
    for i in range(iters):
        if i:
            t = _translation_dir(mid[use], flow[use] - basis[use] @ rot, f)
        lines = _lines(mid, t, f)
        rot = _rotation_on_lines(flow, basis, lines, use, inlier_px)
        if i >= 1:  # trim once the model has settled a little
            keep = _off_lines(flow, basis, rot, *lines) < 3.0 * inlier_px
            use = keep if keep.sum() >= MIN_POINTS else use
    return rot, t, _off_lines(flow, basis, rot, *lines) < inlier_px


def frame_motion(p0: np.ndarray, p1: np.ndarray, f: float, *, inlier_px: float = INLIER_PX,
                 earlier: np.ndarray | None = None, span: int = 1, normals: np.ndarray | None = None,
                 lines: np.ndarray | None = None) -> FrameMotion:
    """The camera's motion between two frames from background points p0 -> p1 (N, 2, centred px,
    at the resolution whose focal length is `f` px). A translation is reported only when parallax
    shows it: rotation + zoom leaves much unexplained and rotation + translation explains it.

    `earlier` (N, 2): the same points `span` frames before p1, NaN where a point was not tracked
    that long. Parallax grows with the baseline while the tracking noise hardly does, so the test
    for a translation (and its direction) runs on earlier -> p1 over the points tracked that long
    when span >= MIN_SPAN; the per-frame rotation then comes from p0 -> p1 given it.

    `normals` (N, 2): the unit normal of each track that lies on an edge, zeros for a corner. An
    edge track that slides along its edge over the baseline (`sliding_edges`: it stands out of the
    corners beside it) keeps only the motion across it, so rotation + zoom (its fit and the share it
    explains), the checks on a dolly and the dolly-zoom's zoom use only that of it (project_normal),
    and the translation's direction and rotation are fitted in 2-D without it (its slide would read
    as parallax, and across its edge any depth fits it). Every other edge track
    counts in 2-D, as a corner; without a baseline all do (no slide can be told). With fewer than
    MIN_POINTS corners they are all taken as corners.

    `lines` (N,): True for the tracks on a line (a looser edge test than `normals`'); they are left
    out of the frame's rotation given a dolly (`rotation_off_lines`; beside a truck they hold its
    weakly seen pan)."""
    p0, p1 = np.asarray(p0, dtype=float).reshape(-1, 2), np.asarray(p1, dtype=float).reshape(-1, 2)
    fin = np.isfinite(p0).all(axis=1) & np.isfinite(p1).all(axis=1)
    if earlier is not None:
        earlier = np.asarray(earlier, dtype=float).reshape(-1, 2)[fin]
    p0, p1 = p0[fin], p1[fin]
    n = len(p0)
    if n < MIN_POINTS:
        return FrameMotion.unknown(n)
    if normals is not None:
        normals = np.nan_to_num(np.asarray(normals, dtype=float).reshape(-1, 2)[fin])
        normals = None if (~edge_tracks(normals, n)).sum() < MIN_POINTS else normals
    on_line = np.zeros(n, dtype=bool) if lines is None else np.asarray(lines, dtype=bool).reshape(-1)[fin]
    try:
        return _fit_frame(p0, p1, f, inlier_px, earlier, span, normals, on_line)
    except np.linalg.LinAlgError:  # degenerate points (all on a line, ...): the frame's motion is unknown
        return FrameMotion.unknown(n)


def _fit_frame(p0: np.ndarray, p1: np.ndarray, f: float, inlier_px: float, earlier: np.ndarray | None,
               span: int, normals: np.ndarray | None, on_line: np.ndarray) -> FrameMotion:
    """frame_motion on finite points (`on_line` (N,): its `lines`)."""
    n = len(p0)
    sel = np.ones(n, dtype=bool)
    if earlier is not None and span >= MIN_SPAN:
        sel = np.isfinite(np.asarray(earlier, dtype=float).reshape(-1, 2)).all(axis=1)
    long = bool(earlier is not None and span >= MIN_SPAN and sel.sum() >= MIN_BASELINE_POINTS)
    k = span if long else 1
    a = np.asarray(earlier, dtype=float).reshape(-1, 2)[sel] if long else p0
    b, b0 = (p1[sel], p0[sel]) if long else (p1, p0)
    tol = inlier_px * LONG_INLIER_FACTOR if long else inlier_px
    normals = _sliding_normals(a, b, f, normals, sel, tol) if long and normals is not None else None
    nb = normals[sel] if normals is not None else None
    q, inl = fit_rotation_zoom(p0, p1, f, inlier_px=inlier_px, normals=normals)
    explained = float(inl.mean())
    share = explained_share(a, b, f, q * k, inlier_px=tol, normals=nb) if long else explained
    if share < EXPLAINED_SHARE:
        # the direction and rotation are fitted on the tracks in 2-D, without those that slide: given
        # an edge track only across its edge, its depth takes up all of it and it tells nothing, and
        # in 2-D its slide reads as parallax (docs/camera_motion.md)
        told = ~edge_tracks(nb, len(a))
        told = told if told.sum() >= MIN_POINTS else np.ones(len(a), dtype=bool)
        needed = parallax_share_needed(share)
        rot, t, inl_k = fit_rotation_translation(a[told], b[told], f, q[:3] * k, inlier_px=tol, shown=needed)
        inl_t = np.zeros(len(a), dtype=bool)
        inl_t[told] = inl_k
        moved = float(inl_k.mean())
        shown = moved >= needed
        if shown and ground_denies_dolly(a, b, f, rot, t, inl_t, nb) \
                and ground_backs_mirror(a, b, f, rot, -t, inl_t, nb):
            t = -t  # a dolly-zoom whose zoom outweighs the dolly on every point (ground_backs_mirror)
        if shown and not ground_denies_dolly(a, b, f, rot, t, inl_t, nb) \
                and not sliding_tracks(a, b, f, rot, t, inl_t, tol, nb):
            # the baseline's own rotation judges its points (a swaying camera's last frame times the
            # span mispredicts them by pixels); the frame's rotation comes from its two frames given t
            t = dolly_sign(a, b, f, rot, t, inl_t, nb)
            zoom = zoom_against_dolly(a, b, f, rot, t, inl_t, inlier_px=tol, normals=nb) / k
            on = rotation_off_lines(inl_t, on_line[sel]) if abs(t[2]) >= DOLLY_AXIS else inl_t
            rot = rotation_given_direction(b0, b, f, t, on, inlier_px=inlier_px) if long else rot
            return FrameMotion(rot, zoom, t, n, explained)
    return FrameMotion(q[:3].copy(), float(q[3]), np.zeros(3), n, explained)


def rotation_off_lines(use: np.ndarray, on_line: np.ndarray) -> np.ndarray:
    """The points `use` (N,) less those `on_line` (N,) that a frame's rotation given a dolly is
    fitted on; all of `use` when fewer than MIN_POINTS are left.

    Given the direction, the rotation is set by each point's flow across its translation line. A
    track on a line of the paving slides along it by a fraction of a pixel a frame, below what the
    sliding test sees (the tracks beside it slide too), and under a dolly that slide crosses the
    translation's lines with the sign of the travel: on the rendered dollies it read as a pan of
    0.3 deg/s the camera never made."""
    kept = use & ~on_line
    return kept if kept.sum() >= MIN_POINTS else use


def _sliding_normals(a: np.ndarray, b: np.ndarray, f: float, normals: np.ndarray, sel: np.ndarray,
                     tol: float) -> np.ndarray | None:
    """The normals (N, 2) of the edge tracks that slide over the baseline a -> b (the points `sel`),
    zeros for every other track (judged in 2-D as a corner); None when none slides. A track that
    follows its texture keeps the motion along its edge, which a dolly's parallax over a paving
    mostly is (judged across the edge only, dolly_out's output read zoom_out on every row)."""
    slide = np.zeros(len(normals), dtype=bool)
    slide[np.flatnonzero(sel)] = sliding_edges(a, b, f, normals[sel], inlier_px=tol)
    return np.where(slide[:, None], normals, 0.0) if slide.any() else None


def _radial_scales(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray,
                   use: np.ndarray, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each point's scale rate along its radial line once the rotation is taken out (M,), and the
    midpoints (M, 2) it was read at: the points `use` away from the centre (there a scale is lost in
    the noise). An edge track's scale is read across its edge, (n . r) / (n . p), where its normal
    lies within 60 deg of the radial line (`normals`, see project_normal)."""
    mid = 0.5 * (p0 + p1)
    resid = project_normal((p1 - p0) - rotation_zoom_basis(mid, f)[:, :, :3] @ rot, normals)
    r2 = np.einsum("nk,nk->n", mid, mid)
    seen = np.einsum("nk,nk->n", mid, project_normal(mid, normals))  # m . P m: r2 for a corner
    ok = use & (seen > (0.1 * f) ** 2) & (seen >= 0.25 * r2)
    return np.einsum("nk,nk->n", resid[ok], mid[ok]) / seen[ok], mid[ok]


def _dolly_scales(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray,
                  use: np.ndarray, normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, bool] | None:
    """The radial scales of a dolly's points, their image positions and whether they scale both ways
    (a zoom against the dolly: FAR_SHARE's percentiles either side of 0); None when t is no dolly
    or too few points are seen."""
    if abs(t[2]) < DOLLY_AXIS or use.sum() < MIN_POINTS:
        return None
    scale, mid = _radial_scales(p0, p1, f, rot, use, normals)
    if len(scale) < MIN_POINTS:
        return None
    lo, hi = np.percentile(scale, [100.0 * FAR_SHARE, 100.0 * (1.0 - FAR_SHARE)])
    return scale, mid, bool(lo < 0.0 < hi)


def dolly_sign(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray,
               use: np.ndarray, normals: np.ndarray | None = None) -> np.ndarray:
    """The translation t (3,) with the sign of a dolly-zoom that its points alone cannot tell.

    Past a dolly with a zoom against it some points grow and some shrink, and two moves fit every
    point with a positive depth: in while zooming out (the zoom is the least scale, of the farthest
    points) and out while zooming in (the zoom is the greatest). The direction fit takes the sign
    most points agree with, which flips from frame to frame as the scene's depths go by (the
    smoother's mean direction then cancels out). The ground decides: the lower a point in the
    image, the nearer it is (a camera above the ground looking about level), and the nearer a
    point, the more a dolly makes it scale its way (grow going in). Any other translation, and a
    dolly whose points all scale the same way, keeps its sign."""
    seen = _dolly_scales(p0, p1, f, rot, t, use, normals)
    if seen is None or not seen[2]:
        return t
    scale, mid, _ = seen
    lower_grows = float(np.corrcoef(mid[:, 1], scale)[0, 1])
    return -t if math.isfinite(lower_grows) and lower_grows * t[2] < 0.0 else t


def ground_denies_dolly(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray,
                        use: np.ndarray, normals: np.ndarray | None = None) -> bool:
    """True when a dolly along t whose points all scale one way puts the ground beyond the walls:
    the lower points scale less its way (correlation below -GROUND_DENIES), as no camera above
    the ground looking about level sees. A zoom reads so where some tracks slide over a repeating
    texture (the paving under a zoom out: their drift over the baseline looks like parallax, the
    translation fit gives them depths, and they come out the farthest). A dolly-zoom, whose points
    scale both ways, is dolly_sign's to judge."""
    seen = _dolly_scales(p0, p1, f, rot, t, use, normals)
    if seen is None or seen[2]:
        return False
    scale, mid, _ = seen
    lower_grows = float(np.corrcoef(mid[:, 1], scale * np.sign(t[2]))[0, 1])
    return math.isfinite(lower_grows) and lower_grows < -GROUND_DENIES


def ground_backs_mirror(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray,
                        use: np.ndarray, normals: np.ndarray | None = None) -> bool:
    """True when the ground below the focus of expansion backs a dolly along t (the mirror of one that
    `ground_denies_dolly` denied): there the lower (nearer) points scale more t's way, with a
    correlation of image row and scale of at least GROUND_BACKS. A dolly-zoom whose zoom outweighs
    the dolly on every point (the output's dolly-zoom in setting off: all points shrink, the nearer
    less) reads to the translation fit as a dolly the zoom's way, which the ground denies; the
    paving's lower points grew against it with a correlation of +0.81 to +0.95. Under a zoom out
    the ground's tracks that slide deny the dolly out too, but below the horizon they show no
    parallax (-0.34 to -0.59): that is a zoom, and stays one."""
    seen = _dolly_scales(p0, p1, f, rot, t, use, normals)
    if seen is None:
        return False
    scale, mid, _ = seen
    below = mid[:, 1] > f * t[1] / t[2] + 0.05 * f
    if below.sum() < MIN_POINTS:
        return False
    nearer_grows = float(np.corrcoef(mid[below, 1], scale[below] * np.sign(t[2]))[0, 1])
    return math.isfinite(nearer_grows) and nearer_grows >= GROUND_BACKS


def sliding_tracks(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray, use: np.ndarray,
                   inlier_px: float, normals: np.ndarray | None = None) -> bool:
    """True when what a dolly along t explains beyond rotation is tracks sliding by themselves: its
    parallax points (those of `use` that the rotation leaves more than inlier_px off) lie to one side
    of the focus of expansion and many would be behind the camera. Under a tilt over the paving, a
    cluster of tracks at the lower left slid along the tiles' lines (5-8 px over 8 frames, all to
    the right); a dolly out whose focus of expansion sits beside them explains them, with 62-93 %
    of them in front of the camera (the tilt read tilt+dolly_out on 14 of 48 rows). A dolly's
    parallax surrounds its focus of expansion or puts all its points in front (the rendered dollies
    96-100 %); a dolly-zoom scales points both ways, but all round it."""
    if abs(t[2]) < DOLLY_AXIS:
        return False
    mid = 0.5 * (p0 + p1)
    resid = project_normal((p1 - p0) - rotation_zoom_basis(mid, f)[:, :, :3] @ rot, normals)
    big = use & (np.linalg.norm(resid, axis=1) > inlier_px)
    if big.sum() < MIN_POINTS:
        return False
    d = mid[big] * t[2] - f * t[:2]  # each point's line from the focus of expansion, along t's motion
    in_front = float((np.einsum("nk,nk->n", resid[big], d) > 0.0).mean())
    side = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
    return float(np.linalg.norm(side.mean(axis=0))) >= ONE_SIDED and in_front < IN_FRONT


def zoom_against_dolly(p0: np.ndarray, p1: np.ndarray, f: float, rot: np.ndarray, t: np.ndarray,
                       use: np.ndarray, *, inlier_px: float = INLIER_PX, normals: np.ndarray | None = None) -> float:
    """The log-zoom p0 -> p1 that a dolly along t cannot explain (0 when none is seen).

    Past a dolly each point's image scales at t_z / depth plus the zoom, so a zoom the same way
    as the dolly is the dolly to any point at a finite depth: it is not reported. One the other way
    (the dolly-zoom: in while zooming out) makes the far points shrink as no depth can. A point at
    depth d_b scales at s (1 - d_s / d_b) when the zoom s holds a subject at d_s, so the farthest
    points (the FAR_SHARE with the least scale along the dolly) give only part of it (0.64 s for a
    wall 25 m behind a subject 9 m away); the ground gives all of it where it is seen
    (`zoom_at_horizon`, the camera taken to move parallel to it, so that the horizon is the focus
    of expansion's row), never less than the farthest points show."""
    if abs(t[2]) < DOLLY_AXIS or use.sum() < MIN_POINTS:
        return 0.0
    scale = _radial_scales(p0, p1, f, rot, use, normals)[0] * np.sign(t[2])
    if len(scale) < MIN_POINTS:
        return 0.0
    far = float(np.percentile(scale, 100.0 * FAR_SHARE))
    if far >= 0.0:
        return 0.0
    mid = 0.5 * (p0 + p1)[use]
    resid = ((p1 - p0) - rotation_zoom_basis(0.5 * (p0 + p1), f)[:, :, :3] @ rot)[use]
    ground = zoom_at_horizon(mid, resid * np.sign(t[2]), f * t[:2] / t[2], f, inlier_px=inlier_px,
                             normals=None if normals is None else normals[use])
    return (min(ground, far) if math.isfinite(ground) else far) * float(np.sign(t[2]))


def zoom_at_horizon(mid: np.ndarray, resid: np.ndarray, foe: np.ndarray, f: float, *, inlier_px: float,
                    iters: int = 200, normals: np.ndarray | None = None) -> float:
    """The zoom s (per the points' time step) of a camera moving parallel to flat ground, from the
    points' flow with the rotation taken out `resid` (N, 2) at `mid` (N, 2, centred px), flow signed
    so that the translation makes points grow, and the focus of expansion `foe` (2,); NaN when no
    ground is seen.

    Each point moves by s p + w (p - e), w = t_z / depth. The camera moving parallel to the ground,
    the horizon is the row of e, and on the ground w = beta (y - e_y) (its inverse depth grows
    linearly with the row below the horizon): along u = (p - e) / |p - e| the flow is
    s (p . u) + beta (y - e_y) |p - e|, across u it is s (p x u), both linear in (s, beta).
    Anything seen below the horizon is at most as far as the ground behind it, so the ground is the
    lower envelope of the points below the horizon: RANSAC over point pairs scores a line by the
    points that fit it both ways less twice those that fit across it and lie clearly under it,
    then least squares on its inliers. An edge track (`normals`, see project_normal) gives one
    equation, its flow across the edge, in place of the two, and always fits across."""
    e = np.asarray(foe, dtype=float)
    d = mid - e
    dist = np.linalg.norm(d, axis=1)
    below = (mid[:, 1] > e[1] + 0.05 * f) & (dist > 0.1 * f)
    if below.sum() < MIN_POINTS:
        return math.nan
    u = d[below] / dist[below, None]
    n = np.column_stack([-u[:, 1], u[:, 0]])
    p, r = mid[below], resid[below]
    m_along, m_across = np.einsum("nk,nk->n", r, u), np.einsum("nk,nk->n", r, n)
    a_along = np.column_stack([np.einsum("nk,nk->n", p, u), (p[:, 1] - e[1]) * dist[below]])
    a_across = np.column_stack([np.einsum("nk,nk->n", p, n), np.zeros(len(p))])
    if normals is not None:
        _edge_rows(np.asarray(normals, dtype=float)[below], u, p, r, a_along, m_along, a_across, m_across)
    pairs = np.random.default_rng(0).integers(0, len(p), size=(iters, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    ok = np.abs(np.linalg.det(a_along[pairs])) > 1e-9
    hyps = np.linalg.solve(a_along[pairs][ok], m_along[pairs][ok][..., None])[..., 0]
    hyps = hyps[hyps[:, 1] > 0.0]  # the ground comes nearer lower down
    if not len(hyps):
        return math.nan
    off_along = m_along[None] - hyps @ a_along.T
    fits_across = np.abs(m_across[None] - hyps @ a_across.T) < inlier_px
    score = ((np.abs(off_along) < inlier_px) & fits_across).sum(axis=1) \
        - 2 * ((off_along < -inlier_px) & fits_across).sum(axis=1)
    best = int(np.argmax(score))
    inl = (np.abs(off_along[best]) < inlier_px) & fits_across[best]
    if inl.sum() < MIN_POINTS:
        return math.nan
    s, beta = np.linalg.lstsq(np.vstack([a_along[inl], a_across[inl]]),
                              np.concatenate([m_along[inl], m_across[inl]]), rcond=None)[0]
    return float(s) if beta > 0.0 else math.nan


def _edge_rows(normals: np.ndarray, u: np.ndarray, p: np.ndarray, r: np.ndarray, a_along: np.ndarray,
               m_along: np.ndarray, a_across: np.ndarray, m_across: np.ndarray) -> None:
    """zoom_at_horizon's rows of the edge tracks, in place: the flow across the edge, its normal n
    turned to u's side, s (n . p) + beta (y - e_y) |p - e| (n . u) = n . r as the along row (the
    ground's part along u scaled by n . u), and a row of zeros across."""
    edge = edge_tracks(normals, len(u))
    if not edge.any():
        return
    n = normals[edge] * np.where(np.einsum("nk,nk->n", normals[edge], u[edge]) < 0.0, -1.0, 1.0)[:, None]
    nu = np.einsum("nk,nk->n", n, u[edge])
    a_along[edge] = np.column_stack([np.einsum("nk,nk->n", n, p[edge]), a_along[edge, 1] * nu])
    m_along[edge] = np.einsum("nk,nk->n", n, r[edge])
    a_across[edge], m_across[edge] = 0.0, 0.0


def rotation_given_direction(p0: np.ndarray, p1: np.ndarray, f: float, t: np.ndarray, use: np.ndarray, *,
                             inlier_px: float | None = None) -> np.ndarray:
    """Rotation (3,) [rad] moving p0 to p1 (N, 2) with translation direction t, each point's depth
    eliminated, over the points `use` (N,) (least squares): cross(flow - B rot, d) = 0 is linear in rot.

    With `inlier_px` the fit is repeated on the points within TRIM_FACTOR x inlier_px of it: the
    rotation along the translation's lines is weakly seen (a tilt beside a pedestal, a pan beside a
    truck), and the few tracks that drift across the lines would otherwise set it."""
    mid = 0.5 * (p0 + p1)
    return _rotation_on_lines(p1 - p0, rotation_zoom_basis(mid, f)[:, :, :3], _lines(mid, t, f), use, inlier_px)


def _rotation_on_lines(flow: np.ndarray, basis: np.ndarray, lines: tuple[np.ndarray, np.ndarray], use: np.ndarray,
                       inlier_px: float | None) -> np.ndarray:
    """rotation_given_direction from the points' flows, rotation basis (N, 2, 3) and translation lines `_lines`."""
    d = lines[0]
    a = basis[:, 0, :] * d[:, 1:2] - basis[:, 1, :] * d[:, 0:1]
    b = flow[:, 0] * d[:, 1] - flow[:, 1] * d[:, 0]
    use = use if use.sum() >= MIN_POINTS else np.ones(len(flow), dtype=bool)
    rot = np.linalg.lstsq(a[use], b[use], rcond=None)[0]
    for _ in range(TRIM_ROUNDS if inlier_px is not None else 0):
        keep = use & (_off_lines(flow, basis, rot, *lines) < TRIM_FACTOR * inlier_px)
        if keep.sum() < MIN_POINTS:
            break
        rot = np.linalg.lstsq(a[keep], b[keep], rcond=None)[0]
    return rot


def parallax_untested(m: FrameMotion) -> FrameMotion:
    """The motion of a frame whose parallax could not be tested (no baseline of MIN_SPAN frames yet:
    a shot's first frames, or just after the tracks were found afresh), its zoom and translation
    unknown: from one frame a dolly's parallax is within the tracking noise, so the rotation + zoom
    fit reads any dolly as a zoom (the output videos' dollies read zoom_in or zoom_out on their first
    rows), while the smoother fills unknown rows from the frames around them that were tested. A
    translation seen even so is kept."""
    if np.any(m.translation_dir):
        return m
    return FrameMotion(m.rotation_rad, math.nan, np.full(3, np.nan), m.points, m.explained)


def dolly_carried(m: FrameMotion, before: FrameMotion | None) -> FrameMotion:
    """The motion of a frame that reads a zoom with no translation, where the frame `before` it read
    a dolly the same way: that dolly, carried on (its direction, no zoom). Any other frame as it is.

    A zoom and a dolly past a flat background are the same image motion. Near the end of the
    rendered dolly in the walker, grown near, covers the paving, and what is left of the background
    is the far wall: rotation + zoom explains 93-97 % of the baseline's points (44-79 % before), no
    translation is tried, and the last six frames read a zoom in at 0.38-0.40 /s, the rate the
    frames before read as their dolly's apparent zoom (0.37-0.38 /s). A camera that was seen to
    dolly and shows no parallax any more is taken to go on dollying; a zoom the other way (the
    dolly-zoom's) is never carried over."""
    if before is None or np.any(m.translation_dir) or not math.isfinite(m.log_zoom) or m.log_zoom == 0.0:
        return m
    t = before.translation_dir
    if not np.isfinite(t).all() or abs(t[2]) < DOLLY_AXIS or np.sign(t[2]) != np.sign(m.log_zoom):
        return m
    return FrameMotion(m.rotation_rad, 0.0, t.copy(), m.points, m.explained)


# --------------------------------------------------------------------------- per shot
def smooth_rates(x: np.ndarray, window: int) -> np.ndarray:
    """Median then mean over a centred window of `window` rows (NaN ignored; NaN where the window
    holds nothing finite). Columns are smoothed independently."""
    a = np.asarray(x, dtype=float)
    flat = a.reshape(len(a), -1)
    out = np.full_like(flat, np.nan)
    h = max(int(window) // 2, 0)
    med = np.full_like(flat, np.nan)
    for k in range(len(flat)):
        w = flat[max(0, k - h):k + h + 1]
        fin = np.isfinite(w).any(axis=0)
        med[k, fin] = np.nanmedian(w[:, fin], axis=0)
    for k in range(len(flat)):
        w = med[max(0, k - h):k + h + 1]
        fin = np.isfinite(w).any(axis=0)
        out[k, fin] = np.nanmean(w[:, fin], axis=0)
    return out.reshape(a.shape)


def classify(pan_dps: float, tilt_dps: float, roll_dps: float, zoom_rate: float,
             translation_dir: np.ndarray | None = None) -> str:
    """The class of one set of rates: the moves present joined with "+" in the order of CLASSES,
    "static" when none is; "" when nothing is known (every rate NaN)."""
    rates = np.array([pan_dps, tilt_dps, roll_dps, zoom_rate], dtype=float)
    t = np.zeros(3) if translation_dir is None else np.nan_to_num(np.asarray(translation_dir, dtype=float))
    if not np.isfinite(rates).any():
        return ""
    r = np.nan_to_num(rates)
    moves = []
    trans = _translation_class(t)
    turn = ROTATION_BESIDE_TRANSLATION_DPS if trans else ROTATION_MIN_DPS
    if trans == "truck" and abs(r[0]) >= ROTATION_MIN_DPS and np.sign(r[0]) == np.sign(t[0]):
        trans = "orbit"  # moving right while turning left (or the reverse): round a centre ahead
    for name, on in (("pan", abs(r[0]) >= turn and trans != "orbit"),
                     ("tilt", abs(r[1]) >= turn), ("roll", abs(r[2]) >= ROTATION_MIN_DPS)):
        if on:
            moves.append(name)
    zoom = "zoom_in" if r[3] >= ZOOM_MIN_PER_S else "zoom_out" if r[3] <= -ZOOM_MIN_PER_S else ""
    if trans.startswith("dolly") and zoom and (trans == "dolly_in") == (zoom == "zoom_out"):
        trans, zoom = "dolly_zoom", ""
    moves += [m for m in (zoom, trans) if m]
    return "+".join(sorted(moves, key=CLASSES.index)) if moves else "static"


def _translation_class(t: np.ndarray) -> str:
    """'dolly_in', 'dolly_out', 'truck', 'pedestal' for the main axis of a translation, '' for none."""
    if not np.any(t):
        return ""
    i = int(np.argmax(np.abs(t)))
    return ("truck", "pedestal", "dolly_in" if t[2] > 0 else "dolly_out")[i]


def components(cls: str) -> set[str]:
    """The moves of a class ("pan+tilt" -> {"pan", "tilt"})."""
    return set(cls.split("+")) if cls else set()


# --------------------------------------------------------------------------- from poses
def rates_from_poses(ypr_rad: np.ndarray, focal_mm: np.ndarray, fps: float) -> dict[str, np.ndarray]:
    """Pan, tilt, roll rates [deg/s] and zoom rate [1/s] per frame (K,) from the camera's attitude
    (K, 3) yaw, pitch, roll [rad] (shared/camera.py) and focal length (K,) [mm] per frame: the
    relative rotation between consecutive frames, in the camera's own axes (first row NaN)."""
    from cinetransfer.shared.camera import rotation_ypr

    ypr = np.asarray(ypr_rad, dtype=float)
    k = len(ypr)
    out = {n: np.full(k, np.nan) for n in ("pan_rate_dps", "tilt_rate_dps", "roll_rate_dps", "zoom_rate")}
    for i in range(1, k):
        if not (np.isfinite(ypr[i]).all() and np.isfinite(ypr[i - 1]).all()):
            continue
        rel = rotation_ypr(*ypr[i - 1]).T @ rotation_ypr(*ypr[i])  # camera i in camera i-1's (fwd, left, up) axes
        w = _rotvec(rel) * fps
        # shared/camera.py's camera axes are x forward, y left, z up: pan = about up, tilt = about
        # -left (pitch up is positive), roll = about forward, clockwise as the camera sees it
        out["pan_rate_dps"][i], out["tilt_rate_dps"][i] = math.degrees(w[2]), math.degrees(-w[1])
        out["roll_rate_dps"][i] = math.degrees(w[0])
    f = np.asarray(focal_mm, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out["zoom_rate"][1:] = np.log(f[1:] / f[:-1]) * fps
    return out


def translation_from_velocity(velocity_w: np.ndarray, ypr_rad: np.ndarray, distance_m: float) -> np.ndarray:
    """Unit translation direction (3,) in the camera frame (x right, y down, z forward) of a camera
    moving at `velocity_w` (world, m/s) with attitude `ypr_rad`; zeros when the move is too slow to
    show against a scene `distance_m` away (|v| / distance below ZOOM_MIN_PER_S: a dolly that
    changes the subject's size less than the least zoom that counts); NaN when unknown."""
    from cinetransfer.shared.camera import rotation_ypr

    v, ypr = np.asarray(velocity_w, dtype=float), np.asarray(ypr_rad, dtype=float)
    if not (np.isfinite(v).all() and np.isfinite(ypr).all() and math.isfinite(distance_m) and distance_m > 0):
        return np.full(3, np.nan)
    fwd, left, up = rotation_ypr(*ypr).T @ v  # camera axes of shared/camera.py: forward, left, up
    t = np.array([-left, -up, fwd])
    speed = float(np.linalg.norm(t))
    return t / speed if speed / distance_m >= ZOOM_MIN_PER_S else np.zeros(3)


def _rotvec(r: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) [rad] of a rotation matrix (small or moderate angles)."""
    c = max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0))
    ang = math.acos(c)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return v * (0.5 if ang < 1e-9 else ang / (2.0 * math.sin(ang)))
