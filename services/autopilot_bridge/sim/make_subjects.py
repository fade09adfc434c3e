"""Subject library: cut-out people from the real clips in ../shared/data (see docs/simulator.md).

    .venv/bin/python -m cinetransfer.services.autopilot_bridge.sim.make_subjects [--data DIR]

Each subject is `<name>.json` + `<name>_NN.png` in `assets/` (the juggler is made by
make_assets.py; this module adds its library fields). A subject's json holds, per cut-out frame,
the COCO-17 joints MediaPipe's pose model measures on the cut-out itself (composited on grey, the
way it is rendered), the ground-contact point and whether a foot is on the ground; and per action
the frames that show it, how they loop (`pingpong` or `cycle`), the clip rate, and for
locomotion its natural speed (so a `walk` step plays the gait at a rate matching its stride).

Frames are scale-normalised: every cut-out is resized so that the subject's torso (shoulder
mid-point to hip mid-point, smoothed over time) has the same length, so a camera zoom or a
change of distance in the source footage does not make the person grow or shrink.

- dancer: DAVIS dance-twirl, exact cut-outs from its ground-truth masks (dance: frames 0-10,
  twirl: 18-34; the feet leave the picture after 34).
- runner: DAVIS parkour, exact cut-outs from its ground-truth masks (jump-down and run towards the
  camera, frames 0-12; vault over the wall, frames 20-27).
- walker: TUD-Stadtmitte pedestrian 2 (one gait cycle); mask = background subtraction against a
  temporal-median clean plate of the static shot inside a dilated MediaPipe segmentation and the
  ground-truth box; speed from the ground-truth world positions.
Deterministic (MediaPipe on CPU, fixed frames).
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from pathlib import Path

import cv2
import numpy as np

from cinetransfer.services.autopilot_bridge.sim.make_assets import (ASSETS, COCO_FROM_BLAZE, default_data_dir,
                                                                  read_frames)

log = logging.getLogger("make_subjects")

#: standing height / torso length (shoulder mid to hip mid), measured on the juggler's cut-outs
#: (then cut at 420 px tall, torso 121 px; the ratio holds at any size): keeps every subject on one scale convention.
HEIGHT_PER_TORSO = 3.47
#: ankle (the lower one) to the ground point of the cut-out, in torso lengths: the juggler's, median
#: over his cut-outs (anchor = lowest mask pixel there: 0.36 torso below his lower ankle)
SOLE_PER_TORSO = 0.36
#: torso length of a scale-normalised cut-out [px] (standing height ~ 330 px: small assets).
TORSO_PX = 95.0
GREY = 128
#: radius of the walker's default loop [m] and its number of sides. At 1 m/s he turns 1/WALK_LOOP_M rad/s,
#: and a camera filming his front goes round the loop's centre with him: the planner keeps it within
#: 45 deg of his front, so it lags on the outside of the turn, 5-6 m from him, about 70 deg round:
#: 12.6 m from the centre at 7 m (1.8 m/s), under CineMPC's 2 m/s; at 5 m it needed 2 m/s and
#: fell side-on. Many sides: each corner turns him by 15 deg, not the octagon's 45 deg jumps
#: that threw the camera side-on at once (docs/planner.md, "Side of the subject").
WALK_LOOP_M = 7.0
WALK_LOOP_SIDES = 24

#: library facts that are not measured: who, from where, credit, height (metres), a default script
LIBRARY = {
    "juggler": {
        "person": "the juggler of sam2_juggle (a man juggling a football on a lawn)",
        "source": "sam2_juggle_1280x720.mp4",
        "credit": "shipped in the Apache-2.0 repository facebookresearch/sam2 (demo gallery)",
        "height_m": 1.78,
        "default_script": [{"action": "juggle", "duration_s": 4.0}, {"action": "stand", "duration_s": 1.0}],
    },
    "dancer": {
        "person": "the dancer of DAVIS dance-twirl (a woman dancing before a seated crowd)",
        "source": "davis_dance-twirl_854x480.mp4",
        "credit": "DAVIS, BSD licence (Perazzi et al., CVPR 2016)",
        "height_m": 1.65,
        "default_script": [{"action": "dance", "duration_s": 3.0}, {"action": "twirl", "duration_s": 1.5}],
    },
    "runner": {
        "person": "the runner of DAVIS parkour (a man running and vaulting)",
        "source": "davis_parkour_854x480.mp4",
        "credit": "DAVIS, BSD licence (Perazzi et al., CVPR 2016)",
        "height_m": 1.80,
        # a jog (his run clip slowed to 1.5 m/s, stride matched) between vaults: a camera limited
        # to 2 m/s and 1.2 m/s^2 cannot follow 3-4 m/s sprints that turn every 0.5 s
        "default_script": [{"action": "vault", "duration_s": 2.0},
                           {"action": "run", "path_m": [[0.0, 2.0]], "speed_mps": 1.5},
                           {"action": "vault", "duration_s": 2.0},
                           {"action": "run", "path_m": [[0.0, 0.0]], "speed_mps": 1.5}],
    },
    "walker": {
        "person": "pedestrian 2 of TUD-Stadtmitte (a man walking along a shopping street)",
        "source": "tud_stadtmitte_640x480.mp4",
        "credit": "MOTChallenge TUD-Stadtmitte, CC BY-NC-SA 3.0 (Andriluka, Roth, Schiele, CVPR 2010; "
                  "Leal-Taixé et al. 2015), research use",
        "height_m": 1.75,
        # a loop (WALK_LOOP_SIDES sides, radius WALK_LOOP_M) at 1.0 m/s, gait slowed to match: a camera limited
        # to 1.2 m/s^2 follows smooth turns, not a walk back and forth (a 2.4 m/s reversal takes it 2 s). He sets
        # off towards -x, where the bundled scenes' cameras start (so the take opens on his front, not his back),
        # turning left, towards -y: open_country's camera starts on that side, inside the turn
        "default_script": [{"action": "walk", "speed_mps": 1.0, "path_m": [
            [round(-WALK_LOOP_M * math.sin(2 * math.pi * k / WALK_LOOP_SIDES), 3) + 0.0,
             round(-WALK_LOOP_M * (1 - math.cos(2 * math.pi * k / WALK_LOOP_SIDES)), 3) + 0.0]
            for k in range(1, WALK_LOOP_SIDES + 1)]}],
    },
}


def _pose_on_cutout(pose, bgr: np.ndarray, alpha: np.ndarray) -> np.ndarray | None:
    """(33, 4) landmarks in pixels of `bgr` measured on the cut-out composited on grey."""
    a = alpha.astype(np.float32)[..., None] / 255.0
    comp = (bgr.astype(np.float32) * a + GREY * (1 - a)).astype(np.uint8)
    h, w = comp.shape[:2]
    r = pose.process(cv2.cvtColor(comp, cv2.COLOR_BGR2RGB))
    if r.pose_landmarks is None:
        return None
    return np.array([[p.x * w, p.y * h, p.z, p.visibility] for p in r.pose_landmarks.landmark])


def _torso(j: np.ndarray) -> float:
    return float(np.linalg.norm((j[5, :2] + j[6, :2]) / 2 - (j[11, :2] + j[12, :2]) / 2))


def _clear(out: Path, name: str) -> None:
    for p in out.glob(f"{name}_[0-9][0-9].png"):
        p.unlink()


def cut_subject(name: str, frames: list[np.ndarray], masks: list[np.ndarray], actions: dict, out: Path,
                extra: dict) -> dict:
    """Write `<name>_NN.png` + `<name>.json` for the frames the actions use; returns the json."""
    import mediapipe as mp

    used = sorted({i for a in actions.values() for i in a["source_frames"]})
    crops = {}
    with mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1) as pose:
        for i in used:
            m = masks[i].astype(np.uint8)
            ys, xs = np.nonzero(m)
            h = ys.max() - ys.min()
            pad = int(0.25 * h) + 8
            big = cv2.copyMakeBorder(frames[i], pad, pad, pad, pad, cv2.BORDER_REPLICATE)
            bm = cv2.copyMakeBorder(m, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
            x0, x1, y0, y1 = xs.min(), xs.max() + 2 * pad + 1, ys.min(), ys.max() + 2 * pad + 1
            crop, alpha = big[y0:y1, x0:x1], bm[y0:y1, x0:x1] * 255
            lm = _pose_on_cutout(pose, crop, alpha)
            if lm is None:  # MediaPipe cannot see this one: it is left out of the library
                log.info("%s: no pose in source frame %d, left out", name, i)
                continue
            crops[i] = (crop, alpha, lm[COCO_FROM_BLAZE])
    used = sorted(crops)
    actions = {a: {**v, "source_frames": [i for i in v["source_frames"] if i in crops]} for a, v in actions.items()}
    # scale: torso length smoothed over time (median of 5, then a 3-tap mean)
    tor = np.array([_torso(crops[i][2]) for i in used])
    med = np.array([np.median(tor[max(0, k - 2):k + 3]) for k in range(len(tor))])
    sm = np.array([med[max(0, k - 1):k + 2].mean() for k in range(len(med))])
    scale = {i: TORSO_PX / s for i, s in zip(used, sm)}
    _clear(out, name)
    meta = {"name": name, **{k: v for k, v in extra.items()}, "height_px_standing": HEIGHT_PER_TORSO * TORSO_PX,
            "joint_names": "coco17", "note": "joints/anchor in cut-out pixels (x right, y down)",
            "frames": [], "actions": {}}
    index = {}
    with mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1) as pose:
        for k, i in enumerate(used):
            crop, alpha, _ = crops[i]
            s = scale[i]
            w, h = int(round(crop.shape[1] * s)), int(round(crop.shape[0] * s))
            a = cv2.GaussianBlur(alpha.astype(np.float32), (3, 3), 0.6)
            crop_r = cv2.resize(crop, (w, h), interpolation=cv2.INTER_AREA)
            a_r = np.clip(cv2.resize(a, (w, h), interpolation=cv2.INTER_AREA) + 0.5, 0, 255).astype(np.uint8)
            # tight crop of the resized cut-out (a few px margin)
            ys, xs = np.nonzero(a_r > 8)
            x0, x1 = max(xs.min() - 6, 0), min(xs.max() + 7, w)
            y0, y1 = max(ys.min() - 6, 0), min(ys.max() + 7, h)
            bgra = np.dstack([crop_r, a_r])[y0:y1, x0:x1].copy()
            bgra[..., :3][bgra[..., 3] == 0] = 0
            # the joints are measured again on the final cut-out (what the renderer draws)
            pad = 40
            tex = cv2.copyMakeBorder(bgra, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0)
            lm = _pose_on_cutout(pose, tex[..., :3], tex[..., 3])
            if lm is None:
                raise RuntimeError(f"{name}: no pose on the cut-out of source frame {i}")  # never seen
            j = lm[COCO_FROM_BLAZE]
            fname = f"{name}_{k:02d}.png"
            cv2.imwrite(str(out / fname), bgra, [cv2.IMWRITE_PNG_COMPRESSION, 9])
            index[i] = k
            meta["frames"].append({
                "file": fname, "source_frame": int(i), "size_px": [int(bgra.shape[1]), int(bgra.shape[0])],
                "joints_px": [[round(float(x - pad), 2), round(float(y - pad), 2)] for x, y in j[:, :2]],
                "visibility": [round(float(v), 3) for v in j[:, 3]],
            })
    # ground contact: the ground lies a sole below the lowest ankle (a stance foot's ankle), taken
    # as the lowest over +-6 frames of the same action; the sole (ankle to the ground point of a
    # billboard) is the juggler's, measured on his standing cut-outs (SOLE_PER_TORSO). The lowest
    # mask pixel is not used: a pointed foot or a leg stretched towards a high camera reaches far
    # below the ground (the dancer's toes: 0.7 torso below her ankles). A frame whose lowest ankle
    # is higher than that by > 6 % of the height (more than rising onto the toes) is airborne.
    H = meta["height_px_standing"]
    for aname, a in actions.items():
        ks = [index[i] for i in a["source_frames"]]
        fr = [meta["frames"][k] for k in ks]
        hip = [(f["joints_px"][11][1] + f["joints_px"][12][1]) / 2 for f in fr]
        d = [max(f["joints_px"][15][1], f["joints_px"][16][1]) - h for f, h in zip(fr, hip)]
        for n, f in enumerate(fr):
            g = max(d[max(0, n - 6):n + 7])
            jx = f["joints_px"]
            # the ground point lies under the hips (the pelvis, near the centre of mass), not between
            # the ankles: anchored at the ankles, a swinging leg pushed the whole body to and fro on
            # the ground (0.38 m in the runner's vault, up to 0.17 m from one cut-out to the next at
            # 24 per second), a jitter no real body has and no camera can follow
            f["anchor_px"] = [round((jx[11][0] + jx[12][0]) / 2, 2), round(hip[n] + g + SOLE_PER_TORSO * TORSO_PX, 2)]
            f["contact"] = bool(d[n] >= g - 0.06 * H)
        meta["actions"][aname] = {"frames": ks, "loop": a["loop"], "fps": a["fps"],
                                  **({"speed_mps": a["speed_mps"]} if "speed_mps" in a else {}),
                                  "source_frames": [int(i) for i in a["source_frames"]]}
    (out / f"{name}.json").write_text(json.dumps(meta, indent=1))
    log.info("%s: %d cut-outs, actions %s", name, len(used), sorted(actions))
    return meta


def _davis(data: Path, clip: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    frames = read_frames(data / f"davis_{clip}_854x480.mp4")
    masks = [cv2.imread(str(data / f"davis_{clip}_masks" / f"{i:05d}.png"), cv2.IMREAD_GRAYSCALE) > 0
             for i in range(len(frames))]
    return frames, masks


def make_dancer(data: Path, out: Path) -> None:
    frames, masks = _davis(data, "dance-twirl")
    # every other frame (12 fps) keeps the assets small. Frames 12-16 (a fast leg swing) are left
    # out of the dance: their motion blur reads as defocus to the detector's focus estimate
    # (43-73 % of her pixels judged sharp against 81-94 % in frames 0-10, measured rendered at
    # 460 px on the forest backdrop; the juggler's frames: 84-99 %).
    make = {"dance": {"source_frames": list(range(0, 11, 2)), "loop": "pingpong", "fps": 12.0},
            "twirl": {"source_frames": list(range(18, 35, 2)), "loop": "pingpong", "fps": 12.0}}
    cut_subject("dancer", frames, masks, make, out, LIBRARY["dancer"])


def make_runner(data: Path, out: Path) -> None:
    frames, masks = _davis(data, "parkour")
    # run: 13 frames of running (one stride and a half); natural speed from cadence and a running
    # step of 0.65 x height: ~ 2 steps in 13 frames at 24 fps -> 3.7 steps/s x 1.17 m = 4.3 m/s
    make = {"run": {"source_frames": list(range(0, 13, 2)), "loop": "pingpong", "fps": 12.0, "speed_mps": 4.3},
            "vault": {"source_frames": list(range(20, 28)), "loop": "pingpong", "fps": 24.0}}
    cut_subject("runner", frames, masks, make, out, LIBRARY["runner"])


def _tud_walker(data: Path, track: int) -> tuple[list[np.ndarray], list[np.ndarray], list[int], float]:
    import mediapipe as mp

    frames = read_frames(data / "tud_stadtmitte_640x480.mp4")
    gt = np.loadtxt(data / "tud_stadtmitte_gt.txt", delimiter=",")
    rows = gt[gt[:, 1] == track]
    plate = np.median(np.stack(frames[::4]), axis=0).astype(np.uint8)
    masks = [np.zeros(frames[0].shape[:2], bool) for _ in frames]
    ids = []
    with mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=0) as seg:
        for r in rows:
            i = int(r[0]) - 1
            x, y, w, h = (int(round(v)) for v in r[2:6])
            if x < 2 or x + w > frames[i].shape[1] - 2:
                continue
            box = np.zeros(frames[i].shape[:2], np.uint8)
            box[max(y - 4, 0):y + h + 6, max(x - 6, 0):x + w + 6] = 1
            diff = cv2.absdiff(cv2.GaussianBlur(frames[i], (3, 3), 0), cv2.GaussianBlur(plate, (3, 3), 0)).max(axis=2)
            fg = (diff > 30).astype(np.uint8)
            s = seg.process(cv2.cvtColor(frames[i], cv2.COLOR_BGR2RGB)).segmentation_mask
            core = cv2.dilate((s > 0.4).astype(np.uint8), np.ones((7, 7), np.uint8))
            m = (fg | (s > 0.7)) & core & box
            m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
            n, lab, st, _ = cv2.connectedComponentsWithStats(m)
            if n < 2:
                continue
            big = 1 + int(np.argmax(st[1:, cv2.CC_STAT_AREA]))
            keep = (lab == big).astype(np.uint8)
            # fill holes (dark coat on a dark street) that do not reach the crop's border
            inv = 1 - keep
            n2, lab2 = cv2.connectedComponents(inv)
            border = set(np.unique(np.concatenate([lab2[0], lab2[-1], lab2[:, 0], lab2[:, -1]])).tolist())
            for c in range(1, n2):
                if c not in border:
                    keep[lab2 == c] = 1
            masks[i] = keep > 0
            ids.append(i)
    speed = float(np.linalg.norm(rows[-1, 7:9] - rows[0, 7:9]) / ((rows[-1, 0] - rows[0, 0]) / 25.0))
    return frames, masks, ids, speed


def make_walker(data: Path, out: Path) -> None:
    frames, masks, ids, speed = _tud_walker(data, track=2)
    # one gait cycle (two steps) from the middle of the track, 25 fps: frames 30..54 (the ankles'
    # horizontal separation goes +61 px at 35, -70 px at 48 and back to ~0 at 55 = frame 30)
    cyc = [i for i in ids if 30 <= i < 55]
    make = {"walk": {"source_frames": cyc, "loop": "cycle", "fps": 25.0, "speed_mps": round(speed, 2)}}
    log.info("walker: speed %.2f m/s from the ground-truth world positions", speed)
    cut_subject("walker", frames, masks, make, out, LIBRARY["walker"])


def add_juggler_fields(out: Path) -> None:
    """The juggler's library fields (its cut-outs come from make_assets.make_juggler)."""
    p = out / "juggler.json"
    meta = json.loads(p.read_text())
    n = len(meta["frames"])
    meta.update({"name": "juggler", **LIBRARY["juggler"]})
    meta["actions"] = {"juggle": {"frames": list(range(n)), "loop": "pingpong", "fps": 12.0},
                       "stand": {"frames": [0], "loop": "pingpong", "fps": 12.0}}
    for f in meta["frames"]:
        f["contact"] = True
    p.write_text(json.dumps(meta, indent=1))


MAKERS = {"juggler": add_juggler_fields, "dancer": make_dancer, "runner": make_runner, "walker": make_walker}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=default_data_dir(), help="folder of the real clips")
    p.add_argument("--out", type=Path, default=ASSETS, help="assets folder to write")
    p.add_argument("--only", choices=sorted(MAKERS), action="append")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    for name in args.only or list(MAKERS):
        if name == "juggler":
            add_juggler_fields(args.out)
        else:
            MAKERS[name](args.data, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
