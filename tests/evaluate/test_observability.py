"""How close the training frames around a held-out frame saw its movers: closed forms on a square plate that drives
along the optical axis of a still camera, the PSNR* over the frames seen close, and the caveat."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from radar4dgs.evaluate.observability import (
    UNSEEN_FRAME_SHARE,
    closest_seen,
    seen_caveats,
    seen_summary,
    unseen_close_share,
)

SIZE, FOCAL, HALF_WIDTH, WALL = 64, 100.0, 0.5, 100.0


class PlateScene:
    """A still camera (world = camera frame) and a 1 m square plate facing it at depth ``depths[t]`` in frame t,
    before a static wall; ``off_view_after`` frames see the plate moved 100 m sideways, out of view."""

    def __init__(self, depths, off_view_after: int | None = None):
        self.depths, self.off = list(depths), off_view_after
        self.camera = type("Camera", (), {"K": np.array([[FOCAL, 0, SIZE / 2], [0, FOCAL, SIZE / 2], [0, 0, 1.0]]),
                                          "width": SIZE, "height": SIZE})()

    def __len__(self):
        return len(self.depths)

    def has(self, name):
        return name in ("gt/depth", "gt/flow", "gt/dynamic_mask")

    def world_to_camera(self, index):
        return np.eye(4)

    def sideways(self, index):
        return 100.0 if self.off is not None and index > self.off else 0.0

    def plate(self, index):
        z = self.depths[index]
        pixels = np.arange(SIZE) + 0.0 - SIZE / 2
        inside = np.abs(pixels) * z / FOCAL < HALF_WIDTH
        return (inside[:, None] & inside[None, :]) & (self.sideways(index) == 0.0), z

    def load_optional(self, name, index):
        plate, z = self.plate(index)
        if name == "gt/dynamic_mask":
            return plate.astype(np.uint8) * 255
        if name == "gt/depth":
            return np.where(plate, z, WALL).astype(np.float32)
        if name == "gt/flow":  # the plate's points move along the axis (and sideways once out of view)
            flow = np.zeros((SIZE, SIZE, 3), np.float32)
            if index + 1 < len(self):
                flow[plate] = (self.sideways(index + 1), 0.0, self.depths[index + 1] - z)
            return flow
        raise KeyError(name)


@settings(max_examples=40, deadline=None)
@given(before=st.floats(6.0, 40.0), held_out=st.floats(5.0, 12.0), after=st.floats(6.0, 40.0))
def test_each_moving_pixel_is_seen_at_the_closer_neighbours_depth_ratio(before, held_out, after):
    scene = PlateScene([before, held_out, after])
    ratio = closest_seen(scene, 1, train_indices=[0, 2])
    plate, _ = scene.plate(1)
    assert np.isnan(ratio[~plate]).all()
    # Each pixel takes the closer neighbour's ratio, except at the plate's rim where a point rounds to a pixel of
    # the wall in one neighbour and counts as seen by the other only.
    near, far = sorted((before / held_out, after / held_out))
    at_near = np.isclose(ratio, near, rtol=1e-6)
    assert (at_near | np.isclose(ratio, far, rtol=1e-6))[plate].all()
    assert at_near[ndimage.binary_erosion(plate, iterations=2)].all()
    share = unseen_close_share(scene, 1, [0, 2])
    if near > 2.0:
        assert share == 1.0
    elif far <= 2.0:
        assert share == 0.0
    else:  # only the rim can be seen by the farther neighbour alone
        assert share <= 1.0 - ndimage.binary_erosion(plate, iterations=2).sum() / plate.sum()


def test_a_plate_that_leaves_the_view_counts_only_the_frame_before():
    # 30 m -> 10 m (3x closer) -> out of view: never seen close. 15 m -> 10 m -> out: seen at 2/3 the size.
    far = PlateScene([30.0, 10.0, 10.0], off_view_after=1)
    assert np.all(closest_seen(far, 1, [0, 2])[far.plate(1)[0]] == pytest.approx(3.0))
    assert unseen_close_share(far, 1, [0, 2]) == 1.0
    near = PlateScene([15.0, 10.0, 10.0], off_view_after=1)
    assert unseen_close_share(near, 1, [0, 2]) == 0.0
    # Neither neighbour a training frame: nothing saw it.
    assert np.isinf(closest_seen(near, 1, [])[near.plate(1)[0]]).all()


def test_the_summary_leaves_out_the_unseen_frames_and_the_caveat_names_them():
    frames = [{"frame": "a", "psnr_dyn": 26.0, "unseen_close_share": 0.0},
              {"frame": "b", "psnr_dyn": 17.0, "unseen_close_share": UNSEEN_FRAME_SHARE},
              {"frame": "c", "psnr_dyn": 24.0, "unseen_close_share": 0.1},
              {"frame": "d", "psnr_dyn": None, "unseen_close_share": None}]
    summary = seen_summary(frames)
    assert summary == {"psnr_dyn": 25.0, "n_frames": 2, "unseen_frames": ["b"]}
    caveat, = seen_caveats(summary, 22.33)
    assert "1 test frame(s) (b)" in caveat and "22.33 dB over all" in caveat and "25.00 dB over the other 2" in caveat
    assert seen_caveats({"psnr_dyn": 25.0, "n_frames": 2, "unseen_frames": []}, 25.0) == []
    assert seen_summary([{"frame": "a", "psnr_dyn": 20.0}]) is None
