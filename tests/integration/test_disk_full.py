"""A full disk under a transfer or a deployment: seen at once, said in one line, the recording
closed readable, the supervisor supervising on. A real tmpfs of a few MB as the output or run
folder (needs root to mount; CI runs as root); real processes."""
import json
import os
import signal
import subprocess
import sys

import pytest

from conftest import REPO, cli, cpu_seconds, mount_tmpfs, wait_for


@pytest.fixture
def small_disk(tmp_path):
    yield from mount_tmpfs(tmp_path / "small", "size=16m")


@pytest.fixture
def tiny_disk(tmp_path):
    yield from mount_tmpfs(tmp_path / "tiny", "size=2m")


def fill(folder, leave: int = 0) -> None:
    """Fill the file system of `folder` until `leave` bytes are free (0: until a write fails)."""
    with open(folder / "filler", "wb") as f:
        try:
            while True:
                st = os.statvfs(folder)
                room = st.f_bavail * st.f_frsize - leave
                if room <= 0:
                    break
                f.write(b"\0" * min(room, 1 << 20))
                f.flush()
        except OSError:
            pass


def deploy(*args, env):
    return cli("deploy", *args, env=env, timeout=150)


def test_a_full_run_folder_neither_starts_a_deployment_nor_kills_a_running_one(tiny_disk, port):
    from cinetransfer.deploy.cli import alive_nodes
    from cinetransfer.deploy.rundir import pid_alive, running_procs

    relays = str(REPO / "tests" / "data" / "deploy" / "relays.yaml")
    env = {"CT_ROUTER_PORT": str(port), "CT_RIG": "full"}
    run_dir = tiny_disk / "run"
    # given a deployment up on a small disk ...
    r = deploy("up", relays, "--run-dir", str(run_dir), env=env)
    assert r.returncode == 0, r.stderr
    try:
        pid = json.loads((run_dir / "state.json").read_text())["procs"]["relay_a"]["pid"]
        fill(tiny_disk)  # ... when its run folder fills up and then a node dies
        os.kill(pid, signal.SIGKILL)
        # then the supervisor restarts it all the same (state.json and the log cannot be written)
        endpoint = f"tcp/127.0.0.1:{port}"
        wait_for(lambda: "relay_a" in (alive_nodes(endpoint, "full", 0.5, secrets=run_dir / "secrets") or set())
                 and any(n == "relay_a" and p != pid for p, n in running_procs(run_dir).items()), timeout=60,
                 what="relay_a restarted on a full disk")
        st = deploy("status", relays, "--run-dir", str(run_dir), env=env)
        assert st.returncode == 0 and "supervisor pid" in st.stdout, st.stdout + st.stderr
        assert "RUN FOLDER FULL" in st.stdout and "Traceback" not in st.stdout + st.stderr, st.stdout
        procs = running_procs(run_dir)
    finally:
        down = deploy("down", relays, "--run-dir", str(run_dir), env=env)
    # and it stops cleanly: nothing left running
    assert down.returncode == 0 and "deploy relays: down" in down.stdout, down.stdout + down.stderr
    assert not [p for p in procs if pid_alive(p)]
    # a second `up` on the full folder is refused in one line, before anything starts
    r = deploy("up", relays, "--run-dir", str(tiny_disk / "again"), env=env)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert lines[0].startswith(f"cinetransfer deploy: cannot write the run folder {tiny_disk / 'again'}: No space "
                               "left on device (") and "KB free; a deployment needs 1 MB" in lines[0], lines
    assert not (tiny_disk / "again").exists()


@pytest.mark.slow
@pytest.mark.timeout(1500)  # a whole transfer on a loaded machine: the waits inside bound it
def test_a_full_disk_stops_the_recording_at_once_and_keeps_it_readable(data, tmp_path, small_disk):
    from cinetransfer.runlog import RunReader

    clip = str(data / "sam2_juggle_1280x720.mp4")
    short = tmp_path / "style24.json"
    r = cli("extract", clip, "--stop", "24", "-o", str(short), "--quiet", timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    k = long_style(short, tmp_path / "style.json", 10)  # 10 s at 24 fps: far more than the 8 MB beside the reserve
    out = small_disk / "run"
    # the pre-roll records states and truth, the take its frames: the disk fills in one or the other
    r = cli("transfer", clip, "--style", str(tmp_path / "style.json"), "--scene", "lawn_juggler_25d", "-o", str(out),
            "--preroll", "60", "--rig", "full", "--no-eval", timeout=900)
    assert r.returncode == 1, r.stdout[-2000:] + r.stderr[-3000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("cinetransfer transfer: cannot write the recording: No space left on device"), last
    assert "closed readable" in last and "Traceback" not in r.stderr  # (the stall timeout says "no frame ...")
    info = RunReader(out / "run.mcap").info  # no --salvage needed
    assert info.complete and info.messages > 100 and info.frames > 0
    meta = json.loads((out / "meta.json").read_text())
    assert "No space left on device" in meta["error"]
    # what the take's video holds is read back and said: never started, or cut short
    video = meta["files"]["output.mp4"]
    assert video.startswith("missing") or (video.startswith("partial: ") and video.endswith(f" of {k} frames")), video
    assert f"output.mp4 {video}" in last, (video, last)
    assert not (out / ".reserve").exists()


def test_a_disk_without_room_for_the_reserve_is_refused_before_anything_starts(data, tiny_disk):
    clip = str(data / "sam2_juggle_1280x720.mp4")
    r = cli("transfer", clip, "-o", str(tiny_disk / "run"), "--rig", "tiny")
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stdout + r.stderr
    assert r.stderr.startswith(f"cinetransfer transfer: -o {tiny_disk / 'run'}: No space left on device: "), r.stderr
    assert "MB free; a transfer sets 8 MB aside" in r.stderr
    assert list(tiny_disk.iterdir()) == [] and "deploy up" not in r.stdout  # no folder, no node


def long_style(short, path, reps: int) -> int:
    """A style of `reps` times the rows of the real style `short` (one shot): a long take."""
    import dataclasses

    import numpy as np

    from cinetransfer.shared.instructions import load_style_file, save_style

    instr = load_style_file(short).instructions
    k = instr.image_targets.shape[0]
    rows = {f.name: np.concatenate([getattr(instr, f.name)] * reps) for f in dataclasses.fields(instr)
            if isinstance(getattr(instr, f.name), np.ndarray) and getattr(instr, f.name).shape[:1] == (k,)}
    if instr.shot_start is not None:
        rows["shot_start"] = np.zeros(k * reps, bool)
    if instr.camera_motion_class is not None:  # a list, not an array
        rows["camera_motion_class"] = list(instr.camera_motion_class) * reps
    save_style(path, dataclasses.replace(instr, **rows))
    return k * reps


@pytest.fixture
def mid_disk(tmp_path):
    yield from mount_tmpfs(tmp_path / "mid", "size=64m")


@pytest.mark.slow
@pytest.mark.timeout(1500)  # a whole transfer on a loaded machine: the waits inside bound it
def test_a_disk_filling_mid_take_keeps_an_output_video_larger_than_the_reserve(data, tmp_path, mid_disk):
    from cinetransfer.recorder import LOW_SPACE_BYTES, RESERVE_BYTES
    from cinetransfer.runlog import RunReader
    from cinetransfer.shared.video import probe

    clip = str(data / "sam2_juggle_1280x720.mp4")
    short = tmp_path / "style24.json"
    r = cli("extract", clip, "--stop", "24", "-o", str(short), "--quiet", timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    k = long_style(short, tmp_path / "style.json", 40)  # 40 s at 24 fps: ~20 MB of video
    out = mid_disk / "run"
    video = out / "output.mp4"
    proc = subprocess.Popen([sys.executable, "-m", "cinetransfer", "transfer", clip, "--style",
                             str(tmp_path / "style.json"), "--scene", "lawn_juggler_25d", "-o", str(out),
                             "--preroll", "1", "--rig", "filling", "--no-eval"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        # given a take whose video has grown past the reserve the recorder keeps to close it ...
        # (a loaded machine takes its time: fail when neither the transfer's CPU nor the disk moves for 5 min)
        wait_for(lambda: proc.poll() is not None or (video.is_file() and video.stat().st_size > RESERVE_BYTES + 2**20),
                 timeout=300, interval=0.2, what="output.mp4 larger than the reserve",
                 progress=lambda: (cpu_seconds(proc), os.statvfs(mid_disk).f_bfree))
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        fill(mid_disk, leave=LOW_SPACE_BYTES // 4)  # ... another writer fills the disk
        _, err = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    # then the transfer stops in one line that says what each file holds ...
    assert proc.returncode == 1, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("cinetransfer transfer: cannot write the recording: No space left on device"), last
    assert "closed readable" in last and "output.mp4 partial: " in last and "Traceback" not in err, err[-3000:]
    # ... and the video is readable, faststart, every frame the meta counts, all larger than the reserve
    meta = json.loads((out / "meta.json").read_text())
    info = probe(video)
    assert info["faststart"] and 0 < info["frames"] == meta["recorded_frames"] < k, (info, meta["recorded_frames"])
    assert video.stat().st_size > RESERVE_BYTES
    print(f"output.mp4: {video.stat().st_size / 2**20:.1f} MB, {info['frames']} of {k} frames")  # a figure
    assert meta["files"]["output.mp4"] == f"partial: {info['frames']} of {k} frames", meta["files"]
    assert meta["files"]["run.mcap"] == "complete" and RunReader(out / "run.mcap").info.complete
    assert "No space left on device" in meta["error"] and meta["truth_frames"] > 0
    assert not (out / ".reserve").exists()


def test_a_recording_holding_room_closes_complete_when_another_writer_takes_the_whole_disk(small_disk):
    import errno

    from cinetransfer import diskroom
    from cinetransfer.runlog import RunReader, RunWriter

    path = small_disk / "run.mcap"
    # given a recording that holds 2 MB past its end, a chunk a write (payloads nobody can compress) ...
    w = RunWriter(path, {}, flush_s=0.0, hold_bytes=2 << 20)
    if not w.holding:
        pytest.skip("this file system cannot hold room past a file's end")
    for _ in range(5):
        w.write("ct/r/blob/x", os.urandom(100_000))
    fill(small_disk)  # ... when another writer takes every byte the disk has left
    st = os.statvfs(small_disk)
    assert st.f_bavail * st.f_frsize < 2**16
    # then the next chunk goes into the recording's own room, and the room it cannot hold ahead of that
    # is the full disk: said at once, nothing cut
    with pytest.raises(OSError) as e:
        w.write("ct/r/blob/x", os.urandom(100_000))
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(path)
    # and it closes complete, every message in, its room given back to the disk
    w.close()
    info = RunReader(path).info
    assert info.complete and info.messages == 6
    assert diskroom.allocated(path) < path.stat().st_size + 2**16
