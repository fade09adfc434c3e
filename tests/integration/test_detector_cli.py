"""`cinetransfer detect` as a real process on a real clip excerpt."""
from __future__ import annotations

import subprocess
import sys

import cv2

from cinetransfer.shared.measurements_file import read_measurements


def _detect(*args: str, timeout: float = 240) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cinetransfer", "detect", *args, "--no-progress"],
                          capture_output=True, text=True, timeout=timeout)


def test_detect_writes_measurements_and_overlay(tmp_path, data):
    out, ov = tmp_path / "m.msgpack", tmp_path / "ov.mp4"
    r = _detect(str(data / "davis_parkour_854x480.mp4"), "-o", str(out), "--overlay", str(ov), "--stop", "10")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "frames/s" in r.stderr
    mf = read_measurements(out)
    assert len(mf) == 10 and not mf.truncated
    assert mf.header.source.width == 854 and mf.header.source.fps == 24.0
    assert mf.header.detector in ("box_first", "mediapipe (box_first unavailable)")
    assert mf.header.config["backend"] == "box_first" and mf.header.config["num_poses"] >= 1
    assert [m.frame_index for m in mf] == list(range(10))
    assert sum(len(m.people) > 0 for m in mf) >= 8  # the runner is visible throughout
    assert all(m.focus_map is not None for m in mf)
    cap = cv2.VideoCapture(str(ov))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 10 and int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) == 854
    cap.release()


def test_detect_image_folder_start_stop(tmp_path, data):
    cap = cv2.VideoCapture(str(data / "tud_stadtmitte_640x480.mp4"))
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(4):
        ok, img = cap.read()
        assert ok
        cv2.imwrite(str(folder / f"{i:04d}.jpg"), img)
    cap.release()
    out = tmp_path / "m.msgpack"
    r = _detect(str(folder), "-o", str(out), "--start", "1", "--no-focus", "--fps", "25")
    assert r.returncode == 0, r.stderr[-2000:]
    mf = read_measurements(out)
    assert [m.frame_index for m in mf] == [1, 2, 3]
    assert all(m.focus_map is None for m in mf) and mf[0].stamp_ns == 40_000_000


def test_detect_corrupt_file_fails_clearly(tmp_path):
    bad = tmp_path / "corrupt.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"\x17" * 5000)
    r = _detect(str(bad), "-o", str(tmp_path / "m.msgpack"))
    assert r.returncode == 1
    assert "cannot read the source" in r.stderr and "corrupt.mp4" in r.stderr
    assert not (tmp_path / "m.msgpack").exists()
    r = _detect(str(tmp_path / "missing.mp4"), "-o", str(tmp_path / "m.msgpack"))
    assert r.returncode == 1 and "no such file" in r.stderr
    r = _detect(str(bad), "-o", str(tmp_path / "m.msgpack"), "--num-poses", "0")
    assert r.returncode == 2 and "num_poses" in r.stderr


def test_progress_bar_only_on_a_terminal(tmp_path, data):
    """Without --no-progress the bar is drawn on a terminal and left out of a log (stderr a pipe)."""
    import fcntl
    import os
    import pty
    import struct
    import termios

    args = [sys.executable, "-m", "cinetransfer", "detect", str(data / "davis_parkour_854x480.mp4"),
            "-o", str(tmp_path / "m.msgpack"), "--stop", "3"]
    piped = subprocess.run(args, capture_output=True, text=True, timeout=240)
    assert piped.returncode == 0, piped.stderr[-2000:]
    assert "3/3" not in piped.stderr and "frames/s" in piped.stderr  # the summary line stays
    main, sub = pty.openpty()
    fcntl.ioctl(sub, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # a 0-column pty draws no bar
    try:
        tty = subprocess.run(args, stdout=subprocess.DEVNULL, stderr=sub, timeout=240)
        os.close(sub)
        chunks = []
        while True:
            try:
                chunk = os.read(main, 65536)
            except OSError:  # EIO: the terminal's other end is closed and drained
                break
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(main)
    assert tty.returncode == 0
    assert b"3/3" in b"".join(chunks)
