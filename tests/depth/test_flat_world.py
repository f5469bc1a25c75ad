"""The weight-free flat-world depth source: closed-form geometry, radar scaling on a synthetic scene,
the "auto" fallback, the metric-prior safeguards, and the real aiMotive sample end to end."""

from __future__ import annotations

import math
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize
from radar4dgs.depth import (
    DepthConfig,
    DepthWarning,
    FrameFit,
    depth_anything_available,
    fill_from_neighbours,
    flat_world_depth,
    limit_metric_correction,
    prepare_depth,
)
from radar4dgs.depth.depth_maps import frame_confidences
from radar4dgs.depth.flat_world import lidar_ground_z
from radar4dgs.depth.pairs import RadarPairs
from radar4dgs.depth.sources import resolve_source
from radar4dgs.io.scene import read_mask_png, read_scene

FIXTURE = Path(__file__).resolve().parents[3] / "shared" / "fixtures" / "aimotive-night"

# Principal point on a pixel centre so that rows give round ray slopes: row v has slope (v - 45) / 100.
K = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 45.0], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 160, 90


def _camera_to_ego(height: float, pitch_down: float = 0.0) -> np.ndarray:
    """(4, 4) OpenCV camera looking along ego x at ``height`` m, pitched down by ``pitch_down`` rad."""
    c, s = math.cos(pitch_down), math.sin(pitch_down)
    # Columns: camera x (right) = -ego y; camera y (down) and z (forward) turned about camera x.
    pose = np.eye(4)
    pose[:3, 0] = [0.0, -1.0, 0.0]
    pose[:3, 1] = [-s, 0.0, -c]
    pose[:3, 2] = [c, 0.0, -s]
    pose[2, 3] = height
    return pose


def test_level_camera_sees_the_closed_form_ground_and_the_wall():
    depth = flat_world_depth(K, _camera_to_ego(1.5), WIDTH, HEIGHT, far=80.0)
    assert depth.shape == (HEIGHT, WIDTH)
    # z-depth of the ground = h / (downward ray slope): row 75 descends 0.3 m per metre -> 5 m.
    assert depth[75, 80] == pytest.approx(1.5 / 0.3)
    assert depth[48, 80] == pytest.approx(1.5 / 0.03)
    # z-depth, not range: the same row gives the same depth in every column on a level camera.
    np.testing.assert_allclose(depth[75], 5.0)
    # 1.5 / 0.01 = 150 m is beyond the cap; the horizon row and everything above are the wall.
    assert depth[46, 80] == 80.0
    assert (depth[:46] == 80.0).all()
    # A ground plane 0.3 m above the ego origin: the camera is 1.2 m above the road.
    assert flat_world_depth(K, _camera_to_ego(1.5), WIDTH, HEIGHT, ground_z=0.3)[75, 80] == pytest.approx(4.0)


def test_pitched_camera_matches_the_hand_computed_ray():
    theta, h = 0.1, 1.5
    depth = flat_world_depth(K, _camera_to_ego(h, theta), WIDTH, HEIGHT, far=80.0)
    # The ray (0, y, 1) descends y cos(theta) + sin(theta) metres per metre of z-depth.
    assert depth[45, 80] == pytest.approx(h / math.sin(theta))
    y = (70 - 45) / 100.0
    assert depth[70, 80] == pytest.approx(h / (y * math.cos(theta) + math.sin(theta)))
    # The horizon moved up by fy tan(theta) = 10 rows, to row 35: row 38 sees the ground at
    # 1.5 / (-0.07 cos + sin) = 49.7 m, row 36 at 147 m (capped), row 34 none.
    assert depth[38, 80] == pytest.approx(h / (-0.07 * math.cos(theta) + math.sin(theta)))
    assert depth[36, 80] == 80.0 and depth[34, 80] == 80.0


def test_camera_below_the_ground_plane_is_refused():
    with pytest.raises(ValueError, match="flat_world_ground_z"):
        flat_world_depth(K, _camera_to_ego(1.5), WIDTH, HEIGHT, ground_z=1.6)


def test_lidar_ground_is_the_dense_low_band():
    rng = np.random.default_rng(0)
    # Ego origin 0.8 m above the road (a sensor frame): road at z = -0.8, a car and a wall above.
    road = np.column_stack([rng.uniform(3, 30, 2000), rng.uniform(-6, 6, 2000), rng.normal(-0.8, 0.02, 2000)])
    car = np.column_stack([rng.uniform(10, 14, 600), rng.uniform(-1, 1, 600), rng.uniform(-0.6, 0.7, 600)])
    wall = np.column_stack([rng.uniform(3, 30, 800), np.full(800, 5.5), rng.uniform(-0.8, 3.0, 800)])
    ghosts = np.column_stack([rng.uniform(3, 30, 30), rng.uniform(-6, 6, 30), rng.uniform(-3, -1, 30)])
    points = np.concatenate([road, car, wall, ghosts])
    assert lidar_ground_z(points) == pytest.approx(-0.8, abs=0.03)
    assert math.isnan(lidar_ground_z(points[:10]))


# ---------------------------------------------------------------------------------------------
# The metric-prior safeguards of the scale recovery


def _fit(a: float, b: float, ok: bool = True, reason: str = "ok") -> FrameFit:
    pairs = RadarPairs(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 3), int),
                       np.zeros(0, np.int8))
    return FrameFit("affine", a, b, ok, reason, pairs, np.zeros(0, bool))


def test_no_fit_anywhere_uses_the_metric_prior_unscaled():
    fits = [_fit(math.nan, math.nan, False, "6 inliers < min_pairs 12")] * 3
    with pytest.raises(ValueError, match="no frame"):
        fill_from_neighbours(fits, [0.0, 0.1, 0.2])
    with pytest.warns(DepthWarning, match="unscaled"):
        parameters = fill_from_neighbours(fits, [0.0, 0.1, 0.2], metric_prior=True)
    assert [(p.a, p.b, p.source) for p in parameters] == [(1.0, 0.0, "metric prior")] * 3
    # Half confidence, not zero: the prior is metric, only unconfirmed.
    confidences = frame_confidences(fits, parameters, DepthConfig())
    assert all(c == 0.5 and all(math.isnan(r) for r in span) for c, span in confidences)


def test_fits_that_move_the_metric_prior_too_far_are_rejected():
    fits = [_fit(1.05, 0.0), _fit(0.5, 0.0), _fit(1.0, -0.02), _fit(1.0, 0.001), _fit(math.nan, math.nan, False)]
    out = limit_metric_correction(fits, 0.25, 1.0 / 80.0)
    assert [f.ok for f in out] == [True, False, False, True, False]
    assert "100%" in out[1].reason  # depth doubled by a = 0.5
    assert "infinity" in out[2].reason  # 1/80 - 0.02 < 0: the far end flips behind the camera
    assert out[1].extra["rejected_a"] == 0.5


# ---------------------------------------------------------------------------------------------
# A synthetic scene


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> Path:
    config = preset(SynthConfig, "tiny", seed=7, num_frames=6)
    return synthesize(config, tmp_path_factory.mktemp("flat-world") / "scene", progress=False)


def _road_pixels(scene, index: int, far: float) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) bool pixels whose true surface lies on the ground (ego z within 5 cm of 0, nearer
    than ``far``) and the (H, W) true depth."""
    from radar4dgs.depth.geometry import pixel_grid, pixel_rays

    truth = scene.load_optional("gt/depth", index).astype(np.float64)
    v, u = pixel_grid(scene.camera.width, scene.camera.height)
    rays = pixel_rays(scene.camera.K, u, v)
    cam_to_ego = scene.camera.cam_to_ego
    with np.errstate(invalid="ignore"):
        z_ego = (rays * truth[..., None]) @ cam_to_ego[2, :3] + cam_to_ego[2, 3]
    return np.isfinite(truth) & (np.abs(z_ego) < 0.05) & (truth < far), truth


def test_synthetic_road_depth_after_radar_scaling(synthetic, tmp_path):
    scene = read_scene(synthetic)
    config = DepthConfig(source="flat-world", **DepthConfig.PRESETS["tiny"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        summary = prepare_depth(scene, tmp_path / "prepared", config, progress=False)
    assert summary["source"] == "flat-world" and summary["prior_kind"] == "inverse-depth"
    assert summary["flat_world"]["ground_source"].startswith("lidar")
    assert abs(summary["flat_world"]["ground_z"]) < 0.05
    for i, entry in enumerate(summary["frames"]):
        assert math.isfinite(entry["scale"]) and math.isfinite(entry["shift"])
        assert entry["parameters_from"] in ("fit", "neighbours", "metric prior")
        road, truth = _road_pixels(scene, i, config.flat_world_far)
        assert road.mean() > 0.2
        depth = np.load(tmp_path / "prepared" / "depth" / f"{scene.frames[i].name}.npy")
        error = np.abs(depth[road] / truth[road] - 1)
        assert np.median(error) < 0.02 and np.percentile(error, 90) < 0.06


def test_auto_falls_back_to_flat_world_without_prior_or_weights(synthetic, tmp_path, monkeypatch):
    pytest.importorskip("huggingface_hub")
    import huggingface_hub.constants

    # An empty HuggingFace cache: the default hub id is absent even where someone cached it.
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    root = tmp_path / "scene"
    shutil.copytree(synthetic, root, ignore=shutil.ignore_patterns("mono_depth", "prepared"))
    scene = read_scene(root)
    config = DepthConfig(**DepthConfig.PRESETS["tiny"])
    assert not scene.has("priors/mono_depth") and not depth_anything_available(config)
    assert resolve_source(scene, config) == "flat-world"
    with pytest.warns(DepthWarning) as record:  # the notice, and frames whose fit is out of bounds
        summary = prepare_depth(scene, tmp_path / "prepared", config, progress=False)
    notices = [str(r.message) for r in record if "no learned depth prior" in str(r.message)]
    assert len(notices) == 1 and "\n" not in notices[0]
    assert re.search("no learned depth prior.*flat-world.*Depth-Anything-V2 weights", notices[0])
    assert summary["source"] == "flat-world"
    # A local model folder counts as weights; one that cannot be loaded still falls back.
    broken = tmp_path / "broken-model"
    broken.mkdir()
    (broken / "config.json").write_text("{}")
    config = DepthConfig(model=str(broken), **DepthConfig.PRESETS["tiny"])
    if depth_anything_available(config):  # transformers installed
        assert resolve_source(scene, config) == "depth-anything-v2"
        with pytest.warns(DepthWarning) as record:
            assert prepare_depth(scene, tmp_path / "prepared", config, progress=False)["source"] == "flat-world"
        assert any("cannot load depth model" in str(r.message) for r in record)
    # An explicit source never falls back.
    assert resolve_source(scene, DepthConfig(source="flat-world")) == "flat-world"


# ---------------------------------------------------------------------------------------------
# The real aiMotive sample: no prior, no weights, ~40 radar targets a frame


@pytest.mark.skipif(not FIXTURE.is_dir(), reason="shared aiMotive fixture not present")
def test_aimotive_prepares_radar_and_depth(tmp_path, monkeypatch):
    import huggingface_hub.constants

    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.datasets.convert.aimotive import convert_aimotive

    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    root = convert_aimotive(FIXTURE, tmp_path / "aim", scale=0.25, progress=False)
    with pytest.warns(DepthWarning) as record:  # the flat-world notice, and no frame fits this sparse radar
        status = run_prepare(root, config=PrepareConfig(), only=("radar", "depth"), progress=False)
    assert any("flat-world" in str(r.message) for r in record)
    assert status == {"radar": "ran", "depth": "ran"}
    scene = read_scene(root)
    import json

    summary = json.loads((root / "prepared" / "depth" / "summary.json").read_text())
    assert summary["source"] == "flat-world" and summary["num_frames"] == len(scene) == 50
    for entry in summary["frames"]:
        assert math.isfinite(entry["scale"]) and math.isfinite(entry["shift"]) and entry["scale"] > 0
        # Every frame says where its parameters came from (this sparse radar rarely fits).
        assert entry["parameters_from"] in ("fit", "neighbours", "metric prior")
    for frame in scene.frames:
        depth = np.load(root / "prepared" / "depth" / f"{frame.name}.npy")
        sky = read_mask_png(root / "prepared" / "depth" / "sky" / f"{frame.name}.png")
        assert depth.shape == (141, 320) and 0.1 < sky.mean() < 0.9
        ground = depth[~sky]
        assert np.isfinite(ground).all() and (ground > 0).all()
        assert np.isposinf(depth[sky]).all()
