"""H.264 videos people watch (shared/video.py): browser-playable, index first, frame-exact."""
import cv2
import numpy as np
import pytest

from cinetransfer.shared.video import H264Writer, probe


def _frames(n: int, h: int = 54, w: int = 96) -> list[np.ndarray]:
    out = []
    for i in range(n):
        img = np.zeros((h, w, 3), np.uint8)
        img[:, (i * 3) % w: (i * 3) % w + 10] = (40, 200, 250)
        out.append(img)
    return out


@pytest.mark.parametrize("size", [(54, 96), (55, 97)], ids=["even", "odd (padded)"])
def test_h264_with_faststart_and_every_frame(tmp_path, size):
    # given n frames written at 24 fps
    path = tmp_path / "v.mp4"
    frames = _frames(30, *size)
    with H264Writer(path, 24.0) as w:
        for f in frames:
            w.write(f)
    # then the file is H.264 yuv420p with its index before the data, 30 frames lasting 1.25 s
    info = probe(path)
    assert (info["codec"], info["pix_fmt"], info["faststart"], info["frames"]) == ("h264", "yuv420p", True, 30)
    assert info["duration_s"] == pytest.approx(30 / 24)
    # and OpenCV reads back every frame, in order, close to what was written
    cap = cv2.VideoCapture(str(path))
    back = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        back.append(img[: size[0], : size[1]])
    cap.release()
    assert len(back) == 30
    assert max(float(np.abs(a.astype(int) - b).mean()) for a, b in zip(frames, back)) < 4.0


def test_x264_params_reach_the_encoder_and_the_video_still_plays(tmp_path):
    # given the report's cheaper motion search on top of the preset
    from cinetransfer.report.video import X264_PARAMS

    path = tmp_path / "v.mp4"
    frames = _frames(30)
    with H264Writer(path, 24.0, crf=23, x264_params=X264_PARAMS) as w:
        for f in frames:
            w.write(f)
    # then x264's own settings record (an SEI in the stream) names them, where the default has hex / 7
    data = path.read_bytes()
    assert b"me=dia" in data and b"subme=1" in data
    with H264Writer(tmp_path / "d.mp4", 24.0, crf=23) as w:
        w.write(frames[0])
    assert b"me=hex" in (tmp_path / "d.mp4").read_bytes()
    # and the video is still a browser's H.264 with every frame
    info = probe(path)
    assert (info["codec"], info["pix_fmt"], info["faststart"], info["frames"]) == ("h264", "yuv420p", True, 30)


def test_bad_frames_are_refused(tmp_path):
    w = H264Writer(tmp_path / "v.mp4", 24.0)
    try:
        w.write(_frames(1)[0])
        with pytest.raises(ValueError, match="the video is 96x54"):
            w.write(np.zeros((60, 96, 3), np.uint8))
        with pytest.raises(ValueError, match="uint8"):
            w.write(np.zeros((54, 96, 3), np.float32))
    finally:
        w.close()
    with pytest.raises(ValueError, match="fps"):
        H264Writer(tmp_path / "x.mp4", 0.0)


def test_the_reports_halves_average_areas_only_on_a_whole_factor():
    # 720 -> 360 and 360 -> 360 shrink by a whole factor (OpenCV's fast area path); 540 -> 360 is bilinear
    from cinetransfer.report.video import _interpolation

    assert [_interpolation(h) for h in (720, 360, 1080, 540, 480)] == [
        cv2.INTER_AREA, cv2.INTER_AREA, cv2.INTER_AREA, cv2.INTER_LINEAR, cv2.INTER_LINEAR]


def test_the_reports_rows_read_ahead_are_the_frames_read_in_turn(tmp_path, monkeypatch):
    # given a 30-frame source whose rows repeat and skip (k = 0 0 1 3 4 ...), an output of 20, and
    # a read-ahead of only 2 rows (the reading thread waits for the drawing most of the time)
    from cinetransfer.report import video as V

    src, out = tmp_path / "src.mp4", tmp_path / "out.mp4"
    for path, n in ((src, 30), (out, 20)):
        with H264Writer(path, 24.0) as w:
            for img in _frames(n, 72, 128):
                w.write(img)
    rows = [0, 0, 1, 3, 4, 4, 4, 9, 12, 13, 17, 18, 20, 21, 25, 26, 27, 28, 29, 29]
    monkeypatch.setattr(V, "READ_AHEAD", 2)
    got = list(V._rows(src, out, rows))
    # then each row holds the very frames (and halves) that reading both videos in turn gives
    srd, ord_ = V._Reader(src), V._Reader(out)
    for i, (a, b, left, right) in enumerate(got):
        want_a, want_b = srd.get(rows[i]), ord_.get(i)
        assert np.array_equal(a, want_a) and np.array_equal(b, want_b), i
        assert left.shape == right.shape == (V.HEIGHT, 640, 3)
        assert np.array_equal(left, V._half(want_a, 640, "")), i
    assert len(got) == len(rows)
    # and a row past the output's end is None (its half is the placeholder), not an error
    tail = list(V._rows(src, out, [0] * 22))
    assert tail[-1][1] is None and tail[-1][3].shape == (V.HEIGHT, 640, 3)
