"""`cinetransfer transfer SOURCE_VIDEO --scene SCENE -o OUTDIR`: the whole job.

1. extract the source's style (detector + smoother)            → OUTDIR/style.json
2. bring up the flying half as separate processes over Zenoh   → OUTDIR/deploy/*.log
   (a router, the autopilot bridge with the simulator, the planner) — or use a running
   deployment with `--connect tcp/HOST:PORT` (e.g. after `cinetransfer deploy up local`)
3. publish the instructions, start the recording after a pre-roll, let the planner fly it,
   and record every message                                    → OUTDIR/run.ctlog
   and the camera's frames                                     → OUTDIR/output.mp4
4. stop: the planner stops, the bridge holds; Ctrl-C at any time does the same and keeps
   what was recorded
5. evaluate: the same extraction on the output video           → OUTDIR/output_style.json
   compared with the source and with the simulator's truth    → OUTDIR/report.html, report.json
"""
from __future__ import annotations

import argparse
import json
import logging
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from tqdm import tqdm

from cinetransfer.shared import codec, keys, zenoh_config
from cinetransfer.shared import messages as M
from cinetransfer.shared.node import setup_logging
from cinetransfer.shared.recording import LogWriter

log = logging.getLogger("cinetransfer.transfer")


class TransferError(RuntimeError):
    """A step of the transfer failed; the message says which and where its log is."""


def run_cli(args: list[str], what: str, log_path: Path | None = None) -> None:
    """Run `cinetransfer ARGS` as a child process (progress bars go to the terminal)."""
    cmd = [sys.executable, "-m", "cinetransfer", *args]
    log.info("%s: %s", what, " ".join(args))
    rc = subprocess.call(cmd)
    if rc != 0:
        raise TransferError(f"{what} failed (exit {rc}): cinetransfer {' '.join(args)}")


class Recorder:
    """Subscribes to everything of the rig: logs every message; writes the output video and truth."""

    def __init__(self, session, rig: str, outdir: Path, meta: dict) -> None:
        self.rig, self.outdir = rig, outdir
        self.log = LogWriter(outdir / "run.ctlog", meta)
        self.lock = threading.Lock()
        self.window: tuple[int, int] | None = None  # [t0_ns, t1_ns) of the recording, by frame stamp
        self.frames: list[tuple[int, np.ndarray]] = []  # (stamp, image) of frames in the window, in order
        self.truths: list[M.GroundTruth] = []
        self.latest: dict[str, object] = {}
        self.health: dict[str, M.Health] = {}
        self.frame_key = keys.FRAME.key(rig)
        self.truth_key = keys.SIM_TRUTH.key(rig)
        self._video = None
        self._last_img: np.ndarray | None = None
        self.n_video = 0
        self.repeated = 0
        self.late = 0
        self.undecodable = 0
        self.interrupted = False
        self._sub = session.declare_subscriber(keys.everything(rig), self._on)

    def _on(self, sample) -> None:  # Zenoh thread: decode only what is needed, write the log
        key, payload = str(sample.key_expr), sample.payload.to_bytes()
        self.log.write(key, payload)
        if key == self.frame_key or key == self.truth_key or "/health/" in key or key.endswith("/state") \
                or key.endswith("/setpoint"):
            try:
                msg = codec.decode(payload)
            except codec.DecodeError:
                self.undecodable += 1
                return
            with self.lock:
                self.latest[key] = msg
                if isinstance(msg, M.Health):
                    self.health[msg.node] = msg
                elif self.window is not None and self.window[0] <= msg.stamp_ns < self.window[1]:
                    slot = int(round((msg.stamp_ns - self.window[0]) * 1e-9 * self.fps))
                    if slot >= self.n_slots:
                        return
                    if isinstance(msg, M.Frame):
                        self._write_frame(slot, np.array(msg.image))
                    elif isinstance(msg, M.GroundTruth):
                        self._add_truth(slot, msg)

    def _write_frame(self, slot: int, img: np.ndarray) -> None:
        """Write the frame at its time slot; a slot the simulator skipped (it renders in real
        time and drops late frames) repeats the previous frame, as a constant-rate recorder
        would, so that video frame k is exactly instruction frame k. Repeats are counted."""
        import cv2

        if self._video is None:
            h, w = img.shape[:2]
            self._video = cv2.VideoWriter(str(self.outdir / "output.mp4"), cv2.VideoWriter_fourcc(*"mp4v"),
                                          self.fps, (w, h))
        if slot < self.n_video:  # two frames in one slot (clock jitter): keep the first
            self.late += 1
            return
        if self._last_img is None:
            self._last_img = img  # a take that starts between two renders opens on the first one
        while self.n_video < slot:
            self._video.write(self._last_img)
            self.n_video += 1
            self.repeated += 1
        self._video.write(img)
        self._last_img = img
        self.n_video += 1

    def _add_truth(self, slot: int, truth: M.GroundTruth) -> None:
        """Truth of each video frame: a repeated frame shows the previous render, so it gets that
        render's truth."""
        if slot < len(self.truths):
            return
        while len(self.truths) < slot:
            self.truths.append(replace(self.truths[-1] if self.truths else truth, frame_index=len(self.truths)))
        self.truths.append(replace(truth, frame_index=slot))

    def start_window(self, t0_ns: int, duration_s: float, fps: float) -> None:
        with self.lock:
            self.fps = fps
            self.n_slots = int(round(duration_s * fps))
            self.window = (t0_ns, t0_ns + int(duration_s * 1e9))

    def close(self) -> None:
        self._sub.undeclare()
        with self.lock:
            if self._video is not None:
                self._video.release()
            self.window = None
        self.log.close()


def _deploy_config(outdir: Path, port: int, rig: str, scene: str) -> Path:
    """A deploy config for this run: a router on `port`, the simulator bridge and the planner."""
    cfg = {
        "description": "generated by cinetransfer transfer",
        "rig": rig,
        "routers": [{"name": "router", "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]}}],
        "defaults": {"zenoh": {"mode": "client", "connect": [f"tcp/127.0.0.1:{port}"], "shm": True}},
        "nodes": [
            {"name": "autopilot_bridge", "command": "autopilot_bridge",
             "args": ["--backend", "sim", "--scene", scene]},
            {"name": "planner", "command": "planner", "args": []},
        ],
        "restart": {"backoff_initial_s": 0.5, "stop_grace_s": 10, "startup_timeout_s": 180},
    }
    path = outdir / "deploy" / "transfer.yaml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return path


def _wait_alive(session, rig: str, names: set[str], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    seen: set[str] = set()
    while time.monotonic() < deadline:
        seen = {str(r.ok.key_expr).rsplit("/", 1)[-1] for r in session.liveliness().get(keys.all_alive(rig), timeout=1.0)
                if r.ok is not None}
        if names <= seen:
            return
        time.sleep(0.2)
    raise TransferError(f"nodes not alive after {timeout:.0f}s: {', '.join(sorted(names - seen))}")


def fly(style: M.Instructions, *, outdir: Path, session, rig: str, preroll_s: float, margin_s: float,
        meta: dict) -> Recorder:
    """Publish the instructions, start after the pre-roll, record the take, stop."""
    rec = Recorder(session, rig, outdir, meta)
    k = style.image_targets.shape[0]
    duration = k / style.fps
    instr_pub = session.declare_publisher(keys.INSTRUCTIONS.key(rig))
    cmd_pub = session.declare_publisher(keys.PLANNER_COMMAND.key(rig))
    instr_pub.put(codec.encode(replace(style, stamp_ns=M.now_ns(), final=True)))
    time.sleep(0.5)

    def command(action: str, **args) -> None:
        cmd_pub.put(codec.encode(M.Command(stamp_ns=M.now_ns(), action=action, args=args)))

    try:
        # Pre-roll: 'start' then 'pause' makes the planner frame instruction 0 without the clock
        # running, so the drone settles on the first frame's framing before the take begins.
        command("start", start_frame=0)
        command("pause")
        log.info("pre-roll: settling on frame 0 for %.1f s", preroll_s)
        time.sleep(preroll_s)
        t0 = M.now_ns()
        rec.start_window(t0, duration, style.fps)
        command("resume")
        with tqdm(total=k, desc="recording", unit="frame") as bar:
            end = time.monotonic() + duration + margin_s
            while time.monotonic() < end:
                time.sleep(0.1)
                bar.n = min(rec.n_video, k)
                bar.refresh()
                if rec.n_video >= k:
                    break
    except KeyboardInterrupt:
        rec.interrupted = True
        log.warning("interrupted: stopping the vehicle and keeping what was recorded")
    finally:
        # Whatever happened: the planner stops (it then commands a hold) and the bridge is told
        # to hold too, before the recording is closed.
        command("stop")
        session.declare_publisher(keys.BRIDGE_COMMAND.key(rig)).put(
            codec.encode(M.Command(stamp_ns=M.now_ns(), action="hold")))
        time.sleep(0.3)
        rec.close()
        instr_pub.undeclare()
        cmd_pub.undeclare()
    return rec


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="cinetransfer transfer", description=__doc__.splitlines()[0])
    p.add_argument("source", help="source video (anything OpenCV decodes)")
    p.add_argument("--scene", default="open_country", help="simulator scene name or YAML file (default %(default)s)")
    p.add_argument("-o", "--outdir", required=True, help="output folder")
    p.add_argument("--rig", default="transfer", help="rig name (default %(default)s)")
    p.add_argument("--preroll", type=float, default=5.0, help="seconds to settle on frame 0 before recording")
    p.add_argument("--max-frames", type=int, default=0, help="use only the first N frames of the source (0 = all)")
    p.add_argument("--style", help="use this style.json instead of extracting one")
    p.add_argument("--no-eval", action="store_true", help="skip extraction on the output and the report")
    p.add_argument("--log-level", default="INFO")
    zenoh_config.add_arguments(p)
    args = p.parse_args(argv)
    setup_logging(args.log_level)
    src = Path(args.source)
    out = Path(args.outdir)
    if not src.is_file():
        print(f"cinetransfer transfer: source video {src} does not exist", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.monotonic()
    timings: dict[str, float] = {}
    meta: dict = {"source": str(src), "scene": args.scene, "rig": args.rig, "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    try:
        # 1. style
        t = time.monotonic()
        style_path = out / "style.json"
        if args.style:
            shutil.copyfile(args.style, style_path)
        else:
            extra = ["--stop", str(args.max_frames)] if args.max_frames else []
            run_cli(["extract", str(src), "-o", str(style_path), *extra], "style extraction")
        from cinetransfer.services.smoother.instructions import load_style

        style = load_style(style_path)
        timings["extract_source_s"] = time.monotonic() - t
        # 2. processes
        t = time.monotonic()
        deploy_dir = out / "deploy"
        if args.connect:
            opts = zenoh_config.options_from_args(args, mode="client")
            cfg_path = None
        else:
            port = zenoh_config.free_tcp_port()
            cfg_path = _deploy_config(out, port, args.rig, args.scene)
            run_cli(["deploy", "up", str(cfg_path), "--run-dir", str(deploy_dir)], "starting nodes")
            opts = zenoh_config.ZenohOptions(mode="client", connect=(f"tcp/127.0.0.1:{port}",), shared_memory=True)
        try:
            with zenoh_config.open_session(opts) as session:
                _wait_alive(session, args.rig, {"planner", "autopilot_bridge"}, 180)
                timings["start_nodes_s"] = time.monotonic() - t
                t = time.monotonic()
                rec = fly(style, outdir=out, session=session, rig=args.rig, preroll_s=args.preroll, margin_s=5.0,
                          meta=meta)
                timings["flight_s"] = time.monotonic() - t
                meta["health"] = {n: {"received": h.received, "rejected": h.rejected, "dropped": h.dropped,
                                      "published": h.published, "counters": h.counters}
                                  for n, h in rec.health.items()}
        finally:
            if cfg_path is not None:
                run_cli(["deploy", "down", str(cfg_path), "--run-dir", str(deploy_dir)], "stopping nodes")
        meta.update(recorded_frames=rec.n_video, repeated_frames=rec.repeated, truth_frames=len(rec.truths),
                    logged_messages=rec.log.count, output_fps=style.fps,
                    instruction_frames=int(style.image_targets.shape[0]), fps=style.fps,
                    interrupted=rec.interrupted)
        from cinetransfer.report.truthfile import write_truths

        write_truths(out / "truth.msgpack", rec.truths)
        if rec.n_video == 0:
            raise TransferError("no frames were recorded (see OUTDIR/deploy/*.log)")
        if meta["interrupted"] or args.no_eval:
            (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str))
            print(f"recorded {rec.n_video} frames to {out / 'output.mp4'} (no evaluation)")
            return 130 if meta["interrupted"] else 0
        # 5. evaluation
        t = time.monotonic()
        out_style = out / "output_style.json"
        try:
            run_cli(["extract", str(out / "output.mp4"), "-o", str(out_style)], "extraction on the output")
        except TransferError as e:
            log.error("%s", e)
            out_style = None
        timings["extract_output_s"] = time.monotonic() - t
        timings["total_s"] = time.monotonic() - t_start
        meta["timings"] = timings
        meta["credit"] = _credit(src)
        (out / "meta.json").write_text(json.dumps(meta, indent=2, default=str))
        from cinetransfer.report import build_report

        summary = build_report(out, source_style=style_path, output_style=out_style, truths=rec.truths,
                               source_video=src, output_video=out / "output.mp4", meta=meta)
    except (TransferError, ValueError, OSError) as e:
        print(f"cinetransfer transfer: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # outside the flight (extraction, start-up): nothing is flying yet
        print(f"cinetransfer transfer: interrupted; what was written is in {out}", file=sys.stderr)
        return 130
    print(json.dumps(summary.get("headline", summary), indent=2, default=str)[:3000])
    print(f"\nreport: {(out / 'report.html').resolve()}  ({timings['total_s']:.0f} s in all)")
    return 0


def _credit(src: Path) -> str:
    """The credit line of a bundled clip from its MANIFEST (empty for other videos)."""
    manifest = src.resolve().parent / "MANIFEST.md"
    if not manifest.is_file():
        return ""
    for line in manifest.read_text().splitlines():
        if line.startswith("|") and f"`{src.name}`" in line:
            cells = [c.strip() for c in line.strip("|").split("|")]
            return f"{src.name}: {cells[3]}" if len(cells) > 3 else ""
    return ""
