"""End to end, through real processes over Zenoh: a short excerpt of a real clip is
extracted, flown by the planner against the simulator bridge (separate processes started by
the deploy supervisor), recorded, re-extracted and reported. The report's numbers must be
the ones computed from this run's own recording."""
import json
import subprocess
import sys

import numpy as np
import pytest

from cinetransfer.report.truthfile import read_truths
from cinetransfer.shared.instructions import load_style
from cinetransfer.shared import codec, keys
from cinetransfer.shared import messages as M
from cinetransfer.runlog import RunReader, read_run, size_report
from cinetransfer.shared.video import probe

FRAMES = 36  # 1.5 s of the 24 fps clip


def video_frames(path) -> list[np.ndarray]:
    import cv2

    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            cap.release()
            return out
        out.append(img)


def observer_session(out, proc, going):
    """A Zenoh session on the transfer's own deployment as its read-only observer, opened as soon as
    its router listens (the credentials exist a moment before it does); `going()`: keep waiting."""
    import time

    from cinetransfer.deploy import join
    from cinetransfer.shared import zenoh_config

    while not (out / "deploy" / "secrets" / "users.txt").is_file():
        assert going(), "the transfer ended (or stood still) before its deployment came up"
        time.sleep(0.1)
    opts = join.deployment_options(out / "deploy" / "transfer.yaml", "observer", run_dir=out / "deploy")
    while True:
        assert going(), "the transfer ended (or stood still) before its router came up"
        try:
            return zenoh_config.open_session(opts)
        except Exception:  # noqa: BLE001 - zenoh.ZError: not listening yet
            time.sleep(0.2)


def still_going(proc, moving, idle: float = 120.0, limit: float = 900.0):
    """A check for a wait on a running transfer: true while it runs and `moving()` or the transfer's
    CPU time has changed within `idle` seconds, for at most `limit` seconds in all. A loaded machine
    gets the time its work takes; a transfer that stands still is caught (one whose node hangs
    mid-take ends by itself: no frame for its stall time)."""
    import time

    from conftest import cpu_seconds

    start = time.monotonic()
    moved = {"at": start, "what": None}

    def going() -> bool:
        now, what = time.monotonic(), (moving(), cpu_seconds(proc))
        if what != moved["what"]:
            moved.update(at=now, what=what)
        return proc.poll() is None and now - moved["at"] < idle and now - start < limit
    return going


def wait_for_take(out, rig: str, proc, seconds_in: float) -> float:
    """Block until the transfer's simulation has run `seconds_in` simulated seconds past its reset
    (seen on the bus as the deployment's observer); returns how far it was."""
    import time

    seen = {"t": -1.0}
    going = still_going(proc, lambda: seen["t"])

    def on_clock(sample):
        clk = codec.decode(sample.payload.to_bytes(), M.SimClock)
        if clk.epoch_ns > M.now_ns() + 300 * 10**9:  # the transfer's time zero lies far ahead of the wall clock
            seen["t"] = max(seen["t"], (clk.stamp_ns - clk.epoch_ns) * 1e-9)

    with observer_session(out, proc, going) as session:
        sub = session.declare_subscriber(keys.SIM_CLOCK.key(rig), on_clock)
        try:
            while seen["t"] < seconds_in:
                assert going(), "the take ended (or stood still) before the interrupt"
                time.sleep(0.05)
        finally:
            sub.undeclare()
    return seen["t"]


def busy_cores(n: int = 2) -> list[subprocess.Popen]:
    """Processes that keep the machine's cores busy (the CI machine has 2)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def replayed_frames(path, port, listener_opts, last_index: int) -> None:
    import threading

    from cinetransfer.shared import zenoh_config
    from conftest import connect_flags, cpu_seconds, spawn, wait_for

    got: list[M.Frame] = []
    lock = threading.Lock()
    with zenoh_config.open_session(listener_opts) as s:
        def on(sample):
            with lock:
                got.append(codec.decode(sample.payload.to_bytes(), M.Frame))
        sub = s.declare_subscriber(keys.FRAME.key("again"), on)
        proc = spawn("replay", str(path), "--rig", "again", "--speed", "4", "--only", "camera/frame",
                     *connect_flags(port))
        try:
            # a loaded machine starts the replay and passes its frames slowly: what must not happen is
            # two minutes of neither a frame nor the replay's CPU moving on
            wait_for(lambda: any(f.index == last_index for f in got), timeout=120, what="replayed frames",
                     progress=lambda: (len(got), cpu_seconds(proc), proc.poll()), limit=600)
        finally:
            assert proc.wait(60) == 0
        sub.undeclare()
    assert got[-1].image.shape == (540, 960, 3)


@pytest.mark.slow
def test_take_is_frame_exact_and_reproducible_on_a_loaded_machine(data, tmp_path):
    # given one style, flown twice in the same scene: once on a quiet machine, once while two
    # other processes keep both cores busy
    def fly(name: str, *extra: str) -> tuple[dict, list, list]:
        out = tmp_path / name
        r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                            "--scene", "lawn_juggler_25d", "-o", str(out), "--max-frames", str(FRAMES),
                            "--preroll", "1", "--rig", name, "--no-eval", *extra], capture_output=True, text=True,
                           timeout=900)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
        return json.loads((out / "meta.json").read_text()), read_truths(out / "truth.msgpack"), \
            video_frames(out / "output.mp4")

    quiet = fly("quiet")
    load = busy_cores()
    try:
        loaded = fly("loaded", "--style", str(tmp_path / "quiet" / "style.json"))
    finally:
        for p in load:
            p.kill()
            p.wait()
    # then both records hold every instruction frame exactly once, nothing repeated
    for meta, truths, frames in (quiet, loaded):
        assert meta["recorded_frames"] == FRAMES == meta["instruction_frames"] == len(frames) == len(truths)
        assert meta["repeated_frames"] == 0 and meta["missing_frames"] == 0
        assert not [k for k in range(FRAMES - 1) if np.array_equal(frames[k], frames[k + 1])]
    # and the two flights agree frame by frame (simulator truth within 1e-3, normalised)
    for a, b in zip(quiet[1], loaded[1], strict=True):
        np.testing.assert_allclose(a.joints_norm, b.joints_norm, atol=1e-3)
        assert np.array_equal(a.region_in_focus, b.region_in_focus)
    diff = max(float(np.abs(x.astype(int) - y.astype(int)).mean()) for x, y in zip(quiet[2], loaded[2]))
    assert diff < 1.0, diff


@pytest.mark.slow
@pytest.mark.timeout(1500)  # a transfer in the 3-D world on a loaded machine: the waits inside bound it
def test_transfer_through_zenoh_processes(data, tmp_path, port, listener_opts):
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "open_country", "-o", str(out), "--max-frames", str(FRAMES), "--preroll", "2",
                        "--rig", "e2e"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
    for f in ("style.json", "output.mp4", "output_style.json", "run.mcap", "truth.msgpack", "report.html",
              "report.json", "meta.json"):
        assert (out / f).is_file(), f

    # the nodes really ran as separate processes, supervised, with their own logs
    for node in ("router", "planner", "autopilot_bridge"):
        assert (out / "deploy" / f"{node}.log").stat().st_size > 0

    # the recording holds what crossed Zenoh: setpoints from the planner, frames and truth from the bridge
    counts: dict[str, int] = {}
    planner_setpoints = []
    for _, key, payload in read_run(out / "run.mcap"):
        counts[key] = counts.get(key, 0) + 1
        if key == keys.SETPOINT.key("e2e"):
            planner_setpoints.append(codec.decode(payload, M.Setpoint))
    assert counts.get(keys.FRAME.key("e2e"), 0) >= FRAMES
    assert counts.get(keys.SIM_TRUTH.key("e2e"), 0) >= FRAMES
    assert any(sp.mode == "track" for sp in planner_setpoints)
    assert counts.get(keys.health("e2e", "planner"), 0) >= 1
    # ... complete, within 2 MB per second of flight, and the output video is H.264 with its index first
    run = RunReader(out / "run.mcap")
    assert run.info.complete and 0 < size_report(run.info)["mb_per_flight_s"] <= 2.0, size_report(run.info)
    vid = probe(out / "output.mp4")
    assert vid["codec"] == "h264" and vid["faststart"] and vid["frames"] == FRAMES, vid
    # ... and `replay run.mcap` republishes the camera frames, under another rig name
    replayed_frames(out / "run.mcap", port, listener_opts, last_index=max(
        codec.decode(p, M.Frame).index for _, k, p in read_run(out / "run.mcap", keys.FRAME.key("e2e"))))

    meta = json.loads((out / "meta.json").read_text())
    assert meta["recorded_frames"] == FRAMES == meta["instruction_frames"]
    # the recording's camera frames are the take's, each stamped at its slot after the flight's time
    # zero: the pre-roll is flown (its truth recorded) but not rendered, and nothing is from before the reset
    recorded = [codec.decode(p, M.Frame) for _, _, p in read_run(out / "run.mcap", keys.FRAME.key("e2e"))]
    first = meta["preroll_frames"]
    assert first == 48 and [f.index for f in recorded] == list(range(first, first + FRAMES))
    assert all(f.stamp_ns == meta["epoch_ns"] + int(round(f.index / 24 * 1e9)) for f in recorded)
    timeline = [codec.decode(p, M.GroundTruth) for _, _, p in read_run(out / "run.mcap", keys.SIM_TRUTH.key("e2e"))]
    assert [t.frame_index for t in timeline][:first + FRAMES] == list(range(first + FRAMES))
    assert min(t.stamp_ns for t in timeline) == meta["epoch_ns"]
    assert min(t.stamp_ns for t in read_truths(out / "truth.msgpack")) >= meta["epoch_ns"]
    # in simulation time every instruction frame is its own render: nothing repeated or missing
    assert meta["clock_mode"] == "lockstep"
    assert meta["repeated_frames"] == 0 and meta["missing_frames"] == 0 and meta["truth_frames"] == FRAMES
    frames = video_frames(out / "output.mp4")
    assert len(frames) == FRAMES
    assert not [k for k in range(FRAMES - 1) if np.array_equal(frames[k], frames[k + 1])]

    # the report's ground-truth joint error is this run's: recompute it from the recorded truth
    style = load_style(out / "style.json")
    truths = read_truths(out / "truth.msgpack")
    assert len(truths) == FRAMES
    names = list(truths[0].joint_names)
    idx = [names.index(j) for j in style.joint_names]
    errs = []
    for k, t in enumerate(truths):
        for e, j in enumerate(idx):
            tgt = style.image_targets[k, e]
            if t.joints_visible[j] and np.isfinite(tgt).all() and style.subject_visible[k]:
                errs.append(np.linalg.norm(t.joints_norm[j] - tgt))
    report = json.loads((out / "report.json").read_text())
    assert report["headline"]["truth"]["joint_error_mean"] == pytest.approx(float(np.mean(errs)), rel=1e-3)
    assert report["headline"]["extraction"]["available"] is True
    # its floor (the best any camera could do with the dancer's poses) is computed on the same joint-frames
    # and lies below what was flown
    floor = report["truth_floor"]
    assert floor["joint_frames"] == len(errs) and 0.0 <= floor["joint_error"] < float(np.mean(errs))
    # the camera-motion section: the juggler's locked-off camera reads as static; the output is
    # measured the same way, and the truth comes from the recorded camera poses
    cmo = report["camera_motion"]
    assert cmo["available"] and [s["rows"] for s in cmo["shots"]] == [[0, FRAMES]], cmo
    shot = cmo["shots"][0]
    assert shot["source"]["class"] == "static", shot
    for side in ("source", "output", "truth"):
        assert {"class", "pan_rate_dps", "tilt_rate_dps", "roll_rate_dps", "zoom_rate"} <= set(shot[side]), side
    assert shot["truth"]["pan_rate_dps"] is not None and 0.0 <= shot["agreement"] <= 1.0
    assert "fig_camera_motion.png" in report["figures"]
    assert "The source camera was static." in (out / "report.html").read_text()
    # and the report's side-by-side video is H.264 and plays offline in headless Chromium, when there is one
    assert probe(out / "report_video.mp4")["frames"] == FRAMES
    assert report["recording_file"]["complete"] is True
    import shutil

    if shutil.which("chromium"):
        from cinetransfer.report.browser_check import check, verdict

        result = check(out / "report.html")
        assert verdict(result) == [], result


@pytest.mark.slow
def test_ctrl_c_stops_the_vehicle_and_keeps_the_recording(data, tmp_path):
    import signal
    import time

    from cinetransfer.deploy.rundir import pid_alive as _pid_alive

    out = tmp_path / "run"
    console = open(tmp_path / "console.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                             "--scene", "lawn_juggler_25d", "-o", str(out), "--max-frames", "240", "--preroll", "1",
                             "--rig", "ctrlc", "--pace", "0.5"],  # a take of 20 s or more, however fast the machine
                            stdout=console, stderr=subprocess.STDOUT, text=True,
                            # started as a script's background job is (`cmd &`: SIGINT ignored, which the
                            # child inherits): the Ctrl-C must stop the take all the same
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        # when the take is being recorded (watched on the bus as the deployment's read-only observer:
        # 1 s of the take has been simulated since the transfer's reset) ...
        take_s = wait_for_take(out, "ctrlc", proc, seconds_in=1.0 + 1.0)
        assert take_s >= 2.0
        state = json.loads((out / "deploy" / "state.json").read_text())
        pids = [state["supervisor_pid"], *(v["pid"] for v in state["procs"].values())]
        proc.send_signal(signal.SIGINT)  # ... Ctrl-C, and an impatient second one
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(120)
    finally:
        if proc.poll() is None:  # the test failed mid-flight: leave no deployment behind
            proc.kill()
            proc.wait()
            if (out / "deploy" / "transfer.yaml").is_file():
                subprocess.run([sys.executable, "-m", "cinetransfer", "deploy", "down",
                                str(out / "deploy" / "transfer.yaml"),
                                "--run-dir", str(out / "deploy")], capture_output=True, timeout=120)
        console.close()
        log = (tmp_path / "console.log").read_text()
    assert rc == 130, log[-3000:]
    # then the planner was told to stop and the bridge to hold, after the take had started
    actions = [(key, codec.decode(p, M.Command).action) for _, key, p in read_run(out / "run.mcap")
               if key in (keys.PLANNER_COMMAND.key("ctrlc"), keys.BRIDGE_COMMAND.key("ctrlc"))]
    reset_at = actions.index((keys.BRIDGE_COMMAND.key("ctrlc"), "reset"))  # the take had started
    stop_at = actions.index((keys.PLANNER_COMMAND.key("ctrlc"), "stop"), reset_at)  # (a 'stop' precedes the take)
    assert actions[stop_at:stop_at + 2] == [(keys.PLANNER_COMMAND.key("ctrlc"), "stop"),
                                            (keys.BRIDGE_COMMAND.key("ctrlc"), "hold")]
    # what was recorded is kept, and said to be partial
    meta = json.loads((out / "meta.json").read_text())
    assert meta["interrupted"] is True and 0 < meta["recorded_frames"] < 240
    # (a frame and its truth travel separately: the last one's truth may miss the cut)
    assert abs(len(read_truths(out / "truth.msgpack")) - meta["recorded_frames"]) <= 1
    assert meta["repeated_frames"] == 0
    assert meta["truth_frames"] == len(read_truths(out / "truth.msgpack"))
    # and no node is left running
    assert not [p for p in pids if _pid_alive(p)]


@pytest.mark.slow
def test_realtime_take_states_its_repeats_or_fails_when_short(data, tmp_path):
    # given a take flown on the wall clock (as with a real vehicle): the simulator may skip frames
    out = tmp_path / "rt"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "lawn_juggler_25d", "-o", str(out), "--max-frames", "24", "--preroll", "1",
                        "--rig", "rt", "--realtime"], capture_output=True, text=True, timeout=600)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["clock_mode"] == "realtime"
    if meta["recorded_frames"] < 24:
        # then a short take is an error that says so, never a silent partial result
        assert r.returncode == 1 and "the real-time take is short" in r.stderr, r.stderr[-2000:]
        return
    assert r.returncode == 0, r.stderr[-3000:]
    # then whatever was repeated is counted, and stated in the report with its share
    assert meta["repeated_frames"] == len(meta["repeated_slots"])
    truths = read_truths(out / "truth.msgpack")
    assert len(truths) == 24 and len(video_frames(out / "output.mp4")) == 24
    fresh = [k for k in range(24) if k not in meta["repeated_slots"]]
    for k in meta["repeated_slots"]:  # a repeated slot shows (and is scored as) a render next to it
        assert truths[k].stamp_ns in {truths[j].stamp_ns for j in fresh}
    # (a take that opens between two renders fills its first slots with the first one)
    stamps = [truths[k].stamp_ns for k in fresh]
    assert stamps == sorted(set(stamps))  # every fresh slot its own, newer render
    report = json.loads((out / "report.json").read_text())
    assert report["recording"]["repeated_frames"] == meta["repeated_frames"]
    assert report["recording"]["clock"] == "realtime"
    if meta["repeated_frames"]:
        assert "repeat the previous frame" in (out / "report.html").read_text()


@pytest.mark.slow
def test_a_three_shot_source_is_flown_as_three_takes_cut_at_the_source_cuts(data, tmp_path):
    from cinetransfer.shared.instructions import save_style

    # given a style of three shots (cuts at rows 12 and 24): one extracted from real frames, cut
    first = tmp_path / "first"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "extract", str(data / "sam2_juggle_1280x720.mp4"),
                        "--stop", str(FRAMES), "-o", str(tmp_path / "style1.json"), "--quiet"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    style = load_style(tmp_path / "style1.json")
    starts = np.zeros(FRAMES, bool)
    starts[[0, 12, 24]] = True
    import dataclasses

    save_style(tmp_path / "three.json", dataclasses.replace(style, shot_start=starts))
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "lawn_juggler_25d", "-o", str(first), "--style", str(tmp_path / "three.json"),
                        "--preroll", "1", "--settle", "0.5", "--rig", "shots"], capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-5000:]
    meta = json.loads((first / "meta.json").read_text())
    # then three takes, every instruction frame recorded once, nothing repeated
    assert [(t["first_row"], t["end_row"]) for t in meta["takes"]] == [(0, 12), (12, 24), (24, 36)]
    assert meta["recorded_frames"] == FRAMES and meta["repeated_frames"] == 0 and meta["missing_frames"] == 0
    # and the edit cuts exactly at the source's cuts: within a take consecutive frames are one frame
    # period apart in simulated time, across a cut the settle phase (0.5 s = 12 frames) lies between
    truths = read_truths(first / "truth.msgpack")
    gaps = np.diff([t.stamp_ns for t in truths]) / (1e9 / 24)
    assert [k + 1 for k, g in enumerate(gaps) if abs(g - 1) > 1e-3] == [12, 24]
    assert np.allclose(gaps[[11, 23]], 13, atol=1e-3)
    # and the report gives each take's goals and settle phase
    report = json.loads((first / "report.json").read_text())
    assert [s["rows"] for s in report["shots"]] == [[0, 12], [12, 24], [24, 36]]
    assert all(s["settle_limit_s"] is not None for s in report["shots"])
    assert "Shots" in (first / "report.html").read_text()
