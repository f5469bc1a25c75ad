"""The synthetic generator checked against physics and geometry, not against its own code.

Every check reads only the written scene folder (poses, calibration, metadata and arrays) and
recomputes the expected quantity from first principles.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _synth_helpers import backproject, bilinear, depth_agrees, doppler_residual, inside_cars, project
from scipy.ndimage import binary_erosion

from radar4dgs.cli import main
from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig, synthesize, traffic_profile
from radar4dgs.io import read_scene

EXACT_RADAR = {"range_std": 0.0, "azimuth_std_deg": 0.0, "elevation_std_deg": 0.0, "v_r_std": 0.0}


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    """The tiny preset with default noise (20 frames)."""
    out = tmp_path_factory.mktemp("synth") / "noisy"
    synthesize(preset(SynthConfig, "tiny", seed=2), out, progress=False)
    return read_scene(out)


@pytest.fixture(scope="module")
def exact(tmp_path_factory):
    """Tiny, 8 frames, radar measurement noise off (clutter and ghosts stay, labelled -1)."""
    out = tmp_path_factory.mktemp("synth") / "exact"
    synthesize(preset(SynthConfig, "tiny", seed=5, num_frames=8, radar=EXACT_RADAR), out, progress=False)
    return read_scene(out)


# ---------------------------------------------------------------- the scene folder


def test_scene_loads_with_every_folder_and_metadata(noisy):
    assert len(noisy) == 20 and (noisy.camera.width, noisy.camera.height) == (160, 90)
    assert set(noisy.optional_folders()) == {"lidar", "priors/mono_depth", "priors/sky_mask", "gt/depth",
                                             "gt/dynamic_mask", "gt/sky_mask", "gt/flow", "gt/radar_labels"}
    assert noisy.source == {"dataset": "synthetic", "seed": 2, "preset": None, "generator": "radar4dgs.synth"}
    kinds = [o["kind"] for o in noisy.extra["synthetic"]["objects"]]
    assert kinds[0] == "ego" and 2 <= kinds.count("parked") <= 4 and 2 <= kinds.count("moving") <= 4
    speed = noisy.frames[0].ego_velocity[0]
    assert 5.0 <= speed <= 20.5 and np.allclose(noisy.frames[0].ego_to_world, np.eye(4))
    counts = [len(noisy.load_radar(i)) for i in range(len(noisy))]
    assert 100 <= np.median(counts) <= 1000
    assert noisy.load_image(0).std() > 20  # a textured picture, not a flat fill


def test_poses_agree_with_recorded_velocity_and_yaw_rate(noisy):
    """Central differences of the poses give the recorded ego velocity and yaw rate."""
    dt = noisy.frames[1].timestamp - noisy.frames[0].timestamp
    for i in range(1, len(noisy) - 1):
        before, now, after = (noisy.frames[j].ego_to_world for j in (i - 1, i, i + 1))
        v_world = (after[:3, 3] - before[:3, 3]) / (2 * dt)
        assert np.allclose(now[:3, :3].T @ v_world, noisy.frames[i].ego_velocity, atol=0.02)
        yaw = [np.arctan2(m[1, 0], m[0, 0]) for m in (before, after)]
        yaw_rate = (yaw[1] - yaw[0]) / (2 * dt)
        assert abs(yaw_rate - noisy.frames[i].extra["ego_angular_velocity"][2]) < 2e-3


# ---------------------------------------------------------------- radar physics


def test_static_radar_points_obey_the_doppler_model_exactly(exact):
    moving_residuals = []
    for i in range(len(exact)):
        residual, labels = doppler_residual(exact, i)
        assert (labels == 0).sum() > 50
        assert np.abs(residual[labels == 0]).max() < 1e-4
        moving_residuals.append(residual[labels == 1])
    moving = np.abs(np.concatenate(moving_residuals))
    # Moving cars must break the static model (crossing cars can be nearly tangential, so not all).
    assert len(moving) > 10 and np.mean(moving > 0.5) > 0.5


def test_static_radar_points_obey_the_doppler_model_within_noise(noisy):
    residuals = np.concatenate([r[labels == 0]
                                for r, labels in (doppler_residual(noisy, i) for i in range(len(noisy)))])
    # v_r noise 0.08 m/s plus azimuth noise 0.3 deg times the radar speed (<= 20 m/s).
    speed = noisy.frames[0].ego_velocity[0]
    sigma = np.hypot(0.08, speed * np.radians(0.3))
    assert np.median(np.abs(residuals)) < 1.0 * sigma
    assert np.percentile(np.abs(residuals), 95) < 3.0 * sigma


def test_radar_labels_match_the_cars_they_hit(exact):
    """Label 1 points lie on moving cars; label 0 points do not; each frame has a few -1 points."""
    minus_one = ghosts = 0
    for i in range(len(exact)):
        scan = exact.load_radar(i)
        labels = exact.load_optional("gt/radar_labels", i)
        world = scan.xyz.astype(np.float64) @ exact.radar_to_world(i)[:3, :3].T + exact.radar_to_world(i)[:3, 3]
        on_moving = inside_cars(exact, i, world, moving=True, slack=0.01)
        assert on_moving[labels == 1].all()
        assert not on_moving[labels == 0].any()
        minus_one += (labels == -1).sum()
        # Multipath ghosts: -1 points below the road whose mirror image lies on a car.
        mirrored = world * np.array([1.0, 1.0, -1.0])
        on_car = inside_cars(exact, i, mirrored, moving=True) | inside_cars(exact, i, mirrored, moving=False)
        ghosts += ((labels == -1) & (world[:, 2] < 0) & on_car).sum()
    assert minus_one > 0 and ghosts > 0


def test_radar_points_project_onto_pixels_of_the_same_depth(exact, noisy):
    agree = []
    for i in range(len(exact)):
        scan = exact.load_radar(i)
        labels = exact.load_optional("gt/radar_labels", i)
        world = scan.xyz.astype(np.float64) @ exact.radar_to_world(i)[:3, :3].T + exact.radar_to_world(i)[:3, 3]
        uv, z = project(exact, i, world[labels >= 0])
        ok, inside = depth_agrees(exact, i, uv, z, rel_tol=0.01)
        agree.append(ok[inside])
    agree = np.concatenate(agree)
    # The camera sits 1 m higher than the radar: a few radar points are hidden behind cars or lie
    # on an edge; the rest match to 1 %.
    assert len(agree) > 200 and agree.mean() > 0.8
    errors = []
    for i in range(len(noisy)):
        scan = noisy.load_radar(i)
        labels = noisy.load_optional("gt/radar_labels", i)
        world = scan.xyz.astype(np.float64) @ noisy.radar_to_world(i)[:3, :3].T + noisy.radar_to_world(i)[:3, 3]
        uv, z = project(noisy, i, world[labels >= 0])
        _, inside = depth_agrees(noisy, i, uv, z, rel_tol=1.0)
        inverse = bilinear(1.0 / noisy.load_optional("gt/depth", i).astype(np.float64), uv[inside, 0], uv[inside, 1])
        errors.append(np.abs(inverse * z[inside] - 1.0))
    assert np.median(np.concatenate(errors)) < 0.05


# ---------------------------------------------------------------- camera ground truth


def test_flow_agrees_with_reprojection_into_the_next_frame(exact):
    static_ok, dynamic_ok = [], []
    for i in range(len(exact) - 1):
        points, sky = backproject(exact, i)
        flow = exact.load_optional("gt/flow", i).reshape(-1, 3).astype(np.float64)
        dynamic = exact.load_optional("gt/dynamic_mask", i).reshape(-1)
        moved = points + flow
        uv, z = project(exact, i + 1, moved)
        ok, inside = depth_agrees(exact, i + 1, uv, z, rel_tol=0.01)
        static_ok.append(ok[inside & ~sky & ~dynamic])
        dynamic_ok.append(ok[inside & dynamic])
        # Without the flow, moving pixels would not land on their surface again.
        uv0, z0 = project(exact, i + 1, points)
        ok0, inside0 = depth_agrees(exact, i + 1, uv0, z0, rel_tol=0.01)
        if (inside0 & dynamic).sum() > 30:
            assert ok0[inside0 & dynamic].mean() < ok[inside & dynamic].mean()
    assert np.concatenate(static_ok).mean() > 0.95
    dynamic_ok = np.concatenate(dynamic_ok)
    assert len(dynamic_ok) > 50 and dynamic_ok.mean() > 0.85


def test_flow_is_the_object_motion(exact):
    """Static pixels have zero flow; a moving car's pixels move by its velocity times dt."""
    dt = exact.frames[1].timestamp - exact.frames[0].timestamp
    objects = [o for o in exact.extra["synthetic"]["objects"] if o["kind"] == "moving"]
    for i in range(len(exact)):
        points, sky = backproject(exact, i)
        flow = exact.load_optional("gt/flow", i).reshape(-1, 3)
        static = ~exact.load_optional("gt/dynamic_mask", i).reshape(-1)
        assert np.abs(flow[static]).max() == 0.0
        for obj in objects:
            pose = np.asarray(obj["poses"][i])
            local = (points - pose[:3, 3]) @ pose[:3, :3]
            on = np.zeros(len(points), bool)
            for box in obj["boxes"]:
                on |= (np.abs(local - box["center"]) <= np.asarray(box["half_size"]) + 0.01).all(axis=1)
            if on.any():
                assert np.allclose(flow[on], np.asarray(obj["velocity"]) * dt, atol=1e-4)


def test_dynamic_mask_covers_exactly_the_moving_cars(noisy):
    covered = 0
    for i in range(len(noisy)):
        points, sky = backproject(noisy, i)
        mask = noisy.load_optional("gt/dynamic_mask", i).reshape(-1)
        on_moving = inside_cars(noisy, i, points, moving=True) & ~sky
        on_parked = inside_cars(noisy, i, points, moving=False) & ~sky
        assert np.array_equal(mask, on_moving)
        assert not mask[on_parked].any()
        covered += mask.sum()
        # A moving car's centre, where visible, is inside the mask.
        for obj in noisy.extra["synthetic"]["objects"]:
            if obj["kind"] != "moving":
                continue
            centre = np.asarray(obj["poses"][i]) @ np.array([0.0, 0.0, 0.6, 1.0])
            uv, z = project(noisy, i, centre[None, :3])
            u, v = np.round(uv[0]).astype(int)
            if 0 <= u < noisy.camera.width and 0 <= v < noisy.camera.height and z[0] > 0:
                seen_depth = noisy.load_optional("gt/depth", i)[v, u]
                if abs(seen_depth - z[0]) < obj["dims"][0] / 2 + 0.3:  # the car itself is seen there
                    assert mask.reshape(noisy.camera.height, -1)[v, u]
    assert covered > 100


def test_sky_masks_and_mono_depth_prior(noisy):
    synthetic = noisy.extra["synthetic"]["mono_depth_prior"]
    a, b = synthetic["a"], synthetic["b"]
    for i in (0, len(noisy) - 1):
        depth = noisy.load_optional("gt/depth", i)
        sky = noisy.load_optional("gt/sky_mask", i)
        assert np.array_equal(sky, ~np.isfinite(depth)) and 0.05 < sky.mean() < 0.7
        prior_sky = noisy.load_optional("priors/sky_mask", i)
        assert (prior_sky != sky).mean() < 0.05
        prior = noisy.load_optional("priors/mono_depth", i).astype(np.float64)
        interior = binary_erosion(sky, iterations=3)  # away from the blurred edges
        assert np.allclose(prior[interior], b, atol=0.05 * b + 1e-3)
        solid = ~sky & np.isfinite(depth)
        ratio = (prior[solid] - b) * depth[solid] / a
        assert abs(np.median(ratio) - 1.0) < 0.05 and np.percentile(np.abs(ratio - 1), 50) < 0.08


def test_lidar_points_lie_on_surfaces_seen_by_the_camera(noisy):
    for i in (0, len(noisy) // 2):
        lidar = noisy.load_optional("lidar", i).astype(np.float64)
        assert lidar.shape[1] == 4 and len(lidar) > 1000
        assert ((lidar[:, 3] >= 0) & (lidar[:, 3] <= 1)).all()
        ground = np.abs(lidar[:, 2]) < 0.1
        assert ground.mean() > 0.2
        ego_to_world = noisy.frames[i].ego_to_world
        world = lidar[:, :3] @ ego_to_world[:3, :3].T + ego_to_world[:3, 3]
        uv, z = project(noisy, i, world)
        ok, inside = depth_agrees(noisy, i, uv, z, rel_tol=0.03)
        assert inside.sum() > 200 and ok[inside].mean() > 0.7


# ---------------------------------------------------------------- determinism and the command


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_same_bytes_other_seed_other_layout(tmp_path):
    config = preset(SynthConfig, "tiny", seed=11, num_frames=2)
    synthesize(config, tmp_path / "a", progress=False)
    synthesize(config, tmp_path / "b", progress=False)
    synthesize(preset(SynthConfig, "tiny", seed=12, num_frames=2), tmp_path / "c", progress=False)
    a, b, c = (_files(tmp_path / n) for n in "abc")
    assert a == b
    layout = [read_scene(tmp_path / n).extra["synthetic"]["objects"] for n in "ac"]
    assert layout[0] != layout[1]
    assert a["images/000000.png"] != c["images/000000.png"]


def test_cli_synth_with_field_override(tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["synth", str(out), "--preset", "tiny", "--seed", "3", "--scene.num-frames", "2",
                 "--scene.radar.range-std", "0.1"]) == 0
    scene = read_scene(out)
    assert scene.source["seed"] == 3 and scene.source["preset"] == "tiny" and len(scene) == 2
    assert scene.extra["synthetic"]["config"]["radar"]["range_std"] == 0.1
    assert "wrote" in capsys.readouterr().out
    # An existing output is a user error: one line naming it, exit status 1 (--debug raises).
    assert main(["synth", str(out), "--preset", "tiny", "--scene.num-frames", "2"]) == 1
    assert f"{out}: already exists" in capsys.readouterr().err
    with pytest.raises(FileExistsError):
        main(["synth", str(out), "--preset", "tiny", "--scene.num-frames", "2", "--debug"])


def test_supersampled_image_is_the_area_mean_of_the_scene_rendered_larger(tmp_path):
    """Closed form: with the noise off, a pixel of ``supersample=2`` is the mean of the 2x2 pixels of the same
    scene rendered at twice the size (within the half level each 8-bit rounding adds); the ground truth stays the
    pixel centre's, which the centre-sampled render's image also follows closely but not exactly."""
    base = dict(seed=3, num_frames=3, traffic=traffic_profile("rush"), image_noise_std=0.0)
    synthesize(preset(SynthConfig, "tiny", supersample=2, **base), tmp_path / "ss", progress=False)
    synthesize(preset(SynthConfig, "tiny", width=320, height=180, **base), tmp_path / "big", progress=False)
    synthesize(preset(SynthConfig, "tiny", **base), tmp_path / "centre", progress=False)
    ss, big, centre = (read_scene(tmp_path / n) for n in ("ss", "big", "centre"))
    for i in range(3):
        image = ss.load_image(i).astype(np.float64)
        mean = big.load_image(i).astype(np.float64).reshape(90, 2, 160, 2, 3).mean(axis=(1, 3))
        assert np.abs(image - mean).max() <= 1.0
        assert np.abs(image - centre.load_image(i)).mean() > 1.0  # the two samplings do differ
        for truth in ("gt/dynamic_mask", "gt/depth"):
            np.testing.assert_array_equal(ss.load_optional(truth, i), centre.load_optional(truth, i))


def test_bad_options_are_refused(tmp_path):
    with pytest.raises(ValueError, match="num_frames"):
        synthesize(preset(SynthConfig, "tiny", num_frames=0), tmp_path / "x", progress=False)
    with pytest.raises(ValueError, match="supersample"):
        synthesize(preset(SynthConfig, "tiny", supersample=0), tmp_path / "x", progress=False)
    with pytest.raises(ValueError, match="radar.v_r_std"):
        synthesize(preset(SynthConfig, "tiny", radar={"v_r_std": -1.0}), tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()
