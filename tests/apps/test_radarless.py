"""A radar-less scene end to end: the shared tiny run exported as a nerfstudio dataset and
converted back (no radar), prepared (the radar stages say so; sparse depth from the points),
trained with ``--method static`` and evaluated to a finite PSNR; ``--method ours`` and the other
radar steps refuse in one line naming the scene."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from radar4dgs.cli import main
from radar4dgs.depth.points import point_depth
from radar4dgs.io.scene import SceneError, read_mask_png, read_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def radarless(tiny_trained_run, tmp_path_factory):
    """The tiny run's cameras exported to nerfstudio and converted into a radar-less scene."""
    root = tmp_path_factory.mktemp("radarless")
    assert main(["export", str(tiny_trained_run / "run"), "--format", "nerfstudio", "--out", str(root / "ns")]) == 0
    assert main(["convert", "nerfstudio", str(root / "ns"), str(root / "scene"), "--quiet"]) == 0
    return root / "scene"


def test_the_scene_has_no_radar_and_radar_readers_say_so(radarless):
    scene = read_scene(radarless)
    assert not scene.has_radar and not scene.radar and scene.has_points
    for step in (lambda: scene.load_radar(0), lambda: scene.radar_to_world(0), lambda: scene.radar.fields):
        with pytest.raises(SceneError, match=r"scene: has no radar \(scene.json has no 'radar' section\)"):
            step()


def test_point_depth_is_the_nearest_unoccluded_point_per_pixel():
    K = np.array([[10.0, 0, 5.0], [0, 10.0, 5.0], [0, 0, 1]])
    # Two points on pixel (5, 5): the nearer wins; a point on (7, 5) behind its neighbour (8, 5) by
    # more than 10 % is occluded; one behind the camera and one outside the image are dropped.
    points = np.array([[0, 0, 4.0], [0, 0, 3.0], [0.8, 0, 4.0], [0.6, 0, 3.0], [0, 0, -2.0], [5.0, 0, 1.0]])
    depth = point_depth(points, K, 11, 11, min_depth=0.5, max_depth=100.0)
    assert depth[5, 5] == 3.0 and depth[5, 7] == 3.0 and np.isnan(depth[5, 8])
    assert np.isfinite(depth).sum() == 2


def test_prepare_train_static_and_eval_without_radar(radarless, tmp_path, capsys):
    assert main(["prepare", str(radarless), "--preset", "tiny", "--quiet"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == ["radar", "depth", "masks", "object_depth", "flow"]
    assert all("(the scene has no radar: " in line for line in lines)
    assert "the sparse depth of the scene's point cloud" in lines[1] and "empty dynamic masks" in lines[2]
    scene = read_scene(radarless)
    prepared = radarless / "prepared"
    # The depth is the points' own depth where they land, unknown (NaN) elsewhere; no sky, no motion.
    world, _ = scene.load_points()
    w2c = scene.world_to_camera(0)
    expected = point_depth(world @ w2c[:3, :3].T + w2c[:3, 3], scene.camera.K, scene.camera.height,
                           scene.camera.width, 1.0, 1000.0)
    depth = np.load(prepared / "depth" / f"{scene.frames[0].name}.npy")
    np.testing.assert_array_equal(depth, expected)
    assert 0.05 < np.isfinite(depth).mean() < 0.5
    assert not read_mask_png(prepared / "masks" / f"{scene.frames[0].name}.png").any()
    assert not read_mask_png(prepared / "depth" / "sky" / f"{scene.frames[0].name}.png").any()

    run = tmp_path / "run"
    common = ["--preset", "tiny", "--config.optim.iterations", "30", "--no-tensorboard", "--quiet", "--no-eval"]
    assert main(["train", str(radarless), "--out", str(run), "--method", "static", *common]) == 0
    assert main(["eval", str(run), "--no-video", "--no-report", "--no-lpips"]) == 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert math.isfinite(metrics["nvs"]["psnr"]) and metrics["nvs"]["psnr"] > 12.0
    assert metrics["nvs"]["n_frames"] == len(scene.test_indices) == 2
    capsys.readouterr()

    # The full method needs the radar: one line naming the scene, and no run folder left.
    assert main(["train", str(radarless), "--out", str(tmp_path / "ours"), "--method", "ours", *common]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith(f"radar4dgs train: {radarless}: has no radar (--method ours")
    assert not (tmp_path / "ours" / "config.json").exists()
    assert main(["fit-motion", str(radarless)]) == 1
    assert capsys.readouterr().err.strip() == (f"radar4dgs fit-motion: {radarless}: has no radar (scene.json has no "
                                               f"'radar' section), which this step needs")


def test_a_monocular_prior_is_scaled_by_the_points_in_place_of_the_radar(radarless, tiny_trained_run, tmp_path):
    import shutil

    from radar4dgs.apps.prepare import PrepareConfig, run_prepare
    from radar4dgs.config import preset

    original = read_scene(tiny_trained_run / "scene")
    dense = tmp_path / "dense"
    shutil.copytree(radarless, dense, ignore=shutil.ignore_patterns("prepared"))
    # A relative inverse-depth prior with an unknown scale and shift: 1/z = x / 0.7 - 0.01 / 0.7.
    (dense / "priors" / "mono_depth").mkdir()
    for i, frame in enumerate(original.frames):
        z = original.load_optional("gt/depth", i)
        np.save(dense / "priors" / "mono_depth" / f"{frame.name}.npy",
                np.where(np.isfinite(z), 0.7 / z + 0.01, 0.01).astype(np.float32))
    assert run_prepare(dense, None, preset(PrepareConfig, "tiny"), only=("radar", "depth"), progress=False) == \
        {"radar": "ran", "depth": "ran"}
    summary = json.loads((dense / "prepared" / "depth" / "summary.json").read_text())
    assert (summary["source"], summary["method"], summary["fallbacks"]) == ("prior", "affine", [])
    assert summary["anchors"] == "the scene's point cloud (the scene has no radar)"
    assert summary["sky_sources"] == ["fallback"]
    scene = read_scene(dense)
    world, _ = scene.load_points()
    for i, frame in enumerate(scene.frames):
        depth = np.load(dense / "prepared" / "depth" / f"{frame.name}.npy")
        # Dense: every pixel has a depth or is sky; the fit agrees with the points it was given ...
        assert np.isfinite(depth).mean() > 0.5 and not np.isnan(depth).any()
        w2c = scene.world_to_camera(i)
        at = point_depth(world @ w2c[:3, :3].T + w2c[:3, 3], scene.camera.K, scene.camera.height,
                         scene.camera.width, 1e-6, 1000.0)
        known = np.isfinite(at) & np.isfinite(depth)
        ratio = depth[known] / at[known] - 1  # unbiased, within the points' own noise (~2 % here)
        assert abs(np.median(ratio)) < 0.01 and np.median(np.abs(ratio)) < 0.03
        # ... and with the ground truth to the points' own accuracy (they came from prepared depth);
        # the sky comes from the fallback detector.
        gt = original.load_optional("gt/depth", i)
        both = np.isfinite(gt) & np.isfinite(depth)
        assert np.median(np.abs(depth[both] / gt[both] - 1)) < 0.03
        sky, gt_sky = ~np.isfinite(depth), original.load_optional("gt/sky_mask", i)
        assert (sky & gt_sky).sum() / (sky | gt_sky).sum() > 0.99


def test_without_points_either_the_depth_stage_refuses(radarless, tmp_path, capsys):
    import shutil

    bare = tmp_path / "bare"
    shutil.copytree(radarless, bare, ignore=shutil.ignore_patterns("prepared", "priors"))
    assert main(["prepare", str(bare), "--preset", "tiny", "--quiet"]) == 1
    assert capsys.readouterr().err.strip() == (
        f"radar4dgs prepare: {bare}: has no radar and no point cloud (priors/points3d.npy): the depth stage "
        "needs one of them to make the depth metric")


def test_inspect_summarises_a_camera_only_scene(radarless, tmp_path, capsys):
    sheet = tmp_path / "sheet.png"
    assert main(["inspect", str(radarless), "--sheet", str(sheet), "--json", str(tmp_path / "s.json"),
                 "--frames", "3"]) == 0
    assert "radar      none (a camera-only scene)" in capsys.readouterr().out
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["radar_fields"] is None and summary["radar_points_per_frame"] is None
    assert summary["frames"] == len(read_scene(radarless))
    import cv2

    image = cv2.imread(str(sheet))
    # Two columns of 480-px tiles over the legend: the frames themselves, no radar dots.
    assert image.shape[1] == 960 and image.shape[0] > 28
