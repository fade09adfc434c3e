"""A full disk under a transfer: seen at once, said in one line, the recording closed readable.
A real tmpfs of a few MB as the output folder (needs root to mount; CI runs as root)."""
import json
import subprocess
import sys
import time

import pytest


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "small"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


@pytest.mark.slow
def test_a_full_disk_stops_the_recording_at_once_and_keeps_it_readable(data, tmp_path, small_disk):
    from cinetransfer.runlog import RunReader

    clip = str(data / "sam2_juggle_1280x720.mp4")
    style = tmp_path / "style.json"
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "extract", clip, "--stop", "24", "-o", str(style),
                        "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    out = small_disk / "run"
    t0 = time.monotonic()
    # a pre-roll of 60 s records ~1400 camera frames (~10 MB): more than the 8 MB left beside the 8 MB reserve
    r = subprocess.run([sys.executable, "-m", "cinetransfer", "transfer", clip, "--style", str(style),
                        "--scene", "lawn_juggler", "-o", str(out), "--preroll", "60", "--rig", "full", "--no-eval"],
                       capture_output=True, text=True, timeout=900)
    took = time.monotonic() - t0
    assert r.returncode == 1, r.stdout[-2000:] + r.stderr[-3000:]
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("cinetransfer transfer: cannot write the recording: No space left on device"), last
    assert "closed readable" in last and "Traceback" not in r.stderr
    assert took < 300, took  # not the stall timeout
    info = RunReader(out / "run.mcap").info  # no --salvage needed
    assert info.complete and info.messages > 100 and info.frames > 0
    meta = json.loads((out / "meta.json").read_text())
    assert "No space left on device" in meta["error"]
    assert not (out / ".reserve").exists()
