import os
import stat

import imageio.v2 as imageio
import numpy as np
import pytest

from radar4dgs.evaluate.video import write_video


def _frames(n, height, width):
    return [np.full((height, width, 3), 30 + 40 * i, np.uint8) for i in range(n)]


def _read(path):
    reader = imageio.get_reader(path, format="FFMPEG")
    try:
        return [frame for frame in reader], reader.get_meta_data()
    finally:
        reader.close()


@pytest.mark.parametrize(("height", "width"), [(21, 30), (30, 21)])
def test_odd_sized_frames_are_padded_to_even_and_read_back(tmp_path, height, width):
    path = tmp_path / "out" / "video.mp4"
    assert write_video(iter(_frames(5, height, width)), path, fps=10) == path
    frames, meta = _read(path)
    assert len(frames) == 5
    assert frames[0].shape == (height + height % 2, width + width % 2, 3)
    assert meta["fps"] == pytest.approx(10)
    for i, frame in enumerate(frames):
        # The picture itself survives (H.264 is lossy: a few levels), the padding is black.
        assert abs(frame[:height, :width].mean() - (30 + 40 * i)) < 3
        assert frame[height:].max(initial=0) < 20 and frame[:, width:].max(initial=0) < 20
    assert sorted(p.name for p in path.parent.iterdir()) == ["video.mp4"]
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o644


def test_zero_frames_is_an_error_and_writes_nothing(tmp_path):
    with pytest.raises(ValueError, match="no frames"):
        write_video([], tmp_path / "v.mp4")
    assert list(tmp_path.iterdir()) == []


def test_bad_frames_leave_no_file_and_keep_the_old_one(tmp_path):
    path = tmp_path / "v.mp4"
    path.write_bytes(b"previous video")
    with pytest.raises(ValueError, match="one size"):
        write_video(_frames(3, 20, 30) + _frames(1, 20, 32), path)
    with pytest.raises(ValueError, match="uint8"):
        write_video(_frames(2, 20, 30) + [np.zeros((20, 30, 3), np.float32)], path)
    assert path.read_bytes() == b"previous video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def test_a_failing_frame_source_leaves_no_temporary_file(tmp_path):
    def frames():
        yield from _frames(2, 16, 16)
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_video(frames(), tmp_path / "v.mp4")
    assert list(tmp_path.iterdir()) == []
