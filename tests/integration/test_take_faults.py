"""A take is judged by what happened in it: real transfers, real node processes, a real fault."""
import json
import os
import signal
import subprocess
import sys

import pytest
from test_transfer_e2e import observer_session, still_going, wait_for_take


@pytest.mark.slow
def test_a_planner_killed_mid_take_makes_a_degraded_take_that_exits_3(data, tmp_path):
    out = tmp_path / "run"
    console = open(tmp_path / "console.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                             "--scene", "lawn_juggler_25d", "-o", str(out), "--max-frames", "96", "--preroll", "1",
                             "--rig", "killed", "--pace", "0.5", "--no-eval"],  # a take of 8 s or more
                            stdout=console, stderr=subprocess.STDOUT, text=True)
    try:
        # given a take under way (1 s of it simulated) ...
        wait_for_take(out, "killed", proc, seconds_in=1.0 + 1.0)
        state = json.loads((out / "deploy" / "state.json").read_text())
        os.kill(state["procs"]["planner"]["pid"], signal.SIGKILL)  # ... the planner dies (the supervisor restarts it)
        rc = proc.wait(600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        console.close()
    log = (tmp_path / "console.log").read_text()
    # then every frame is still recorded, but the take is degraded, says why, and exits 3
    assert rc == 3, log[-3000:]
    assert "degraded take" in log and "planner" in log.splitlines()[-1], log[-2000:]
    meta = json.loads((out / "meta.json").read_text())
    assert meta["recorded_frames"] == 96
    faults = meta["faults"]
    assert faults["degraded"] is True
    take = faults["takes"][0]
    assert take["planner_restarts"] >= 1, take  # (the supervisor restarts it within the take)
    # the vehicle held from the kill on: most of the take's remaining ~3 s
    assert take["hold_share"] > 0.1 and take["hold_s"] > 0.4, take


@pytest.mark.slow
def test_an_undisturbed_take_is_not_degraded(data, tmp_path):
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                        "--scene", "lawn_juggler_25d", "-o", str(out), "--max-frames", "24", "--preroll", "1",
                        "--rig", "calm", "--no-eval"], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    faults = json.loads((out / "meta.json").read_text())["faults"]
    take = faults["takes"][0]
    assert faults["degraded"] is False and faults["reasons"] == []
    assert take["hold_share"] == 0.0 and take["planner_restarts"] == 0 and take["watchdog_holds"] == 0, take


@pytest.mark.slow
def test_a_bridge_killed_mid_take_is_named_at_once_and_the_recording_is_kept(data, tmp_path):

    from cinetransfer.report.truthfile import read_truths
    from cinetransfer.runlog import RunReader

    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                             "--scene", "lawn_juggler_25d", "-o", str(out), "--max-frames", "96", "--preroll", "1",
                             "--rig", "nobridge", "--pace", "0.5", "--no-eval"],  # stall timeout: the default 300 s
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err, seen_s = kill_node_then_wait(proc, out, "autopilot_bridge",
                                      lambda: wait_for_take(out, "nobridge", proc, seconds_in=1.0 + 1.0))
    # then the transfer names the dead node in one line, long before the stall timeout ...
    assert proc.returncode == 1, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("cinetransfer transfer:") and "autopilot_bridge node died" in last, err[-3000:]
    assert "Traceback" not in err
    # (the deployment's shutdown is most of it, and a loaded machine slows it: judged against the stall
    # timeout itself, 300 s, which the dead node's name must beat, not against a guess of its speed)
    assert seen_s < 300, seen_s
    # ... and keeps everything recorded so far, readable as it is
    meta = json.loads((out / "meta.json").read_text())
    assert 0 < meta["recorded_frames"] < 96 and "autopilot_bridge" in meta["error"]
    assert meta["truth_frames"] == len(read_truths(out / "truth.msgpack")) > 0
    assert RunReader(out / "run.mcap").info.complete


@pytest.mark.slow
def test_a_detector_killed_during_the_extraction_is_named_at_once(data, tmp_path):

    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "transfer", str(data / "sam2_juggle_1280x720.mp4"),
                             "--scene", "lawn_juggler_25d", "-o", str(out), "--rig", "nodetector", "--no-eval"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # given the extraction under way (the detector has measured frames of the 247-frame clip), the detector dies
    err, seen_s = kill_node_then_wait(proc, out, "detector", lambda: wait_for_measurements(out, "nodetector", proc))
    # then the transfer names it in one line, long before the stall timeout (300 s)
    assert proc.returncode == 1, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last == "cinetransfer transfer: extraction: the detector node died (its liveliness token went away); " \
                   "see OUTDIR/deploy/detector.log", err[-3000:]
    assert seen_s < 300, seen_s  # (before the stall timeout could end it; the shutdown is most of it)


def kill_node_then_wait(proc, out, node: str, when) -> tuple[str, float]:
    """Once `when()` returns, SIGKILL the deployment's `node`; the transfer's stderr and the seconds
    it took to end after the kill."""
    import time

    try:
        when()
        state = json.loads((out / "deploy" / "state.json").read_text())
        os.kill(state["procs"][node]["pid"], signal.SIGKILL)
        killed = time.monotonic()
        _, err = proc.communicate(timeout=600)
        return err, time.monotonic() - killed
    finally:
        if proc.poll() is None:
            proc.kill()
        if not proc.stderr.closed:  # a step failed before communicate(): close the pipes, or a later test trips on them
            proc.communicate()


def wait_for_measurements(out, rig: str, proc) -> None:
    """Block until the detector of the transfer's deployment has published a measurement (seen on
    the bus as the deployment's read-only observer); the detector may load its models for minutes
    on a loaded machine while the transfer itself waits idle."""
    import threading

    from cinetransfer.shared import keys

    seen = threading.Event()
    going = still_going(proc, seen.is_set, idle=300.0)
    with observer_session(out, proc, going) as session:
        sub = session.declare_subscriber(keys.MEASUREMENT.key(rig), lambda _s: seen.set())
        try:
            while not seen.wait(0.1):
                assert going(), "the extraction ended (or stood still) first"
        finally:
            sub.undeclare()
