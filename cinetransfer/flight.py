"""The flight of a transfer: the takes of the style flown against a running deployment and
recorded, then stopped whatever happens (Ctrl-C included).

In simulation time (the default) the simulation restarts at a fresh time zero, the planner
starts each take exactly on schedule (a settle phase on the shot's first frame, then its frames)
and the bridge steps only when the planner's setpoint for the step has arrived, so every camera
frame exists; on the wall clock (`--realtime`) skipped frames are repeated, counted, reported.
"""
from __future__ import annotations

import logging
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

from cinetransfer.job import TransferError, await_subscriber
from cinetransfer.recorder import Recorder, RecorderHang, Take, Window
from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.shared.node import Presence
from cinetransfer.shared.stopsignal import StopSignal
from cinetransfer.take import TakeSummary, require_complete
from cinetransfer.waiting import wait_while_moving

log = logging.getLogger("cinetransfer.transfer")
LIVELINESS_LOOK_S = 0.5  # how often the take looks at the bridge's liveliness between frames


class Conductor:
    """Sends the take's commands to the planner and the bridge of a rig."""

    def __init__(self, session, rig: str) -> None:
        self.planner = session.declare_publisher(keys.PLANNER_COMMAND.key(rig))
        self.bridge = session.declare_publisher(keys.BRIDGE_COMMAND.key(rig))
        self.instructions = session.declare_publisher(keys.INSTRUCTIONS.key(rig))

    def to_planner(self, action: str, **args) -> None:
        self.planner.put(codec.encode(M.Command(stamp_ns=M.now_ns(), action=action, args=args)))

    def to_bridge(self, action: str, **args) -> None:
        self.bridge.put(codec.encode(M.Command(stamp_ns=M.now_ns(), action=action, args=args)))

    def stop(self, sim_time: bool) -> None:
        """Whatever happened: the planner stops (it then commands a hold), the bridge holds, and a
        simulation goes back to real-time pace."""
        self.to_planner("stop")
        self.to_bridge("hold")
        if sim_time:
            self.to_bridge("clock", pace=1.0)

    def await_nodes(self, timeout: float) -> None:
        """Wait until the planner and the bridge listen (call it before this session subscribes to
        their keys itself: a subscriber of our own would match as well)."""
        for what, pub in (("planner", self.planner), ("planner", self.instructions), ("autopilot_bridge", self.bridge)):
            if not await_subscriber(pub, timeout):
                raise TransferError(f"the {what} node does not listen for commands (see OUTDIR/deploy/{what}.log)")

    def undeclare(self) -> None:
        for p in (self.planner, self.bridge, self.instructions):
            p.undeclare()


def _progress(rec: Recorder, k: int, stall_s: float, *, what: str, bridge: Presence | None = None,
              steps_count: bool = False) -> None:
    """Wait until the take's k frames are recorded, with a progress bar; TransferError at once
    when the bridge's liveliness token goes away (it died: its simulation is lost), or when
    nothing moves on for `stall_s` wall seconds (a node hangs): no frame arrives, nor, with
    `steps_count` (simulation time), a simulation step. The pre-roll and settle phases step
    without frames: a 60 s pre-roll took more than 300 s on a loaded machine."""
    losses = bridge.losses if bridge is not None else 0

    def moved() -> tuple:
        return rec.frames_written, (rec.last_clock.stamp_ns if steps_count and rec.last_clock else None)

    def ended() -> bool:
        return rec.frames_written >= k or rec.failure is not None or rec.lost is not None

    def wait(s: float) -> None:
        seen = moved()
        rec.wait(lambda: moved() != seen or ended(), s)

    with tqdm(total=k, desc="recording", unit="frame", disable=None) as bar:
        def check() -> None:
            if bridge is not None and bridge.losses != losses:
                raise TransferError(f"{what}: the autopilot_bridge node died after {rec.frames_written} of {k} "
                                    "frames (its liveliness token went away); what was recorded is kept in OUTDIR "
                                    "(see OUTDIR/deploy/autopilot_bridge.log)")
            bar.n = min(rec.frames_written, k)
            bar.refresh()
        moving = wait_while_moving(ended, moved, stall_s, wait=wait, look_s=min(LIVELINESS_LOOK_S, stall_s),
                                   check=check)
    n = rec.frames_written
    if not moving:
        raise TransferError(f"{what}: no frame{' nor step' if steps_count else ''} for {stall_s:.0f} s "
                            f"after {n} of {k} (see OUTDIR/deploy/*.log)")
    if rec.failure is not None:
        raise TransferError(_write_failure(rec, n, k))
    if rec.lost is not None:
        slot, index = rec.lost
        raise TransferError(f"{what}: camera frame {index} (slot {slot} of {k}) was lost between the "
                            "autopilot_bridge and this transfer (a later frame or its truth came); the take "
                            f"stops after {n} of {k} frames; what was recorded is kept")


def _write_failure(rec: Recorder, n: int, k: int) -> str:
    e = rec.failure
    what = f"{e.strerror or e}" + (f" ({e.filename})" if getattr(e, "filename", None) else "")
    kept = "closed readable" if rec.closed_cleanly else "not all of it could be closed (see the log)"
    return f"cannot write the recording: {what}; it stopped after {n} of {k} frames, {kept}, in OUTDIR"


def shot_schedule(style: M.Instructions, *, preroll_s: float, settle_s: float, one_take: bool,
                  min_take_s: float = 0.5) -> list[dict]:
    """The takes of the flight, in camera frames since time zero (camera rate = instruction rate):
    one per shot of the source (one for all with `one_take`), each after a settle phase (the
    first after the pre-roll) in which the planner frames the shot's first instruction frame.
    A shot shorter than `min_take_s` (a flash cut, frames of a morph) is filmed on in the take
    before it: a re-framing pause for a few frames would cost more than it gives."""
    from cinetransfer.shared.instructions import shot_segments

    fps = float(style.fps)
    k = style.image_targets.shape[0]
    shots = [(0, k)] if one_take else merge_short(shot_segments(style), int(round(min_take_s * fps)))
    t, out = 0, []
    for i, (a, b) in enumerate(shots):
        settle = int(round((preroll_s if i == 0 else settle_s) * fps))
        out.append({"shot": i, "first_row": a, "end_row": b, "settle_start_index": t, "first_index": t + settle,
                    "settle_frames": settle, "settle_limit_s": settle / fps})
        t += settle + (b - a)
    return out


def merge_short(segments: list[tuple[int, int]], min_len: int) -> list[tuple[int, int]]:
    """Join every segment shorter than `min_len` rows to the one before it (the first to the next)."""
    out: list[list[int]] = []
    for a, b in segments:
        if out and b - a < min_len:
            out[-1][1] = b
        elif out and out[-1][1] - out[-1][0] < min_len:
            out[-1][1] = b  # a short first segment joins the next
        else:
            out.append([a, b])
    return [(a, b) for a, b in out]


def fly_sim_time(style: M.Instructions, rec: Recorder, cond: Conductor, *, preroll_s: float, settle_s: float,
                 one_take: bool, stall_s: float, pace: float = 0.0, min_take_s: float = 0.5,
                 bridge: Presence | None = None) -> dict:
    """The flight in simulation time: reset the simulation to a fresh time zero, let the planner
    start each take exactly on schedule (a settle phase on its first frame, then its frames),
    record every frame of every take; the edit joins the takes at the source's cuts."""
    k = style.image_targets.shape[0]
    fps = float(style.fps)
    epoch = _flight_epoch(rec, cond)
    takes = shot_schedule(style, preroll_s=preroll_s, settle_s=settle_s, one_take=one_take, min_take_s=min_take_s)
    _schedule_takes(style, rec, cond, takes, epoch)
    rec.arm(Window(exact=True, n_slots=k, fps=fps, epoch_ns=epoch,
                   takes=tuple(Take(t["first_index"], t["first_row"], t["end_row"] - t["first_row"]) for t in takes)))
    log.info("simulation time: %d take(s) of %s frames at %.3g fps, settling %s frames before each", len(takes),
             "/".join(str(t["end_row"] - t["first_row"]) for t in takes), fps,
             "/".join(str(t["settle_frames"]) for t in takes))
    # only the takes' frames are recorded: the settle phases' frames are not rendered (their truth is kept)
    pictures = [[t["first_index"], t["first_index"] + t["end_row"] - t["first_row"]] for t in takes]
    cond.to_bridge("reset", epoch_ns=epoch, fps=fps, pace=float(pace), pictures=pictures)
    _progress(rec, k, stall_s, what="simulation", bridge=bridge, steps_count=True)
    return {"clock": "simulation (lockstep)", "epoch_ns": epoch, "preroll_frames": takes[0]["settle_frames"],
            "takes": takes, "one_take": one_take}


def _flight_epoch(rec: Recorder, cond: Conductor) -> int:
    """Time zero of the flight [ns]: far ahead of the running simulation clock, so it is never
    reached before the reset. The idle simulation may step only every few seconds (the own
    deployment's slow idle pace): the bridge is asked for a step until a tick arrives (one
    published before this session's subscription reached the router is lost)."""
    if not _await_stepping(rec, cond, lambda: rec.last_clock is not None, 30.0):
        raise TransferError("the bridge publishes no simulation clock (is it a --realtime bridge? "
                            "then run transfer with --realtime)")
    return max(M.now_ns(), rec.last_clock.stamp_ns) + 600 * 10**9


def _await_stepping(rec: Recorder, cond: Conductor, predicate, timeout: float) -> bool:
    """Wait until `predicate()` holds, asking the bridge for a step (a 'clock' command without a
    pace: it ends the bridge's pacing sleep) every second meanwhile; False after `timeout` s."""
    deadline = time.monotonic() + timeout
    while not predicate():
        left = deadline - time.monotonic()
        if left <= 0:
            return False
        cond.to_bridge("clock")
        rec.wait(predicate, min(1.0, left))
    return True


def _schedule_takes(style: M.Instructions, rec: Recorder, cond: Conductor, takes: list[dict], epoch: int) -> None:
    """Tell the planner when each take starts (simulation time) and wait until it says it has them all."""
    fps = float(style.fps)
    cond.to_planner("stop")
    for tk in takes:
        at = epoch + int(round(tk["settle_start_index"] / fps * 1e9))
        cond.to_planner("start", start_frame=int(style.first_frame) + tk["first_row"],
                        end_frame=int(style.first_frame) + tk["end_row"], preroll_s=tk["settle_frames"] / fps, at_ns=at)
    last_at = epoch + int(round(takes[-1]["settle_start_index"] / fps * 1e9))

    def acknowledged() -> bool:
        h = rec.health.get("planner")
        return h is not None and h.counters.get("sim_time") is True and \
            h.counters.get("scheduled") == len(takes) and h.counters.get("scheduled_at_ns") == last_at

    if not _await_stepping(rec, cond, acknowledged, 60.0):  # the planner reads commands on a tick
        raise TransferError("the planner did not acknowledge the scheduled takes (is it following the "
                            "simulation clock? see OUTDIR/deploy/planner.log)")


def fly_realtime(style: M.Instructions, rec: Recorder, cond: Conductor, *, preroll_s: float,
                 stall_s: float, bridge: Presence | None = None, **_unused) -> dict:
    """The take on the wall clock (a --realtime simulator or a real vehicle): frames are slotted
    by their stamp; a slot the camera skipped repeats the previous frame (counted, reported)."""
    k = style.image_targets.shape[0]
    # 'start' then 'pause' makes the planner frame instruction 0 without the clock running
    cond.to_planner("start", start_frame=0)
    cond.to_planner("pause")
    log.info("pre-roll: settling on frame 0 for %.1f s (wall clock)", preroll_s)
    time.sleep(preroll_s)
    rec.arm(Window(exact=False, n_slots=k, fps=float(style.fps), t0_ns=M.now_ns()))
    cond.to_planner("resume")
    try:
        _progress(rec, k, min(stall_s, k / style.fps + 5.0), what="real-time take", bridge=bridge)
    except TransferError as e:
        log.error("%s", e)  # judged with the take below: a short take exits non-zero
    return {"clock": "wall (real time)"}


def _already_stopping(_signum, _frame) -> None:
    print("cinetransfer transfer: already stopping (vehicle told to hold); saving the recording ...",
          file=sys.stderr)


def fly(style: M.Instructions, *, outdir: Path, session, rig: str, preroll_s: float, realtime: bool,
        stall_s: float, meta: dict, publish_instructions: bool = True, settle_s: float = 3.0,
        one_take: bool = False, pace: float = 0.0, min_take_s: float = 0.5, on_frame=None) -> Recorder:
    """Fly and record the take, stop; Ctrl-C stops the vehicle too. The planner has the smoother's
    instructions already; a style given as a file is published here (`publish_instructions`).
    `on_frame(slot, image)` sees every frame of the take as it is recorded."""
    cond = Conductor(session, rig)
    try:
        cond.await_nodes(30.0)
    except TransferError:
        cond.undeclare()
        raise
    rec = Recorder(session, rig, outdir, meta, on_frame=on_frame)
    bridge = Presence(session, rig, "autopilot_bridge")  # its death is seen at once, not after the stall timeout
    if publish_instructions:
        cond.instructions.put(codec.encode(replace(style, stamp_ns=M.now_ns(), final=True)))
        time.sleep(0.3)
    try:
        how = (fly_realtime if realtime else fly_sim_time)(style, rec, cond, preroll_s=preroll_s, stall_s=stall_s,
                                                           settle_s=settle_s, one_take=one_take, pace=pace,
                                                           min_take_s=min_take_s, bridge=bridge)
        meta.update(how)
    except TransferError as e:
        e.flight = (style, rec)  # what was recorded is saved by the caller before it reports the error
        raise
    except KeyboardInterrupt:
        rec.interrupted = True
        # from here on Ctrl-C only says what is happening: the vehicle is told to hold, the nodes
        # are stopped and the recording saved whatever the user presses
        signal.signal(signal.SIGINT, _already_stopping)
        log.warning("interrupted: stopping the vehicle and keeping what was recorded")
    finally:
        held = StopSignal().install((signal.SIGINT,))  # the stop is never cut short; a Ctrl-C now is kept
        try:
            cond.stop(sim_time=not realtime)
            time.sleep(0.3)
            try:
                rec.summaries = rec.close()
            except RecorderHang as e:
                raise TransferError(str(e)) from None
            cond.undeclare()
            bridge.undeclare()
        finally:
            held.restore()
        if held.is_set() and not rec.interrupted:
            rec.interrupted = True
            log.warning("interrupted as the take closed: the recording is kept, nothing is evaluated")
    return rec


def take_meta(rec: Recorder, style: M.Instructions, realtime: bool) -> dict:
    """What the recording holds, stated plainly (repeats, missing frames), for meta.json and the report."""
    frames, truths = rec.summaries
    k = int(style.image_targets.shape[0])
    fs = frames or TakeSummary(k)
    return {"recorded_frames": fs.written, "instruction_frames": k, "fps": style.fps, "output_fps": style.fps,
            "repeated_frames": len(fs.repeated_slots), "repeated_slots": fs.repeated_slots,
            "repeated_share": round(len(fs.repeated_slots) / k, 4) if k else 0.0,
            "missing_frames": len(fs.missing_slots), "duplicate_frames": fs.duplicates, "late_frames": fs.late,
            "truth_frames": 0 if truths is None else truths.written, "logged_messages": rec.log.count,
            "clock_mode": "realtime" if realtime else "lockstep", "interrupted": rec.interrupted}


def check_take(meta: dict, rec: Recorder, realtime: bool) -> None:
    """A take that is not the instructions' length is an error (never a silent partial result)."""
    frames, truths = rec.summaries
    if frames is None:
        raise TransferError("the take never started (see OUTDIR/deploy/*.log)")
    if not realtime:
        require_complete(frames, "frames")
        require_complete(truths, "ground-truth records")
    elif frames.written < frames.n_slots:
        raise TransferError(f"the real-time take is short: {frames.written} of {frames.n_slots} instruction "
                            f"frames were recorded ({meta['repeated_frames']} of them repeats); "
                            "output.mp4 and the truth are kept in OUTDIR")
