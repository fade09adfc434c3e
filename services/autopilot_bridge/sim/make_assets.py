"""Generate the simulator's image assets from the real clips in ../shared/data.

Run once (the outputs are shipped in `assets/`; re-run only to change them):

    .venv/bin/python -m cinetransfer.services.autopilot_bridge.sim.make_assets [--data DIR]

What it makes (all from real footage, see assets/CREDITS.md):
- `juggler_NN.png` + `juggler.json`: a short loop of cut-outs (BGRA, alpha = person mask) of the
  man juggling a football in sam2_juggle_1280x720.mp4, with the COCO-17 joints that MediaPipe's
  pose model finds in each cut-out (pixel coordinates inside the cut-out), the ground-contact
  point and the metric scale. The mask is a background subtraction against a clean plate of the
  locked-off shot, restricted to a dilated MediaPipe segmentation.
- `lawn_backdrop.jpg`: the upper part of the juggle clip's clean plate (trees, glass building,
  far lawn) — the person removed by a temporal median over frames where he is elsewhere, the
  rest inpainted — extended upwards by reflection and sky.
- `lawn_tile.jpg`: a top-down (rectified) patch of the same lawn, tiled by reflection.
- `forest_backdrop.png`: a forest edge from davis_parkour frame 99 (mirror-tiled, tree tops
  given an irregular silhouette), for the open-country scene.
- `sky.jpg`: a vertical sky gradient sampled from the parkour sky (frame 0); `sky_lawn.jpg`
  the same from the juggle clip's bright sky.
- `hedge.png`: shrubs from davis_parkour frame 99 with an irregular top silhouette, used as a
  foreground object.

Needs mediapipe (legacy `solutions.pose`, models ship in the 0.10.21 wheel). Deterministic.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import cv2
import numpy as np

log = logging.getLogger("make_assets")

ASSETS = Path(__file__).resolve().parent / "assets"
#: BlazePose-33 indices of the COCO-17 joints (DESIGN §5).
COCO_FROM_BLAZE = [0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28]

#: Estimated geometry of the locked-off juggle camera (1280x720): focal length in pixels, camera
#: height [m], horizon row (a shift-lens model: principal point on the horizon). Read off the
#: clip: a 1.78 m man spans ~620 px with his feet at row ~660 at ~3 m.
JUGGLE_F_PX = 1100.0
JUGGLE_CAM_H_M = 1.2
JUGGLE_HORIZON_ROW = 240.0
#: distance of the backdrop plane [m] in the lawn scene.
LAWN_BACKDROP_M = 25.0


def default_data_dir() -> Path:
    return Path(__file__).resolve().parents[3] / ".." / "shared" / "data"


def read_frames(path: Path, step: int = 1) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    i = 0
    while True:
        ok, f = cap.read()
        if not ok:
            break
        if i % step == 0:
            out.append(f)
        i += 1
    cap.release()
    if not out:
        raise FileNotFoundError(f"no frames read from {path}")
    return out


def run_pose(frames: list[np.ndarray], static: bool) -> list[tuple[np.ndarray | None, np.ndarray | None]]:
    """(landmarks (33, 4) px x, px y, z, visibility; segmentation float mask) per frame."""
    import mediapipe as mp

    out = []
    with mp.solutions.pose.Pose(static_image_mode=static, model_complexity=1,
                                enable_segmentation=True) as pose:
        for f in frames:
            h, w = f.shape[:2]
            r = pose.process(cv2.cvtColor(f, cv2.COLOR_BGR2RGB))
            if r.pose_landmarks is None:
                out.append((None, None))
                continue
            lm = np.array([[p.x * w, p.y * h, p.z, p.visibility] for p in r.pose_landmarks.landmark])
            out.append((lm, r.segmentation_mask.copy()))
    return out


def clean_plate(frames: list[np.ndarray], masks: list[np.ndarray]) -> np.ndarray:
    """Per-pixel median over frames where the pixel is not covered by the person; inpaint the rest."""
    h, w = frames[0].shape[:2]
    plate = np.zeros((h, w, 3), np.uint8)
    holes = np.zeros((h, w), np.uint8)
    for y0 in range(0, h, 60):
        y1 = min(h, y0 + 60)
        stack = np.stack([f[y0:y1].astype(np.float32) for f in frames])
        cover = np.stack([m[y0:y1] for m in masks])
        stack[cover] = np.nan
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                med = np.nanmedian(stack, axis=0)
        bad = np.isnan(med[..., 0]) | ((~cover).sum(axis=0) < 5)
        med[bad] = 0
        plate[y0:y1] = np.clip(med, 0, 255).astype(np.uint8)
        holes[y0:y1] = bad.astype(np.uint8) * 255
    if holes.any():
        plate = _fill_by_shift(plate, holes > 0)
    log.info("clean plate: %.2f%% of pixels inpainted", 100.0 * (holes > 0).mean())
    return plate


def _fill_by_shift(img: np.ndarray, hole: np.ndarray) -> np.ndarray:
    """Fill a hole row by row with the texture just left of it (translated copy), feathered.

    Keeps grain and structure where plain diffusion inpainting would smear a blob."""
    out = img.copy()
    ys, xs = np.nonzero(hole)
    x0, x1 = xs.min(), xs.max() + 1
    width = x1 - x0
    src_x0 = max(0, x0 - width - 20)
    patch = img[:, src_x0:src_x0 + width]
    region = hole[:, x0:x1]
    soft = cv2.GaussianBlur(cv2.dilate(region.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(np.float32),
                            (15, 15), 4)[..., None]
    blend = out[:, x0:x1].astype(np.float32) * (1 - soft) + patch[:, : x1 - x0].astype(np.float32) * soft
    out[:, x0:x1] = np.clip(blend, 0, 255).astype(np.uint8)
    return out


def person_mask(frame: np.ndarray, plate: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Crisp person (+ ball) mask: background subtraction inside a dilated MediaPipe mask."""
    diff = cv2.absdiff(cv2.GaussianBlur(frame, (5, 5), 0), cv2.GaussianBlur(plate, (5, 5), 0)).max(axis=2)
    fg = (diff > 28).astype(np.uint8)
    core = (seg > 0.5).astype(np.uint8)
    region = cv2.dilate(core, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (41, 41)))
    m = fg & region
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (9, 9)))
    m = cv2.morphologyEx(m, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))
    m |= cv2.erode(core, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (15, 15)))
    # keep components that touch the segmentation core (drops shadows and leaves elsewhere)
    n, lab = cv2.connectedComponents(m)
    keep = np.zeros(n, bool)
    touching = np.unique(lab[(core > 0) & (m > 0)])
    keep[touching] = True
    keep[0] = False
    m = keep[lab].astype(np.uint8)
    # fill small holes (not the gap between the legs, which shows the lawn)
    inv = (1 - m).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(inv)
    border = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])).tolist())
    for k in range(1, n):
        if k not in border and stats[k, cv2.CC_STAT_AREA] < 600:
            m[lab == k] = 1
    return m


def make_juggler(data: Path, out: Path) -> np.ndarray:
    frames = read_frames(data / "sam2_juggle_1280x720.mp4")
    log.info("juggle: %d frames, running pose + segmentation", len(frames))
    poses = run_pose(frames, static=False)
    segs = [s if s is not None else np.zeros(frames[0].shape[:2], np.float32) for _, s in poses]
    # the ball flies outside the person mask: the median over many frames removes it anyway
    cover = [cv2.dilate((s > 0.1).astype(np.uint8), np.ones((31, 31), np.uint8)) > 0 for s in segs]
    seen = [i for i, (lm, _) in enumerate(poses) if lm is not None]
    log.info("juggle: person found in %d/%d frames", len(seen), len(frames))
    plate = clean_plate([frames[i] for i in seen[::2]], [cover[i] for i in seen[::2]])

    # choose a loop: a contiguous run where every COCO joint is confidently seen and the face is
    # frontal (both eyes and ears visible), scored by mean visibility.
    vis = np.array([p[0][COCO_FROM_BLAZE, 3].min() if p[0] is not None else 0.0 for p in poses])
    n_loop, stride = 12, 2
    span = n_loop * stride
    best, best_i = -1.0, 0
    for i in range(0, len(frames) - span):
        s = vis[i:i + span:stride].min()
        if s > best:
            best, best_i = s, i
    log.info("juggler loop: frames %d..%d (step %d), min joint visibility %.3f",
             best_i, best_i + span - 1, stride, best)
    idx = list(range(best_i, best_i + span, stride))
    heights = []
    items = []
    for k, i in enumerate(idx):
        lm, seg = poses[i]
        m = person_mask(frames[i], plate, seg)
        ys, xs = np.nonzero(m)
        x0, x1 = max(xs.min() - 8, 0), min(xs.max() + 9, m.shape[1])
        y0, y1 = max(ys.min() - 8, 0), min(ys.max() + 9, m.shape[0])
        heights.append(ys.max() - ys.min())
        items.append((i, lm, m, (x0, y0, x1, y1)))
    # metric scale: the shot is locked off and he stays at about the same depth over the loop;
    # the standing height (max mask height over the loop) is the subject's height.
    px_height = float(np.max(heights))
    # cut-outs keep the clip's own resolution (scale 1; until the multi-shot work they were cut at 420 px, 0.66x,
    # which a long lens framing him close magnified 2x, and the focus estimator read him soft)
    target_px = px_height
    scale = target_px / px_height
    meta = {"source": "sam2_juggle_1280x720.mp4", "frames": [], "height_px_standing": target_px,
            "joint_names": "coco17", "note": "joints/anchor in cut-out pixels (x right, y down)"}
    for k, (i, lm, m, (x0, y0, x1, y1)) in enumerate(items):
        crop = frames[i][y0:y1, x0:x1]
        a = m[y0:y1, x0:x1].astype(np.float32)
        a = cv2.GaussianBlur(a, (3, 3), 0.8)
        w = int(round((x1 - x0) * scale))
        h = int(round((y1 - y0) * scale))
        crop = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA)
        a = cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA)
        bgra = np.dstack([crop, np.clip(a * 255 + 0.5, 0, 255).astype(np.uint8)])
        bgra[..., :3][bgra[..., 3] == 0] = 0
        name = f"juggler_{k:02d}.png"
        cv2.imwrite(str(out / name), bgra, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        j = lm[COCO_FROM_BLAZE]
        jx = (j[:, 0] - x0) * scale
        jy = (j[:, 1] - y0) * scale
        ys, xs = np.nonzero(m[y0:y1, x0:x1])
        foot_y = (ys.max() + 1) * scale
        ankles_x = float((jx[15] + jx[16]) / 2)
        meta["frames"].append({
            "file": name, "source_frame": int(i), "size_px": [w, h],
            "anchor_px": [round(ankles_x, 2), round(float(foot_y), 2)],
            "joints_px": [[round(float(x), 2), round(float(y), 2)] for x, y in zip(jx, jy)],
            "visibility": [round(float(v), 3) for v in j[:, 3]],
        })
    (out / "juggler.json").write_text(json.dumps(meta, indent=1))
    return plate


def make_lawn(plate: np.ndarray, out: Path) -> None:
    f, h_cam, hz = JUGGLE_F_PX, JUGGLE_CAM_H_M, JUGGLE_HORIZON_ROW
    H, W = plate.shape[:2]
    # backdrop: rows above the ground line at LAWN_BACKDROP_M; extend up by reflection + sky.
    seam = int(round(hz + f * h_cam / LAWN_BACKDROP_M))
    back = plate[:seam + 2]
    top = back[: back.shape[0] // 2][::-1]
    fade = np.linspace(0.0, 1.0, top.shape[0])[:, None, None]
    sky = np.array(cv2.mean(plate[:20])[:3], np.float32)
    top = (top * (1 - fade) + sky * fade)[::-1]  # far top = sky, reflected canopy below it
    backdrop = np.vstack([np.clip(top, 0, 255).astype(np.uint8), back])
    cv2.imwrite(str(out / "lawn_backdrop.jpg"), backdrop, [cv2.IMWRITE_JPEG_QUALITY, 88])
    # sky above it: the same colour as the backdrop's faded top, a little deeper upwards
    g = np.linspace(0, 1, 256)[:, None, None]
    zenith = sky * np.array([1.0, 0.93, 0.85], np.float32)
    grad = (zenith * (1 - g) + sky * g) * np.ones((256, 64, 1), np.float32)
    cv2.imwrite(str(out / "sky_lawn.jpg"), np.clip(grad, 0, 255).astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 90])
    meta = {"backdrop_distance_m": LAWN_BACKDROP_M,
            "backdrop_m_per_px": LAWN_BACKDROP_M / f,
            "backdrop_bottom_row": backdrop.shape[0] - 2,
            "backdrop_size_px": [backdrop.shape[1], backdrop.shape[0]]}
    # lawn tile: rectify ground x (forward) 2.9..5.4 m, y (left) -1.3..1.3 m at 160 px/m (inside
    # the plate's view at every depth of the patch)
    ppm = 160.0
    xs = (2.9, 5.4)
    ys = (-1.3, 1.3)
    tw, th = int((ys[1] - ys[0]) * ppm), int((xs[1] - xs[0]) * ppm)
    # tile pixel (c, r): world y = ys[1] - c/ppm (left at c=0 ... image right = -y), x = xs[1] - r/ppm
    src = []
    dst = []
    for c, r in ((0, 0), (tw, 0), (0, th), (tw, th)):
        yw = ys[1] - c / ppm
        xw = xs[1] - r / ppm
        u = W / 2 - f * yw / xw
        v = hz + f * h_cam / xw
        src.append((c, r))
        dst.append((u, v))
    hmat = cv2.getPerspectiveTransform(np.float32(dst), np.float32(src))
    tile = cv2.warpPerspective(plate, hmat, (tw, th), flags=cv2.INTER_AREA | cv2.INTER_LINEAR)
    cv2.imwrite(str(out / "lawn_tile.jpg"), tile, [cv2.IMWRITE_JPEG_QUALITY, 88])
    meta["tile_m_per_px"] = 1.0 / ppm
    (out / "lawn.json").write_text(json.dumps(meta, indent=1))


def _silhouette(width: int, height: int, rng: np.random.Generator, base: float, amp: float,
                scale_px: float) -> np.ndarray:
    """Alpha with an irregular top edge (smoothed random profile) — tree tops, shrub tops."""
    n = max(4, int(width / scale_px) + 3)
    knots = rng.uniform(-1, 1, n)
    prof = np.interp(np.arange(width), np.linspace(0, width - 1, n), knots)
    fine = rng.uniform(-1, 1, width)
    fine = np.convolve(fine, np.ones(5) / 5, mode="same")
    top = (base + amp * (0.8 * prof + 0.35 * fine)) * height
    rows = np.arange(height)[:, None]
    return np.clip(rows - top[None, :] + 0.5, 0, 1).astype(np.float32)


def _leafy(bgr: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """`bgr` upscaled k times (Lanczos) under a layer of sharp procedural leaves (small filled
    ellipses coloured from the picture beneath, shaded at random). The shrubs come from a 480-line
    clip: seen from 3 m at 50 mm or more (focus_hedge) each of their texels covered 2.5+ output
    pixels, and perfectly focused they read out of focus to the focus estimator (mean in-focus
    probability 0.44 at 50 mm, 0.25 at 70 mm; with the leaves 0.76 and 0.74)."""
    big = cv2.resize(bgr, None, fx=k, fy=k, interpolation=cv2.INTER_LANCZOS4)
    h, w = big.shape[:2]
    out = big.copy()
    n = int(h * w / (2.2 * k) ** 2)
    ys, xs = rng.integers(0, h, n), rng.integers(0, w, n)
    ax = rng.uniform(0.9, 2.2, n) * k
    ay, ang, shade = ax * rng.uniform(0.35, 0.6, n), rng.uniform(0, 180, n), rng.uniform(0.6, 1.35, n)
    for y, x, a, b, t, s in zip(ys, xs, ax, ay, ang, shade):
        c = np.clip(big[y, x].astype(np.float32) * s, 0, 255)
        cv2.ellipse(out, (int(x), int(y)), (int(a), max(int(b), 1)), float(t), 0, 360, tuple(float(v) for v in c), -1,
                    cv2.LINE_AA)
    return out


def _parkour_frame(data: Path, index: int) -> np.ndarray:
    cap = cv2.VideoCapture(str(data / "davis_parkour_854x480.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, index)
    ok, fr = cap.read()
    cap.release()
    if not ok:
        raise FileNotFoundError(f"davis_parkour_854x480.mp4 frame {index}")
    return fr


def make_parkour(data: Path, out: Path) -> None:
    fr = _parkour_frame(data, 99)
    rng = np.random.default_rng(7)
    # forest edge: frame 99, x 80..375, y 0..92 (dense deciduous woods above a shrub line)
    forest = fr[0:92, 80:375].copy()
    strip = np.hstack([forest, forest[:, ::-1], forest, forest[:, ::-1]])
    strip = cv2.resize(strip, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
    sil = _silhouette(strip.shape[1], strip.shape[0], rng, base=0.10, amp=0.08, scale_px=22)
    a = cv2.GaussianBlur(sil, (3, 3), 0.7)
    cv2.imwrite(str(out / "forest_backdrop.png"),
                np.dstack([strip, np.clip(a * 255, 0, 255).astype(np.uint8)]),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])
    # sky gradient from the clip's blue sky (frame 0, top right)
    f0 = _parkour_frame(data, 0)
    top_c = f0[0:20, 420:640].reshape(-1, 3).astype(np.float32).mean(0)
    horizon_c = f0[70:90, 420:520].reshape(-1, 3).astype(np.float32).mean(0)
    g = np.linspace(0, 1, 256)[:, None, None]
    sky = (top_c * (1 - g) + horizon_c * g) * np.ones((256, 64, 1))
    noise = rng.normal(0, 1.0, sky.shape)
    cv2.imwrite(str(out / "sky.jpg"), np.clip(sky + noise, 0, 255).astype(np.uint8),
                [cv2.IMWRITE_JPEG_QUALITY, 90])
    # shrubs: frame 99, x 0..290, y 230..400 (bushes on a lawn), given an irregular top
    shrub = fr[232:400, 0:290].copy()
    shrub = np.hstack([shrub, shrub[:, ::-1]])
    shrub = cv2.resize(shrub, None, fx=1.6, fy=1.6, interpolation=cv2.INTER_CUBIC)
    sa = _silhouette(shrub.shape[1], shrub.shape[0], rng, base=0.22, amp=0.12, scale_px=45)
    sa = cv2.GaussianBlur(sa, (5, 5), 1.2)
    shrub = _leafy(shrub, 3, np.random.default_rng(11))
    sa = cv2.resize(sa, None, fx=3, fy=3, interpolation=cv2.INTER_LINEAR)
    cv2.imwrite(str(out / "hedge.png"), np.dstack([shrub, np.clip(sa * 255, 0, 255).astype(np.uint8)]),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=default_data_dir(), help="folder of the real clips")
    p.add_argument("--out", type=Path, default=ASSETS, help="assets folder to write")
    p.add_argument("--cache", type=Path, default=Path("/tmp/cinetransfer_sim_assets"),
                   help="where the clean plate of the juggle clip is kept between runs")
    p.add_argument("--only", choices=["juggler", "lawn", "parkour"], action="append")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    args.out.mkdir(parents=True, exist_ok=True)
    only = set(args.only or ["juggler", "lawn", "parkour"])
    plate_path = args.cache / "juggle_plate.png"
    args.cache.mkdir(parents=True, exist_ok=True)
    if "juggler" in only:
        plate = make_juggler(args.data, args.out)
        cv2.imwrite(str(plate_path), plate)
        from cinetransfer.services.autopilot_bridge.sim.make_subjects import add_juggler_fields

        add_juggler_fields(args.out)  # his subject-library fields (actions, person, credit, height)
    else:
        plate = cv2.imread(str(plate_path))
        if plate is None:
            p.error(f"{plate_path} missing: run with --only juggler first")
    if "lawn" in only:
        make_lawn(plate, args.out)
    if "parkour" in only:
        make_parkour(args.data, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
