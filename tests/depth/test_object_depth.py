"""The object-depth stage: each moving object's prepared depth rescaled by its own radar returns."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy import ndimage

from radar4dgs.depth.config import ObjectDepthConfig
from radar4dgs.depth.objects import component_scales, rescale_objects, returns_at_camera_time
from radar4dgs.io.scene_files import prepared_depth_path


def car_scene(true_depth: float, bias: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(20, 30) prepared depth: a 30 m wall with a car (rows 5-14, columns 10-19) at ``true_depth``
    drawn ``bias`` too deep; its component labels and the car's mask."""
    depth = np.full((20, 30), 30.0)
    car = np.zeros((20, 30), bool)
    car[5:15, 10:20] = True
    depth[car] = true_depth * (1.0 + bias)
    labels, _ = ndimage.label(car)
    return depth, labels, car


def car_returns(count: int, outliers: int, z: float, far: float) -> tuple[np.ndarray, np.ndarray]:
    """``count`` returns on the car's pixels at depth ``z``, the last ``outliers`` of them at ``far``."""
    uv = np.stack([10 + np.arange(count) % 10, 5 + np.arange(count) // 10 % 10], axis=1)
    depth = np.full(count, z)
    depth[count - outliers:] = far
    return uv, depth


@given(bias=st.floats(-0.2, 0.2), count=st.integers(10, 60), outlier_share=st.floats(0.0, 0.49),
       far=st.floats(0.2, 3.0))
def test_a_biased_car_gets_its_radar_depth_back(bias, count, outlier_share, far):
    # Fewer than half the returns stray (ghosts, the road under the car): the median ratio is the
    # inliers' one, so the car lands on its true depth and the wall behind it is untouched.
    depth, labels, car = car_scene(10.0, bias)
    outliers = int(outlier_share * count)
    uv, z = car_returns(count, outliers, 10.0, 10.0 * far)
    rows = component_scales(depth, labels, uv, z, ObjectDepthConfig())
    assert rows[0]["returns"] == count and rows[0]["applied"]
    fixed = rescale_objects(depth, labels, rows)
    np.testing.assert_allclose(fixed[car], 10.0, rtol=1e-4)
    assert np.array_equal(fixed[~car], depth[~car])


@pytest.mark.parametrize(("count", "bias", "pixels", "why"), [
    (9, 0.05, 100, "too few returns for a steady scale"),
    (10, 0.40, 100, "a 29 % correction: the returns belong to something else"),
    (10, 0.05, 100, None),
])
def test_a_component_is_left_alone_without_enough_evidence(count, bias, pixels, why):
    depth, labels, car = car_scene(10.0, bias)
    uv, z = car_returns(count, 0, 10.0, 10.0)
    row = component_scales(depth, labels, uv, z, ObjectDepthConfig())[0]
    assert row["applied"] is (why is None), why
    assert row["ratio"] == pytest.approx(1.0 / (1.0 + bias), rel=1e-4)
    assert np.array_equal(rescale_objects(depth, labels, [row])[car], depth[car]) is (why is not None)


def test_speckle_and_returns_off_the_mask_do_not_count():
    depth, labels, car = car_scene(10.0, 0.05)
    speck = np.zeros_like(car)
    speck[0, 0] = True
    labels, _ = ndimage.label(car | speck)
    # Three returns on the one-pixel speck, five on the wall: neither counts for the car.
    uv = np.array([[0, 0]] * 3 + [[25, 2]] * 5)
    rows = component_scales(depth, labels, uv, np.full(8, 9.0), ObjectDepthConfig(min_pixels=20))
    speck_row, car_row = sorted(rows, key=lambda r: r["pixels"])
    assert speck_row["returns"] == 3 and not speck_row["applied"]
    assert car_row["returns"] == 0 and car_row["ratio"] is None and not car_row["applied"]


def test_returns_move_along_their_ray_to_the_camera_time():
    # 10 m ahead and 10 m to the left of the radar, receding at 5 m/s; the camera fires 20 ms later.
    origin = np.array([1.0, 2.0, 0.5])
    point = origin + np.array([10.0, 10.0, 0.0])
    moved = returns_at_camera_time(point[None], origin, np.array([5.0]), 0.02)[0]
    np.testing.assert_allclose(np.linalg.norm(moved - origin), np.hypot(10, 10) + 0.1)
    np.testing.assert_allclose((moved - origin)[0], (moved - origin)[1])


def test_readers_take_the_rescaled_depth_where_the_stage_wrote_one(tmp_path):
    (tmp_path / "depth").mkdir()
    (tmp_path / "object_depth").mkdir()
    np.save(tmp_path / "object_depth" / "000001.npy", np.zeros((2, 2)))
    assert prepared_depth_path(tmp_path, "000001") == tmp_path / "object_depth" / "000001.npy"
    assert prepared_depth_path(tmp_path, "000000") == tmp_path / "depth" / "000000.npy"


def test_config_refuses_impossible_values():
    with pytest.raises(ValueError, match="max_correction"):
        ObjectDepthConfig(max_correction=1.5)
    with pytest.raises(ValueError, match="min_returns"):
        ObjectDepthConfig(min_returns=0)


def test_stage_on_a_synthetic_scene_brings_the_movers_to_their_true_depth(tmp_path):
    from radar4dgs.cli import main
    from radar4dgs.config import preset
    from radar4dgs.datasets.synth import SynthConfig, synthesize

    scene = synthesize(preset(SynthConfig, "tiny", seed=7, num_frames=6), tmp_path / "scene", progress=False)
    assert main(["prepare", str(scene), "--preset", "tiny", "--quiet"]) == 0
    assert main(["frontend-eval", str(scene), "--json", str(tmp_path / "fe.json")]) == 0
    report = json.loads((tmp_path / "fe.json").read_text())["object_depth"]
    # The prior's distortion leaves the movers 1 % too deep; their returns bring them within 0.3 %.
    assert report["mover_bias_before"] > 0.008 and abs(report["mover_bias_after"]) < 0.003
    assert report["mover_absrel_after"] < report["mover_absrel_before"]
    assert report["rescaled"] >= 6 and report["mover_pixels"] > 500
    from radar4dgs.evaluate.dynamic_depth import object_depth_metrics
    from radar4dgs.io.scene import read_scene

    nothing_near = object_depth_metrics(read_scene(scene), scene / "prepared", max_depth=0.5)
    assert nothing_near["mover_pixels"] == 0 and nothing_near["mover_absrel_after"] is None
    summary = json.loads((scene / "prepared" / "object_depth" / "summary.json").read_text())
    written = sorted(p.stem for p in (scene / "prepared" / "object_depth").glob("*.npy"))
    assert written == [f["name"] for f in summary["frames"] if any(o["applied"] for o in f["objects"])]
    # Off: nothing rescaled, every reader falls back to the depth stage's maps.
    assert main(["prepare", str(scene), "--preset", "tiny", "--quiet", "--only", "object_depth",
                 "--config.object-depth.no-enabled"]) == 0
    assert not list((scene / "prepared" / "object_depth").glob("*.npy"))
