"""What the style asks of the camera's own motion, per stage of the horizon (pure numpy).

The style carries per source frame a camera-motion class (static, pan, tilt, roll, zoom_in,
zoom_out, dolly_in, dolly_out, truck, pedestal, orbit, dolly_zoom; combinations joined with "+"),
the camera's angular rates (deg/s: pan positive to the camera's left, tilt positive up, roll
positive clockwise as the camera sees it), the zoom rate d ln f/dt (1/s) and the direction of
translation in the source camera's frame (x right, y down, z forward; zeros = none seen), NaN
where unknown. Instructions without these fields (older styles) ask nothing: every mask is 0.

A term is asked of a stage only where its row's class names the move and the rate is finite; a
static row asks the angular rates and the zoom rate to be 0 and the camera to stand still (the
source camera held still: the framing alone let the camera pan and zoom after a dancing subject,
79 % of a static source's rows flown as moves, and following a walker slid it into an orbit); rows
with no class (a style that carries rates only) use the rates that are clearly non-zero.
A dolly, truck or orbit row holds the lens as the source's held and asks the subject's distance to
change as in the source (the style gives the travel a direction only; left free, the lens took the
move); a truck or orbit row also asks the camera's bearing round the subject to turn at the source's rate.

Per-stage parameter layout (N_MOTION values), read by cost.StageBuilder:
    0-1   wanted horizontal bearing of the camera round the subject (unit vector), 2 its mask
    3-5   yaw, pitch, roll rate targets [rad/s], 6-8 their masks
    9     zoom rate target [1/s], 10 its mask
    11-13 direction of travel in the planner's camera frame (x forward, y left, z up), 14 its mask
    15    distance-rate mask, 16 the rate d ln(subject distance)/dt asked then: a dolly's or a dolly-zoom's,
          read from the source subject's size against its lens (subject_distance_rate); a handheld
          dolly-zoom's (or one whose subject is unseen) its zoom rate
    17    1 = the camera stands still (the velocity term's reference is 0 instead of the subject's
          velocity, and no sideways velocity): a static row, or one whose class turns or zooms the
          camera without moving it (pan, tilt, roll, zoom_in, zoom_out), where following a walking
          subject would undo the pan; or it travels along its axis only (a dolly, a dolly-zoom), where
          following him sideways read as a pan
    18    1 = it stands still along its optical axis too: a row whose class zooms in place (zoom_in,
          zoom_out without a translating class), where moving along the axis reads as a dolly-zoom
    19    bearing-rate mask, 20 the rate d(bearing of the camera round the subject)/dt asked then [rad/s,
          positive as the pan]: a truck's, read from the source's pan rate and the subject's
          drift across its image (subject_bearing_rate); an orbit's the same way
    21    the least speed of travel along the direction (11-13) asked, over the subject's distance [1/s]
          (0 = any): a dolly's or a dolly-zoom's, TRAVEL_MIN_RATE (the direction term's one-sided part); a
          pedestal's, the source's rate of turn of its elevation round the subject (pedestal_least_rate); a
          truck's or orbit's whose subject the source lost, the bearing rate it last read in the shot
          (swing_held_rate)
    22-23 ln of the least and the greatest focal length [mm] the lens may stand at, 24 their mask:
          room for the zoom still to come in the take (a dolly-zoom in zooms out by e^-0.27 over its
          2 s, and started at the source's 32.6 mm the lens hit its 30 mm end half-way through)
    25    1 = the source's subject is out of its frame on this row (no image target) while the row names a
          move: the look term does not turn the camera after him (it whipped dolly_in's camera round after
          the walker leaving the frame, 33-48 deg/s, and turned orbit_left's after him); not on a static
          row, whose rates and place are held already
    26    1 = the least speed (21) is the source's own measured speed (a pedestal's), not a floor: its
          shortfall weighs weights.travel_rate as well (at translation_dir's 5 alone the climb ran 10-25 %
          short of it, giving way to the framing)
    27    1 = the angular rates asked (3-8) also weigh weights.held_rate: a truck's or orbit's row whose source
          lost its subject (SWING_HELD_CLASSES), where its travel is asked in the camera's own frame and
          nothing framed holds the camera's heading: at motion_rate's 20 alone the camera kept turning to meet
          its velocity (truck_right's flight panned at -1.8 deg/s for its last ten rows, read pan+truck)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cinetransfer.shared.camera_motion import ASSUMED_HFOV_DEG, ZOOM_MIN_PER_S

N_MOTION = 28
SIDE, SIDE_MASK = slice(0, 2), 2
RATES, RATE_MASKS = slice(3, 6), slice(6, 9)
ZOOM, ZOOM_MASK = 9, 10
TRAVEL, TRAVEL_MASK = slice(11, 14), 14
DOLLY_ZOOM_MASK, DISTANCE_RATE, STILL, STILL_ALONG = 15, 16, 17, 18
BEARING_RATE_MASK, BEARING_RATE = 19, 20
TRAVEL_MIN = 21
LOG_FOCAL_FLOOR, LOG_FOCAL_CEILING, HEADROOM_MASK = 22, 23, 24
LOOK_OFF = 25
TRAVEL_MEASURED = 26
RATES_HELD = 27
#: the columns of the take's moves, which the pre-roll drops; the lens's headroom stays (it is set up there)
TAKE_COLUMNS = slice(0, LOG_FOCAL_FLOOR)
SIDE_PARAMS = slice(0, 3)  #: the side-of-subject parameters (bearing vector and mask), set by the planner core
FLOWN_RATE_COLUMNS = [ZOOM]  #: the lens's rate target, planned slower (core.flown_rate_factor)
#: the camera-motion terms' masks
MOTION_MASKS = [6, 7, 8, ZOOM_MASK, TRAVEL_MASK, DOLLY_ZOOM_MASK, STILL, STILL_ALONG, BEARING_RATE_MASK,
                HEADROOM_MASK, TRAVEL_MEASURED, RATES_HELD]

#: which classes ask for which term
RATE_CLASSES = (("pan", "orbit"), ("tilt",), ("roll",))
ZOOM_CLASSES = ("zoom_in", "zoom_out", "dolly_zoom")
TRAVEL_CLASSES = ("dolly_in", "dolly_out", "truck", "pedestal", "orbit", "dolly_zoom")
STILL_CLASSES = ("pan", "tilt", "roll", "zoom_in", "zoom_out")
STATIC = frozenset({"static"})  #: hold still: every angular rate and the zoom rate 0
#: with no class, a rate counts when at least this large (deg/s; 1/s for the zoom)
MIN_RATE_DPS, MIN_ZOOM_RATE = 1.0, 0.01
#: a dolly: flown with the lens held, at the source's rate of change of the subject's distance
DOLLY_CLASSES = ("dolly_in", "dolly_out")
#: the subject's size is read over this long a window for that rate [s] (the smoother's 0.5 s)
DISTANCE_WINDOW_S = 0.5
#: a truck or an orbit: flown at the source's rate of turn round the subject (subject_bearing_rate), with
#: the lens and the subject's distance as a dolly's (left free, the lens zoomed in after a walker leaving)
SWING_CLASSES = ("truck", "orbit")
#: ... unless the row also tilts or rolls: a handheld operator's sway (parkour's orbit rows all do), whose
#: lens serves the framing and the focus (held, parkour's soft runner read sharp: extraction 0.91 -> 0.86).
#: A truck keeps its bearing rate there, as before
HANDHELD_CLASSES = ("tilt", "roll")
#: a dolly or a dolly-zoom (not a truck, orbit or pedestal with it, nor handheld): the camera travels along its
#: axis and stands still sideways, with J_v's reference 0 (column 17), as a dolly on its rails
ALONG_AXIS_CLASSES = ("dolly_in", "dolly_out", "dolly_zoom")
#: ... and travels at least this fast over the subject's distance [1/s]: twice the rate from which the vocabulary
#: counts a translation (shared.camera_motion.ZOOM_MIN_PER_S). Asked the walker's distance rate alone, a dolly out
#: whose walker came towards it slowed to 0.4 m/s at 14 m, read static by the poses and zoom_out by the video
TRAVEL_MIN_RATE = 2.0 * ZOOM_MIN_PER_S
#: a pedestal (not handheld): the camera rises or sinks at the source's rate of turn of its elevation round the
#: subject (subject_elevation_rate) with the tilt held as the source's; left free, the framing tilted after the
#: walker sinking in the image and the pedestal was flown as a tilt
PEDESTAL_CLASSES = ("pedestal",)
#: the source's height over its width when the style does not say (the rendered sources' 16:9)
ASSUMED_ASPECT = 9.0 / 16.0
#: the lens's headroom is the zoom still to come times e^this (the style's rates are read, not exact)
HEADROOM_MARGIN = 0.05
#: ... and a side with no zoom to come is set this far (ln) outside the lens's range, where it never acts
UNUSED_SIDE = 1.0


@dataclass(frozen=True)
class MotionStyle:
    """The style's camera motion per instruction row (K rows)."""

    classes: list[frozenset[str] | None]  #: None = no class given for the row
    rates_radps: np.ndarray  #: (K, 3) yaw, pitch, roll rates, NaN = unknown
    zoom_rate: np.ndarray  #: (K,) d ln f / dt, NaN = unknown
    travel: np.ndarray  #: (K, 3) unit direction in the planner's camera frame, zeros = none
    #: (K,) d ln(subject distance)/dt of the source camera [1/s], NaN = unknown (subject_distance_rate)
    distance_rate: np.ndarray | None = None
    #: (K,) d(bearing of the source camera round the subject)/dt [rad/s], NaN = unknown (subject_bearing_rate)
    bearing_rate: np.ndarray | None = None
    #: (K, 2) ln of how far the lens still zooms out and in from each row to the end of the take (>= 0)
    zoom_to_come: np.ndarray | None = None
    #: (K,) d(elevation of the source camera round the subject)/dt [rad/s, positive rising], NaN = unknown
    elevation_rate: np.ndarray | None = None
    #: (K,) whether the source frames its subject on the row (any image target); None = not known
    subject_seen: np.ndarray | None = None
    #: (K,) the bearing rate [rad/s] last read in the row's shot, on rows that cannot read it; NaN elsewhere
    swing_held_rate: np.ndarray | None = None


def motion_classes(text: object) -> frozenset[str] | None:
    """The set of moves a class string names ("pan+zoom_in" -> {pan, zoom_in}); None if not a string."""
    if not isinstance(text, str) or not text.strip():
        return None
    return frozenset(p.strip().lower() for p in text.split("+") if p.strip())


def planner_camera_direction(d_source: np.ndarray) -> np.ndarray:
    """A direction in the source camera frame (x right, y down, z forward) in the planner's camera
    frame (x forward, y left, z up), unit length; zeros when it has none (or is not finite)."""
    d = np.asarray(d_source, dtype=float).reshape(3)
    out = np.array([d[2], -d[0], -d[1]])
    n = float(np.linalg.norm(out))
    return out / n if math.isfinite(n) and n > 1e-6 else np.zeros(3)


def _column(ins: object, name: str, k: int, width: int | None = None) -> np.ndarray:
    """A per-row field of the instructions as floats ((K,) or (K, width)); NaN when absent or malformed."""
    shape = (k,) if width is None else (k, width)
    v = getattr(ins, name, None)
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return np.full(shape, np.nan)
    return a if a.shape == shape else np.full(shape, np.nan)


def read_motion_style(ins: object) -> MotionStyle | None:
    """The camera-motion style of the instructions, or None when they carry none (older styles)."""
    k = int(np.asarray(getattr(ins, "image_targets")).shape[0])
    names = ("pan_rate_dps", "tilt_rate_dps", "roll_rate_dps", "zoom_rate", "translation_dir", "camera_motion_class")
    if all(getattr(ins, n, None) is None for n in names):
        return None
    rates = np.stack([_column(ins, n, k) for n in names[:3]], axis=1)
    rates = np.radians(rates)
    raw_cls = getattr(ins, "camera_motion_class", None)
    classes = [motion_classes(c) for c in raw_cls] if isinstance(raw_cls, (list, tuple, np.ndarray)) \
        and len(raw_cls) == k else [None] * k
    travel_src = _column(ins, "translation_dir", k, 3)
    travel = np.stack([planner_camera_direction(t) for t in travel_src]) if k else np.zeros((0, 3))
    zoom = _column(ins, "zoom_rate", k)
    box = _column(ins, "subject_box", k, 4)
    starts = getattr(ins, "shot_start", None)
    starts = np.asarray(starts, dtype=bool) if starts is not None and len(starts) == k else np.zeros(k, dtype=bool)
    fps = _rows_per_s(ins)
    distance = subject_distance_rate(box[:, 3] - box[:, 1], zoom, fps, starts) if fps > 0 else np.full(k, np.nan)
    bearing = subject_bearing_rate(0.5 * (box[:, 0] + box[:, 2]), rates[:, 0], fps, starts) if fps > 0 \
        else np.full(k, np.nan)
    elevation = subject_elevation_rate(0.5 * (box[:, 1] + box[:, 3]), rates[:, 1], fps, starts,
                                       aspect=_source_aspect(ins)) if fps > 0 else np.full(k, np.nan)
    asked = np.array([_zoom_asked(c, float(z)) for c, z in zip(classes, zoom)], dtype=bool)
    to_come = zoom_to_come(np.where(asked, zoom, 0.0), fps) if fps > 0 else np.zeros((k, 2))
    seen = np.isfinite(np.asarray(ins.image_targets, dtype=float)).all(axis=-1).reshape(k, -1).any(axis=1)
    held = np.where(np.isfinite(bearing), np.nan, last_read_in_shot(bearing, starts))
    return MotionStyle(classes, rates, zoom, travel, distance, bearing, to_come, elevation, seen, held)


def last_read_in_shot(values: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Per row the last finite value of `values` at or before it in its shot (NaN before the shot's first)."""
    out = np.full(len(values), np.nan)
    last = math.nan
    for k, v in enumerate(np.asarray(values, dtype=float)):
        if k == 0 or starts[k]:
            last = math.nan
        if math.isfinite(v):
            last = v
        out[k] = last
    return out


def _source_aspect(ins: object) -> float:
    """The source's height over its width (ASSUMED_ASPECT when unknown)."""
    src = getattr(ins, "source", None)
    w, h = float(getattr(src, "width", 0) or 0), float(getattr(src, "height", 0) or 0)
    return h / w if w > 0 and h > 0 else ASSUMED_ASPECT


def _window_slopes(values: np.ndarray, fps: float, starts: np.ndarray, window_s: float) -> np.ndarray:
    """Per row the least-squares slope (per s) of `values` over a centred window inside the row's shot;
    NaN where fewer than half the window is finite."""
    n = len(values)
    out = np.full(n, np.nan)
    half = max(1, int(round(0.5 * window_s * fps)))
    shot = np.cumsum(np.asarray(starts, dtype=bool) | (np.arange(n) == 0))
    for k in range(n):
        lo, hi = max(0, k - half), min(n, k + half + 1)
        idx = np.arange(lo, hi)
        idx = idx[(shot[idx] == shot[k]) & np.isfinite(values[idx])]
        if len(idx) < max(3, half + 1):
            continue
        t = (idx - idx.mean()) / fps
        out[k] = float(np.dot(t, values[idx] - values[idx].mean()) / np.dot(t, t))
    return out


def subject_bearing_rate(centre_x: np.ndarray, pan_rate_radps: np.ndarray, fps: float, starts: np.ndarray,
                         window_s: float = DISTANCE_WINDOW_S, hfov_deg: float = ASSUMED_HFOV_DEG) -> np.ndarray:
    """d(bearing of the source camera round the subject)/dt per row [rad/s, positive as the pan]: the
    subject lies at yaw + a from the camera, a = atan((0.5 - x) 2 tan(hfov/2)) his bearing off the
    optical axis (x his box's normalised centre; positive to the left), so the camera's bearing round
    him turns at the pan rate plus da/dt. A truck to the right with the rotation held turns it at
    v/d, an orbit at its own rate; the subject's walk is inside it, as in the dolly's rate. The slope
    of a is a line over the window inside the row's shot (the lens taken as the extraction's assumed
    one: these rows zoom not); NaN where the window is short or the pan rate unknown."""
    a = _angle_off_axis(centre_x, hfov_deg)
    return np.asarray(pan_rate_radps, dtype=float) + _window_slopes(a, fps, starts, window_s)


def _angle_off_axis(centre: np.ndarray, hfov_deg: float, aspect: float = 1.0) -> np.ndarray:
    """atan((0.5 - c) 2 tan(hfov/2) aspect) [rad]: the angle off the optical axis of a point at the
    normalised image coordinate c (positive left of or above the centre); `aspect` the image's height
    over its width for a vertical coordinate."""
    c = np.asarray(centre, dtype=float)
    return np.arctan((0.5 - c) * 2.0 * math.tan(math.radians(hfov_deg) / 2.0) * aspect)


def subject_elevation_rate(centre_y: np.ndarray, tilt_rate_radps: np.ndarray, fps: float, starts: np.ndarray,
                           window_s: float = DISTANCE_WINDOW_S, hfov_deg: float = ASSUMED_HFOV_DEG,
                           aspect: float = ASSUMED_ASPECT) -> np.ndarray:
    """d(elevation of the source camera round the subject)/dt per row [rad/s, positive rising]: the
    subject lies at pitch + b from the camera, b = atan((0.5 - y) 2 tan(hfov/2) aspect) his angle above
    the optical axis (y his box's normalised centre, down; aspect the image's height over its width), so
    the camera's elevation over him turns at -(tilt rate + db/dt). A pedestal up with the tilt held
    sinks him in the image and turns it at v/d, as a truck turns the bearing; the slope of b is a line
    over the window inside the row's shot; NaN where the window is short or the tilt rate unknown."""
    b = _angle_off_axis(centre_y, hfov_deg, aspect)
    return -(np.asarray(tilt_rate_radps, dtype=float) + _window_slopes(b, fps, starts, window_s))


def subject_distance_rate(heights: np.ndarray, zoom_rate: np.ndarray, fps: float, starts: np.ndarray,
                          window_s: float = DISTANCE_WINDOW_S) -> np.ndarray:
    """d ln(subject distance)/dt of the source camera per row [1/s]: a subject of height H at distance
    d fills f H / d of the image, so ln d = ln f - ln h + const and the rate is the zoom rate less
    d ln h/dt. The slope of ln h is a least-squares line over a centred window inside the row's shot
    (a walker's box breathes with his gait from frame to frame); NaN where fewer than half the
    window is seen or the zoom rate is unknown."""
    h = np.asarray(heights, dtype=float)
    logh = np.where(np.isfinite(h) & (h > 0), np.log(np.where(h > 0, h, 1.0)), np.nan)
    return np.asarray(zoom_rate, dtype=float) - _window_slopes(logh, fps, starts, window_s)


def _rows_per_s(ins: object) -> float:
    """The instructions' rows per second (0 when unknown)."""
    fps = float(getattr(ins, "fps", 0.0) or 0.0)
    if not (math.isfinite(fps) and fps > 0):
        dur = float(getattr(ins, "frame_duration_s", 0.0) or 0.0)
        fps = 1.0 / dur if math.isfinite(dur) and dur > 0 else 0.0
    return fps


def _zoom_asked(cls: frozenset[str] | None, zoom: float) -> bool:
    """Whether a row asks the lens to zoom: its class names a zoom, or it has no class and a clear rate."""
    if cls is not None:
        return any(n in cls for n in ZOOM_CLASSES)
    return math.isfinite(zoom) and abs(zoom) >= MIN_ZOOM_RATE


def zoom_to_come(zoom_rate: np.ndarray, fps: float) -> np.ndarray:
    """(K, 2): from each row on, ln of the furthest the lens zooms out and in over the rest of the
    take at the rows' zoom rates `zoom_rate` (K,) [1/s] (0 where none, NaN read as 0), both >= 0."""
    step = np.nan_to_num(np.asarray(zoom_rate, dtype=float)) / fps
    level = np.concatenate([[0.0], np.cumsum(step)])  # ln f after each row, relative to the take's start
    lowest = np.minimum.accumulate(level[::-1])[::-1][1:]  # the least level reached after each row's start
    highest = np.maximum.accumulate(level[::-1])[::-1][1:]
    return np.column_stack([np.maximum(level[:-1] - lowest, 0.0), np.maximum(highest - level[:-1], 0.0)])


def lens_headroom(to_come: np.ndarray, focal_range_mm: tuple[float, float]) -> tuple[float, float]:
    """ln of the least and greatest focal length [mm] that leave the lens room for the zoom still to
    come `to_come` (ln out, ln in), within the lens's range (the floor never above the ceiling).
    A side with no zoom to come lies UNUSED_SIDE beyond the range: a floor at the lens's own end
    touched a lens resting there (a slow dolly's flight moved, 0.52 -> 0.31 by the video)."""
    lo, hi = math.log(focal_range_mm[0]), math.log(focal_range_mm[1])
    out, zin = (float(v) for v in to_come)
    floor = min(lo + out + HEADROOM_MARGIN, hi) if out > 0 else lo - UNUSED_SIDE
    ceiling = max(hi - zin - HEADROOM_MARGIN, lo) if zin > 0 else hi + UNUSED_SIDE
    return (floor, ceiling) if floor <= ceiling else (0.5 * (floor + ceiling),) * 2


def row_terms(style: MotionStyle, row: int, *, control_roll: bool,
              focal_range_mm: tuple[float, float] | None = None) -> np.ndarray:
    """The N_MOTION parameters of one row (the side-of-subject ones 0); the lens's headroom when
    the lens's `focal_range_mm` is given and a zoom is still to come."""
    out = np.zeros(N_MOTION)
    _headroom_terms(out, style, row, focal_range_mm)
    cls = style.classes[row]
    # (a static row returns below before these: its rates and its place are held already)
    unframed = cls is not None and style.subject_seen is not None and not style.subject_seen[row]
    if cls == STATIC:
        n_rates = 3 if control_roll else 2
        out[RATE_MASKS.start:RATE_MASKS.start + n_rates] = 1.0  # each rate's target 0
        out[ZOOM_MASK] = 1.0
        out[STILL] = 1.0  # the source camera stood still: following the subject would turn it to keep him framed
        return out
    for i, names in enumerate(RATE_CLASSES):
        rate = float(style.rates_radps[row, i])
        asked = (cls is not None and any(n in cls for n in names)) or \
            (cls is None and math.isfinite(rate) and abs(rate) >= math.radians(MIN_RATE_DPS))
        if asked and math.isfinite(rate) and (i < 2 or control_roll):
            out[RATES.start + i], out[RATE_MASKS.start + i] = rate, 1.0
    zoom = float(style.zoom_rate[row])
    zoom_asked = _zoom_asked(cls, zoom)
    if zoom_asked and math.isfinite(zoom):
        out[ZOOM], out[ZOOM_MASK] = zoom, 1.0
        if cls is not None and "dolly_zoom" in cls:
            out[DOLLY_ZOOM_MASK], out[DISTANCE_RATE] = 1.0, _dolly_zoom_distance_rate(style, row, cls, zoom)
    if cls is not None and any(n in cls for n in STILL_CLASSES) and not any(n in cls for n in TRAVEL_CLASSES):
        out[STILL] = 1.0
        if not zoom_asked:  # held in place, the framing would zoom after the subject's distance instead
            out[ZOOM_MASK] = 1.0
        elif any(n in cls for n in ZOOM_CLASSES):  # held sideways only, it backed off as it zoomed: a dolly-zoom
            out[STILL_ALONG] = 1.0
    travel = style.travel[row]
    if travel.any() and (cls is None or any(n in cls for n in TRAVEL_CLASSES)):
        out[TRAVEL], out[TRAVEL_MASK] = travel, 1.0
    if cls is not None:
        _speed_terms(out, style, row, cls)
        _along_axis_terms(out, cls)
        _pedestal_terms(out, style, row, cls)
    if unframed:
        _unframed_terms(out, style, row, control_roll)
    return out


def _unframed_terms(out: np.ndarray, style: MotionStyle, row: int, control_roll: bool) -> None:
    """A row whose source lost its subject: its camera went on with its move, not after him. The look term
    gives way (LOOK_OFF; it whipped dolly_in's camera round after the walker leaving its frame, 33-48 deg/s)
    and every rate the class leaves free is asked as the source measured it (with no framing to serve,
    nothing else holds it: orbit_left's camera tilted up after the walker the source lost)."""
    out[LOOK_OFF] = 1.0
    cls = style.classes[row]
    if cls is not None and any(n in cls for n in SWING_CLASSES):
        out[RATES_HELD] = 1.0
    for i in range(3 if control_roll else 2):
        rate = float(style.rates_radps[row, i])
        if not out[RATE_MASKS.start + i] and math.isfinite(rate):
            out[RATES.start + i], out[RATE_MASKS.start + i] = rate, 1.0


def pedestal_least_rate(elevation_rate: float, travel_up: float) -> float:
    """The least speed over the subject's distance [1/s] a pedestal row asks along its direction of travel:
    the source's elevation rate round the subject when it turns the way the travel goes (up: rising), else
    0 (a reading that disagrees with itself asks no speed)."""
    if not math.isfinite(elevation_rate) or elevation_rate * travel_up <= 0:
        return 0.0
    return abs(elevation_rate)


def _pedestal_terms(out: np.ndarray, style: MotionStyle, row: int, cls: frozenset[str]) -> None:
    """A pedestal rises or sinks at the source's rate with the tilt and the lens held as the source's: the
    style gives the travel a direction only, and the framing tilted after the walker sinking in the image
    (the pedestal flown as a tilt). A handheld (tilting, rolling) or swinging row is left as before."""
    if not any(n in cls for n in PEDESTAL_CLASSES) or any(n in cls for n in (*HANDHELD_CLASSES, *SWING_CLASSES)) \
            or not out[TRAVEL_MASK] or style.elevation_rate is None:
        return
    least = pedestal_least_rate(float(style.elevation_rate[row]), float(out[TRAVEL.start + 2]))
    if least > 0:
        out[TRAVEL_MIN], out[TRAVEL_MEASURED] = least, 1.0
    tilt = float(style.rates_radps[row, 1])
    out[RATES.start + 1], out[RATE_MASKS.start + 1] = (tilt if math.isfinite(tilt) else 0.0), 1.0
    if not any(n in cls for n in ZOOM_CLASSES):
        zoom = float(style.zoom_rate[row])
        out[ZOOM], out[ZOOM_MASK] = (zoom if math.isfinite(zoom) else 0.0), 1.0


def _along_axis_terms(out: np.ndarray, cls: frozenset[str]) -> None:
    """A dolly's or dolly-zoom's camera rides its axis, as on rails: it stands still sideways (following the
    walker sideways, the dolly-zoom in read as a pan) and travels at least at TRAVEL_MIN_RATE."""
    if any(n in cls for n in ALONG_AXIS_CLASSES) and not any(n in cls for n in (*SWING_CLASSES, "pedestal",
                                                                                  *HANDHELD_CLASSES)):
        out[STILL] = 1.0
        if out[TRAVEL_MASK]:
            out[TRAVEL_MIN] = TRAVEL_MIN_RATE


def _speed_terms(out: np.ndarray, style: MotionStyle, row: int, cls: frozenset[str]) -> None:
    """A dolly's lens and distance; a truck's or orbit's too, with its bearing rate (a handheld one's: a
    truck's bearing rate only)."""
    swing = any(n in cls for n in SWING_CLASSES) and not any(n in cls for n in HANDHELD_CLASSES)
    if (swing or any(n in cls for n in DOLLY_CLASSES)) and not any(n in cls for n in ZOOM_CLASSES):
        _dolly_terms(out, style, row)
    if swing or "truck" in cls:
        _swing_terms(out, style, row)


def _dolly_zoom_distance_rate(style: MotionStyle, row: int, cls: frozenset[str], zoom: float) -> float:
    """The subject-distance rate a dolly-zoom row asks: the source subject's own (read from his size, as a
    dolly's), which is the zoom rate only when the move holds his size. The rendered dolly-zoom holds a
    point 9 m ahead while the walker crosses: asked the zoom rate, the distance term fought the framing
    of his size and the camera, at its 2 m/s, panned after him (read pan+dolly_zoom). A handheld row
    (with a tilt or a roll) keeps the zoom rate, as before."""
    rate = math.nan if style.distance_rate is None else float(style.distance_rate[row])
    if any(n in cls for n in HANDHELD_CLASSES) or not math.isfinite(rate):
        return zoom
    return rate


def _headroom_terms(out: np.ndarray, style: MotionStyle, row: int,
                    focal_range_mm: tuple[float, float] | None) -> None:
    """Room on the lens for the zoom still to come in the take, when the lens's range is known."""
    if focal_range_mm is not None and style.zoom_to_come is not None and style.zoom_to_come[row].any():
        out[LOG_FOCAL_FLOOR], out[LOG_FOCAL_CEILING] = lens_headroom(style.zoom_to_come[row], focal_range_mm)
        out[HEADROOM_MASK] = 1.0


def _swing_terms(out: np.ndarray, style: MotionStyle, row: int) -> None:
    """A truck's or orbit's speed: the camera's bearing round the subject turns at the source's rate. The style
    gives the travel a direction only; left free, the framing panned after the walker and the truck
    was flown as a pan."""
    rate = math.nan if style.bearing_rate is None else float(style.bearing_rate[row])
    if math.isfinite(rate):
        out[BEARING_RATE_MASK], out[BEARING_RATE] = 1.0, rate
        return
    held = math.nan if style.swing_held_rate is None else float(style.swing_held_rate[row])
    if math.isfinite(held) and out[TRAVEL_MASK]:
        # the source lost its subject and its camera went on: the swing keeps the sideways speed it last
        # read (left to the direction alone, orbit_left's camera stood and turned after the walker)
        out[TRAVEL_MIN] = abs(held)


def _dolly_terms(out: np.ndarray, style: MotionStyle, row: int) -> None:
    """A dolly's lens and speed, and a truck's or orbit's lens and distance. The style gives the travel
    a direction only; left free, the lens kept the subject's size and the camera stood (the slow dolly
    flown static; a truck and an orbit zoomed in after a walker leaving them). The lens holds as the
    source's did, and the subject's distance changes at the source's rate, read from his size."""
    zoom = float(style.zoom_rate[row])
    out[ZOOM], out[ZOOM_MASK] = (zoom if math.isfinite(zoom) else 0.0), 1.0
    rate = math.nan if style.distance_rate is None else float(style.distance_rate[row])
    if math.isfinite(rate):
        out[DOLLY_ZOOM_MASK], out[DISTANCE_RATE] = 1.0, rate


def zoom_out_held_by_dolly(zoom: float, along_mps: float, distance_m: float) -> float:
    """A dolly-zoom in's zoom out [1/s], at most the rate at which the camera's travel along its axis
    (`along_mps`, forward positive) closes on its subject `distance_m` ahead: the depth the move holds (whose
    image neither grows nor shrinks) is never nearer than him, as the source's is not (its subject's distance
    rate -0.15 /s against its zoom -0.17 /s). The lens zooms at the asked rate at once while the airframe
    gathers speed at its acceleration (1.2 m/s^2): from the take's first row the zoom out outran the dolly
    (0.77 m/s against -0.20 /s, the depth held 3.9 m, nearer than any ground in view), every point shrank and
    the output read zoom_out on rows 0-10. A travel not under way yet holds nothing: 0. A zoom in (the
    dolly-zoom out, which backs off already in its settle) is left as asked: held so, it read dolly_out."""
    if not (math.isfinite(zoom) and zoom < 0 and math.isfinite(along_mps) and math.isfinite(distance_m)
            and distance_m > 0):
        return zoom
    return -min(-zoom, max(0.0, along_mps) / distance_m)


def zoom_in_kept_to_backing_off(zoom: float, along_mps: float, distance_m: float) -> float:
    """A dolly-zoom out's zoom in [1/s], at least the rate at which the camera's backing off along its axis
    (`along_mps`, forward positive) opens the distance to its subject `distance_m` ahead: the depth the move
    holds (speed / zoom, whose image neither grows nor shrinks) is never farther than him. The source's
    reading falls to +0.033-0.057 /s on its last ten rows (its truth: +0.09); flown as asked (+0.041 /s
    while the walker's distance grew at 0.089 /s) the background behind him hardly scaled, rotation + zoom
    explained 0.80-0.92 of its points, no translation was tested and the output read static on rows 38-47.
    Only the camera's own travel is held here (his walking away is not), so this acts little there
    (+0.046 /s). A zoom out, or a camera not backing off, is left as asked."""
    if not (math.isfinite(zoom) and zoom > 0 and math.isfinite(along_mps) and math.isfinite(distance_m)
            and distance_m > 0):
        return zoom
    return max(zoom, max(0.0, -along_mps) / distance_m)


def hold_dolly_zooms(motion: np.ndarray, style: MotionStyle | None, rows: list[int], along_mps: float,
                     distance_m: float) -> None:
    """In place: the zoom asked (ZOOM) of each stage of `motion` (N, N_MOTION) whose row (`rows`) is a
    dolly-zoom, held by the camera's travel now (zoom_out_held_by_dolly, zoom_in_kept_to_backing_off)."""
    if style is None:
        return
    for k, r in enumerate(rows):
        cls = style.classes[r] if 0 <= r < len(style.classes) else None
        if cls is not None and "dolly_zoom" in cls and motion[k, ZOOM_MASK]:
            zoom = zoom_out_held_by_dolly(float(motion[k, ZOOM]), along_mps, distance_m)
            motion[k, ZOOM] = zoom_in_kept_to_backing_off(zoom, along_mps, distance_m)


def plan_for_setpoint_lead(motion: np.ndarray, factor: float) -> None:
    """Plan the rate targets of the stages' `motion` (N, N_MOTION) `factor` times slower where the setpoint's
    lead flies them that much faster (core.flown_rate_factor): the lens's on every stage, the camera's angular
    rates only where the source lost its subject (LOOK_OFF). Elsewhere the framing pins the angles; with
    nothing framed orbit_left's camera panned at 16 deg/s for the source's 8."""
    motion[:, FLOWN_RATE_COLUMNS] /= factor
    motion[motion[:, LOOK_OFF] > 0, RATES] /= factor


def stage_motion(style: MotionStyle | None, rows: list[int], *, control_roll: bool,
                 focal_range_mm: tuple[float, float] | None = None) -> np.ndarray:
    """(N, N_MOTION) parameters of the horizon's stages from their instruction rows."""
    out = np.zeros((len(rows), N_MOTION))
    if style is None:
        return out
    for k, r in enumerate(rows):
        if 0 <= r < len(style.classes):
            out[k] = row_terms(style, r, control_roll=control_roll, focal_range_mm=focal_range_mm)
    return out
