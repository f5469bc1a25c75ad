"""prepare_depth / depth_frontend_metrics end to end on hand-made scene folders."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from _depth_helpers import write_scene
from PIL import Image

from radar4dgs.config import load_config
from radar4dgs.depth import DepthConfig, DepthWarning, depth_frontend_metrics, evaluate_depth_methods, prepare_depth
from radar4dgs.io.scene import read_scene

# The module's scene has an empty radar frame on purpose (frame 2): every load of it says so.
pytestmark = pytest.mark.filterwarnings("ignore:.*000002.npy. empty radar frame:radar4dgs.io.scene.SceneWarning")


def _all_static(scene):
    return [np.ones(len(scene.load_radar(i)), bool) for i in range(len(scene))]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("depth") / "scene"
    write_scene(root, frames=6, empty_radar_frames=(2,))
    return read_scene(root)


def test_prepare_depth_writes_metric_depth_confidence_sky_and_summary(scene, tmp_path):
    prepared = tmp_path / "prepared"
    with pytest.warns(DepthWarning, match="frame 000002.*000001, 000003"):
        summary = prepare_depth(scene, prepared, DepthConfig(), progress=False, static_masks=_all_static(scene))
    names = [f.name for f in scene.frames]
    for name in names:
        depth = np.load(prepared / "depth" / f"{name}.npy")
        conf = np.load(prepared / "depth" / f"{name}_confidence.npy")
        sky = np.asarray(Image.open(prepared / "depth" / "sky" / f"{name}.png"))
        assert depth.dtype == np.float32 and depth.shape == (90, 160)
        assert conf.dtype == np.float32 and conf.min() >= 0 and conf.max() <= 1
        assert sky.dtype == np.uint8 and set(np.unique(sky)) <= {0, 255}
        assert np.isposinf(depth[sky == 255]).all() and np.isfinite(depth[sky == 0]).all()
        assert (conf[sky == 255] == 0).all()
        assert (prepared / "depth" / "relative" / f"{name}.npy").is_file()
    on_disk = json.loads((prepared / "depth" / "summary.json").read_text())
    assert on_disk == json.loads(json.dumps(summary))
    assert summary["method"] == "affine" and summary["source"] == "prior"
    assert summary["fallbacks"] == ["000002"]
    frame = summary["frames"][2]
    assert frame["parameters_from"] == "neighbours" and frame["fallback_frames"] == ["000001", "000003"]
    good = summary["frames"][0]
    assert good["num_valid_pairs"] >= 60 and good["scale"] == pytest.approx(1 / 3.0, rel=0.02)
    assert good["shift"] == pytest.approx(-0.2 / 3.0, rel=0.05)
    assert isinstance(load_config(DepthConfig, prepared / "depth" / "config.json"), DepthConfig)
    # No temporary folders are left behind.
    assert sorted(p.name for p in prepared.iterdir()) == ["depth"]
    assert (prepared / "depth" / "sky").is_dir()

    metrics = depth_frontend_metrics(scene, prepared)
    assert metrics["depth_absrel"] < 0.02
    assert metrics["depth_rmse"] < 1.0
    assert metrics["sky_iou"] > 0.9
    assert metrics["depth_fallback_frames"] == 1 and metrics["depth_method"] == "affine"
    assert metrics["scale_error_median"] is None  # the prior has a shift: no pure scale


def test_prepare_depth_replaces_its_outputs(scene, tmp_path):
    prepared = tmp_path / "prepared"
    config = DepthConfig(keep_relative=False, sky_source="none")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        prepare_depth(scene, prepared, DepthConfig(), progress=False, static_masks=_all_static(scene))
        prepare_depth(scene, prepared, config, progress=False, static_masks=_all_static(scene))
    assert not (prepared / "depth" / "relative").exists()
    sky = np.asarray(Image.open(prepared / "depth" / "sky" / f"{scene.frames[0].name}.png"))
    assert not sky.any()


def test_static_flags_from_the_prepared_radar_folder(scene, tmp_path):
    prepared = tmp_path / "prepared"
    (prepared / "radar").mkdir(parents=True)
    for i, frame in enumerate(scene.frames):
        dynamic = np.zeros(len(scene.load_radar(i)), bool)
        dynamic[:10] = True
        np.savez(prepared / "radar" / f"{frame.name}.npz", dynamic=dynamic)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        summary = prepare_depth(scene, prepared, DepthConfig(), progress=False)
    first = summary["frames"][0]
    assert first["static_source"] == "prepared radar"
    assert first["rejected"]["dynamic"] == 10 and first["num_static"] == first["num_radar_points"] - 10


def test_oracle_with_paper_recovers_unit_scale(scene, tmp_path):
    prepared = tmp_path / "prepared"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        summary = prepare_depth(scene, prepared, DepthConfig(source="oracle"), progress=False,
                                static_masks=_all_static(scene))
    assert summary["method"] == "paper" and summary["prior_kind"] == "depth"
    metrics = depth_frontend_metrics(scene, prepared)
    assert metrics["scale_error_median"] is not None and metrics["scale_error_median"] < 0.01


def test_paper_single_scale_fails_on_a_shifted_prior_and_affine_does_not(scene):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        result = evaluate_depth_methods(scene, DepthConfig(), ("affine", "paper"), static_masks=_all_static(scene))
    assert result["affine"]["depth_absrel"] < 0.02
    assert result["paper"]["depth_absrel"] > 3 * result["affine"]["depth_absrel"]


def test_sky_prior_is_used_when_present(tmp_path):
    root = tmp_path / "scene"
    write_scene(root, frames=3, with_sky_prior=True)
    scene = read_scene(root)
    summary = prepare_depth(scene, tmp_path / "prepared", DepthConfig(), progress=False,
                            static_masks=_all_static(scene))
    assert summary["sky_sources"] == ["prior"]
    assert depth_frontend_metrics(scene, tmp_path / "prepared")["sky_iou"] == 1.0


def test_robust_to_ghosts_and_clutter_end_to_end(tmp_path):
    root = tmp_path / "scene"
    write_scene(root, frames=3, ghosts=30, clutter=40, noise=0.05)
    scene = read_scene(root)
    summary = prepare_depth(scene, tmp_path / "prepared", DepthConfig(), progress=False,
                            static_masks=_all_static(scene))
    assert summary["fallbacks"] == []
    assert depth_frontend_metrics(scene, tmp_path / "prepared")["depth_absrel"] < 0.03


def test_missing_prior_folder_is_a_clear_error(scene, tmp_path):
    with pytest.raises(FileNotFoundError, match="sky_mask"):
        prepare_depth(scene, tmp_path / "p", DepthConfig(sky_source="prior"), progress=False,
                      static_masks=_all_static(scene))


def test_write_depth_into_a_stage_folder(scene, tmp_path):
    """The form the prepare command's stages use: write into a given (temporary) folder, static
    flags from the radar stage's folder, progress as a wrapper callable."""
    from radar4dgs.depth import write_depth

    radar_dir = tmp_path / "prepared" / "radar"
    radar_dir.mkdir(parents=True)
    for i, frame in enumerate(scene.frames):
        np.savez(radar_dir / f"{frame.name}.npz", dynamic=np.zeros(len(scene.load_radar(i)), bool))
    seen = []

    def wrapper(items):
        seen.append(True)
        return items

    stage = tmp_path / "prepared" / "depth"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        summary = write_depth(scene, stage, stage / "sky", DepthConfig(), wrapper, radar_dir=radar_dir)
    assert seen and summary["frames"][0]["static_source"] == "prepared radar"
    assert (stage / "sky" / f"{scene.frames[0].name}.png").is_file()
    assert depth_frontend_metrics(scene, tmp_path / "prepared")["sky_iou"] > 0.9
