"""A truncated source is said, not flown as a silent partial style."""
from cinetransfer.extraction import declared_frames, shortfall


def test_a_source_far_shorter_than_its_header_is_an_error():
    assert "19 of the 72 frames" in shortfall(19, 72, None)
    assert "--max-frames 19" in shortfall(19, 72, None)
    assert shortfall(19, 72, 20) is None  # --max-frames 20: one frame short is within the estimate
    assert "19 of the 40 frames" in shortfall(19, 72, 40)


def test_a_container_estimate_off_by_a_frame_or_two_is_accepted():
    assert shortfall(70, 72, None) is None
    assert shortfall(490, 500, None) is None  # 2 %
    assert shortfall(489, 500, None) is not None
    assert shortfall(None, 72, None) is None and shortfall(19, None, None) is None


def test_declared_frames_reads_the_header(data, tmp_path):
    assert declared_frames(data / "sam2_juggle_1280x720.mp4") > 100
    (tmp_path / "x.mp4").write_bytes(b"not a video")
    assert declared_frames(tmp_path / "x.mp4") is None
