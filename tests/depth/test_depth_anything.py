"""The Depth-Anything-V2 source through HuggingFace transformers, with a tiny random model."""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pytest
from _depth_helpers import write_scene

from radar4dgs.depth import (
    DepthAnythingV2,
    DepthConfig,
    DepthModelError,
    DepthWarning,
    load_depth_anything,
    prepare_depth,
)
from radar4dgs.io.scene import read_scene


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """A few-kFLOP network on a shared CI machine: OpenMP threads spin against other processes and
    make each call ~100x slower; one thread for these tests, restored afterwards."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _tiny_model_folder(folder, depth_estimation_type="relative"):
    """Save a randomly initialised, tiny DepthAnythingForDepthEstimation (Dinov2 backbone with
    2 heads of width 16) and a DPT image processor to ``folder``."""
    transformers = pytest.importorskip("transformers")
    import torch

    torch.manual_seed(0)
    backbone = transformers.Dinov2Config(hidden_size=32, num_hidden_layers=4, num_attention_heads=2,
                                         intermediate_size=64, image_size=56, patch_size=14,
                                         out_indices=[1, 2, 3, 4], reshape_hidden_states=False)
    config = transformers.DepthAnythingConfig(backbone_config=backbone, neck_hidden_sizes=[8, 16, 32, 32],
                                              reassemble_hidden_size=32, fusion_hidden_size=16, head_hidden_size=8,
                                              patch_size=14, depth_estimation_type=depth_estimation_type)
    model = transformers.DepthAnythingForDepthEstimation(config).eval()
    # A random head outputs ~0 everywhere (ReLU): lift it so the prior has depth to scale.
    last_conv = [m for m in model.head.modules() if isinstance(m, torch.nn.Conv2d)][-1]
    with torch.no_grad():
        last_conv.bias.fill_(1.0)
    model.save_pretrained(folder)
    processor = transformers.DPTImageProcessor(size={"height": 56, "width": 56}, keep_aspect_ratio=True,
                                               ensure_multiple_of=14)
    processor.save_pretrained(folder)
    return folder


def test_tiny_random_depth_anything_runs_end_to_end(tmp_path):
    folder = _tiny_model_folder(tmp_path / "tiny-da")
    network = DepthAnythingV2(folder, device="cpu")
    assert network.kind == "inverse-depth"
    image = np.random.default_rng(0).integers(0, 255, (90, 160, 3), dtype=np.uint8)
    output = network(image)
    assert output.shape == (90, 160) and output.dtype == np.float32
    assert np.isfinite(output).all() and (output >= 0).all() and output.max() > 0

    write_scene(tmp_path / "scene", frames=3)
    scene = read_scene(tmp_path / "scene")
    # A random network's "depth" is nearly constant: the paper's single scale still votes.
    config = DepthConfig(source="depth-anything-v2", model=str(folder), device="cpu", scale_method="paper",
                         min_pairs=4, max_neighbour_depth_ratio=1.0)
    static = [np.ones(len(scene.load_radar(i)), bool) for i in range(len(scene))]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DepthWarning)
        summary = prepare_depth(scene, tmp_path / "prepared", config, progress=False, static_masks=static)
    assert summary["source"] == "depth-anything-v2" and summary["network"] == str(folder)
    assert summary["prior_kind"] == "inverse-depth"
    relative = np.load(tmp_path / "prepared" / "depth" / "relative" / f"{scene.frames[0].name}.npy")
    assert relative.shape == (90, 160)
    depth = np.load(tmp_path / "prepared" / "depth" / f"{scene.frames[0].name}.npy")
    assert depth.shape == (90, 160) and (depth > 0).all()


def test_metric_checkpoints_are_depth(tmp_path):
    folder = _tiny_model_folder(tmp_path / "tiny-metric", depth_estimation_type="metric")
    network = DepthAnythingV2(folder, device="cpu")
    assert network.kind == "depth"
    assert DepthConfig().resolved_kind("depth-anything-v2", "metric") == "depth"


def test_missing_weights_say_how_to_get_them(tmp_path):
    pytest.importorskip("transformers")
    with pytest.raises(DepthModelError, match="huggingface-cli download depth-anything/Depth-Anything-V2-Small-hf"):
        load_depth_anything(tmp_path / "no-such-folder")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DepthModelError, match="huggingface-cli download"):
        load_depth_anything(tmp_path / "empty", local_files_only=True)


def test_missing_transformers_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "transformers", None)  # import fails as if not installed
    with pytest.raises(DepthModelError, match=r"pip install 'radar4dgs\[models\]'"):
        load_depth_anything("depth-anything/Depth-Anything-V2-Small-hf")
