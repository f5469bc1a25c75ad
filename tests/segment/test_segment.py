"""The segmentation stage on hand-made data: shapes, paste-back, linear attention, empty radar,
checkpoints, overfitting, the baseline, prepare_masks, training with resume."""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from radar4dgs.io.scene import Camera, Frame, RadarSpec, SceneWarning, SceneWriter, read_scene
from radar4dgs.segment.baseline import BaselineConfig, baseline_frame
from radar4dgs.segment.dataset import TrainFrame, load_radar_frame, load_train_frames
from radar4dgs.segment.infer import SegInferConfig, frame_rng, prepare_masks, segment_frame
from radar4dgs.segment.model import (
    NUM_RADAR_FEATURES,
    RadarCameraSegNet,
    SegModelConfig,
    checkpoint_payload,
    linear_attention,
    load_pretrained_backbone,
    model_from_checkpoint,
)
from radar4dgs.segment.patches import (
    RadarFrame,
    extract_patches,
    make_radar_frame,
    paste_max,
    patch_boxes,
    patch_side,
    radar_features,
    sample_anchors,
)
from radar4dgs.segment.train import SegTrainConfig, segmentation_loss, train_segmentation, training_patches

TINY = SegModelConfig(**SegModelConfig.PRESETS["tiny"])
K = np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
CAM_TO_EGO = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1.0], [0, 0, 0, 1.0]])


def radar_at_pixels(uv: np.ndarray, depth: float, dynamic: np.ndarray, v: float = 5.0) -> RadarFrame:
    """Points at (N, 2) pixels and one depth, in camera axes."""
    cam = np.concatenate([(uv - K[:2, 2]) / K[0, 0] * depth, np.full((len(uv), 1), depth)], axis=1)
    return make_radar_frame(cam, K, np.where(dynamic, v, 0.0), dynamic)


def rectangle_image(h=48, w=64, box=(20, 14, 44, 34), seed=0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    image = np.clip(rng.normal(110, 4, (h, w, 3)), 0, 255).astype(np.uint8)
    mask = np.zeros((h, w), bool)
    x0, y0, x1, y1 = box
    image[y0:y1, x0:x1] = (200, 40, 40)
    mask[y0:y1, x0:x1] = True
    return image, mask


# ---------------------------------------------------------------- model


def test_model_output_shapes():
    torch.manual_seed(0)
    model = RadarCameraSegNet(TINY)
    s = TINY.input_size
    out = model(torch.rand(5, 3, s, s), torch.randn(5, 7, NUM_RADAR_FEATURES), torch.rand(5, 7) > 0.3)
    assert out.shape == (5, 1, s, s)
    assert torch.isfinite(out).all()


def test_linear_attention_matches_naive_formula():
    torch.manual_seed(0)
    q, k, v = torch.randn(2, 5, 3, 4, dtype=torch.float64), torch.randn(2, 7, 3, 4, dtype=torch.float64), \
        torch.randn(2, 7, 3, 6, dtype=torch.float64)
    phi = lambda x: torch.nn.functional.elu(x) + 1  # noqa: E731
    expected = torch.zeros(2, 5, 3, 6, dtype=torch.float64)
    for b in range(2):
        for h in range(3):
            for i in range(5):
                weights = torch.stack([phi(q[b, i, h]) @ phi(k[b, j, h]) for j in range(7)])  # O(N^2)
                expected[b, i, h] = (weights[:, None] * v[b, :, h]).sum(0) / weights.sum()
    torch.testing.assert_close(linear_attention(q, k, v, eps=0.0), expected)


def test_checkpoint_reproduces_outputs():
    torch.manual_seed(1)
    model = RadarCameraSegNet(TINY).eval()
    s = TINY.input_size
    x, p, m = torch.rand(3, 3, s, s), torch.randn(3, 4, NUM_RADAR_FEATURES), torch.ones(3, 4, dtype=torch.bool)
    with torch.no_grad():
        reference = model(x, p, m)
    for half, tol in ((False, 0.0), (True, 5e-2)):
        buffer = io.BytesIO()
        torch.save(checkpoint_payload(model, half=half), buffer)
        buffer.seek(0)
        loaded = model_from_checkpoint(torch.load(buffer, weights_only=True))
        with torch.no_grad():
            torch.testing.assert_close(loaded(x, p, m), reference, atol=tol, rtol=tol)


def test_pretrained_backbone_loads_torchvision_state_dict(tmp_path):
    from torchvision.models import resnet18

    path = tmp_path / "resnet18.pth"
    torch.save(resnet18(weights=None).state_dict(), path)
    model = RadarCameraSegNet(SegModelConfig(backbone_width=64, input_size=32))
    keys = load_pretrained_backbone(model, path)
    assert "layer3.1.conv2.weight" in keys and not any(k.startswith(("layer4", "fc")) for k in keys)
    with pytest.raises(ValueError, match="backbone_width=64"):
        load_pretrained_backbone(RadarCameraSegNet(TINY), path)


# ---------------------------------------------------------------- patches


def test_paste_max_matches_naive_loop():
    rng = np.random.default_rng(0)
    h, w, side = 20, 30, 9
    centres = rng.uniform(-5, 35, size=(12, 2))
    boxes = patch_boxes(centres, side)
    patches = torch.rand(12, side, side)
    expected = np.zeros((h, w))
    for patch, (x0, y0, _, _) in zip(patches.numpy(), boxes, strict=True):
        for dy in range(side):
            for dx in range(side):
                y, x = y0 + dy, x0 + dx
                if 0 <= y < h and 0 <= x < w:
                    expected[y, x] = max(expected[y, x], patch[dy, dx])
    np.testing.assert_allclose(paste_max(patches, boxes, h, w).numpy(), expected, rtol=0, atol=0)


def test_extract_patches_is_a_crop_at_native_size_with_zero_padding():
    image = torch.arange(3 * 10 * 12, dtype=torch.float32).reshape(3, 10, 12)
    boxes = np.array([[2, 3, 7, 8], [-2, -1, 3, 4]])
    patches = extract_patches(image, boxes, 5)
    torch.testing.assert_close(patches[0], image[:, 3:8, 2:7])
    torch.testing.assert_close(patches[1, :, 1:, 2:], image[:, 0:4, 0:3])
    assert patches[1, :, 0].abs().max() == 0 and patches[1, :, :, :2].abs().max() == 0


def test_patch_side_scales_with_width():
    assert patch_side(1920) == 256 and patch_side(320) == 43 and patch_side(160) == 21


def test_sample_anchors_fixed_count_or_fewer():
    rng = np.random.default_rng(0)
    uv = rng.uniform(0, 100, (30, 2))
    for method in ("random", "farthest"):
        chosen = sample_anchors(uv, np.arange(5, 25), 8, rng, method)
        assert len(chosen) == 8 and len(set(chosen)) == 8 and set(chosen) <= set(range(5, 25))
        assert list(sample_anchors(uv, np.array([3, 9]), 8, rng, method)) == [3, 9]
    covered = sample_anchors(uv, np.arange(30), 30, rng, "cover", cover_radius=20.0)
    gaps = np.abs(uv[covered][:, None] - uv[covered][None]).max(axis=2) + np.eye(len(covered)) * 1e9
    assert gaps.min() > 20.0  # no two anchors within the radius
    assert (np.abs(uv[:, None] - uv[covered][None]).max(axis=2).min(axis=1) <= 20.0).all()  # every point covered


def test_radar_features_relative_to_anchor():
    radar = radar_at_pixels(np.array([[30.2, 20.2], [35.2, 20.2], [60.2, 40.2]]), 10.0, np.array([True, False, True]))
    boxes = patch_boxes(radar.uv[[0]], 21)
    feats, valid = radar_features(radar, boxes, np.array([0]), 4)
    assert valid[0].tolist() == [True, True, False, False]
    np.testing.assert_allclose(feats[0, 1, :2], [5 / 21, 0], atol=1e-6)
    assert feats[0, 0, 5] == 1 and feats[0, 1, 5] == 0


# ---------------------------------------------------------------- inference


def test_no_dynamic_point_gives_empty_mask():
    model = RadarCameraSegNet(TINY).eval()
    image, _ = rectangle_image()
    config = SegInferConfig()
    for radar in (RadarFrame.empty(), radar_at_pixels(np.array([[30.0, 20.0]]), 10.0, np.array([False])),
                  radar_at_pixels(np.array([[-30.0, 20.0]]), 10.0, np.array([True]))):  # dynamic but out of view
        result = segment_frame(model, image, radar, config, frame_rng(0, 0))
        assert result.prob.shape == (48, 64) and not result.mask(0.5).any() and len(result.anchors) == 0
    assert not baseline_frame(image, None, RadarFrame.empty(), K).any()


def test_segment_frame_shapes_and_anchor_count():
    model = RadarCameraSegNet(TINY).eval()
    image, _ = rectangle_image()
    uv = np.random.default_rng(0).uniform([20, 14], [44, 34], size=(12, 2))
    result = segment_frame(model, image, radar_at_pixels(uv, 10.0, np.ones(12, bool)),
                           SegInferConfig(num_anchors=8, anchor_sampling="random"), frame_rng(0, 0))
    assert result.prob.shape == (48, 64) and result.anchors.shape == (8, 2) and result.boxes.shape == (8, 4)
    assert 0 <= result.prob.min() and result.prob.max() <= 1


def test_baseline_fills_a_rectangle_from_one_radar_point():
    image, mask = rectangle_image()
    depth = np.full(mask.shape, 30.0, np.float32)
    depth[mask] = 10.0
    radar = radar_at_pixels(np.array([[31.2, 22.2], [5.2, 5.2]]), 10.0, np.array([True, False]))
    for d in (depth, None):
        config = BaselineConfig(max_object_m=8.0, max_area_m2=100.0, min_support=0)
        pred = baseline_frame(image, d, radar, K, config)
        iou = (pred & mask).sum() / (pred | mask).sum()
        assert iou > 0.95, iou


# ---------------------------------------------------------------- training


def _rectangle_frames(count: int, seed: int = 0) -> list[TrainFrame]:
    rng = np.random.default_rng(seed)
    frames = []
    for i in range(count):
        x0, y0 = int(rng.integers(4, 30)), int(rng.integers(4, 20))
        box = (x0, y0, x0 + int(rng.integers(12, 24)), y0 + int(rng.integers(10, 20)))
        image, mask = rectangle_image(box=box, seed=i)
        inside = rng.uniform([box[0], box[1]], [box[2], box[3]], size=(5, 2))
        outside = rng.uniform([0, 0], [64, 48], size=(10, 2))
        radar = radar_at_pixels(np.concatenate([inside, outside]), 10.0, np.arange(15) < 5)
        frames.append(TrainFrame(image, mask, radar, "rect", f"{i:06d}"))
    return frames


def test_overfitting_a_tiny_batch_decreases_the_loss():
    torch.manual_seed(0)
    config = SegTrainConfig(model=TINY, num_anchors=4, max_points=8, lr=3e-3)
    model = RadarCameraSegNet(TINY)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    rng = np.random.default_rng(0)
    batch = [training_patches(f, config, rng, "cpu", torch.float32) for f in _rectangle_frames(2)]
    patches, points, valid, target = (torch.cat(parts) for parts in zip(*batch, strict=True))
    losses = []
    for _ in range(40):
        loss = segmentation_loss(model(patches, points, valid), target, 1.0)["total"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0], losses[::8]


def test_train_checkpoints_and_resume(tmp_path):
    config = SegTrainConfig(model=TINY, epochs=1, batch_size=2, num_anchors=4, max_points=8)
    frames = _rectangle_frames(6)
    state = train_segmentation(frames[:4], frames[4:], config, tmp_path, log=lambda s: None)
    assert state.epoch == 1 and (tmp_path / "last.pt").is_file() and (tmp_path / "best.pt").is_file()
    config.epochs = 2
    state = train_segmentation(frames[:4], frames[4:], config, tmp_path, resume=True, log=lambda s: None)
    assert state.epoch == 2 and len(state.history) == 2 and state.step == 4
    model = model_from_checkpoint(torch.load(tmp_path / "best.pt", weights_only=True))
    assert model.config == TINY


# ---------------------------------------------------------------- scene level


def write_rect_scene(out: Path, frames: int = 3) -> Path:
    """A 64x48 scene: a red rectangle 10 m ahead with dynamic radar points on it, and one frame
    with an empty radar scan."""
    camera = Camera(64, 48, K, CAM_TO_EGO)
    radar_spec = RadarSpec(np.eye(4), ("x", "y", "z", "v_r", "rcs"))
    with SceneWriter(out) as writer:
        for i in range(frames):
            pose = np.eye(4)
            pose[0, 3] = float(i)
            image, mask = rectangle_image(seed=i)
            # Radar (= ego) frame points on the rectangle: ego x forward = camera z.
            uv = np.array([[31.2, 22.2], [25.2, 18.2], [40.2, 30.2]])
            cam = np.concatenate([(uv - K[:2, 2]) / K[0, 0] * 10.0, np.full((3, 1), 10.0)], axis=1)
            ego = cam @ CAM_TO_EGO[:3, :3].T + CAM_TO_EGO[:3, 3]
            radar = np.concatenate([ego, np.full((3, 1), 4.0), np.zeros((3, 1))], axis=1).astype(np.float32)
            labels = np.ones(3, np.int8)
            if i == frames - 1:
                radar, labels = radar[:0], labels[:0]
            writer.add_frame(Frame(f"{i:06d}", 0.1 * i, pose, 0.1 * i, pose), image, radar,
                             gt_dynamic_mask=mask, gt_radar_labels=labels, gt_depth=np.where(mask, 10.0, 30.0))
        writer.finish("rect", camera, radar_spec)
    return out


def test_prepare_masks_writes_masks_and_empty_frames(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = read_scene(write_rect_scene(tmp_path / "scene"))
        radar = load_radar_frame(scene, 0, "oracle")
        np.testing.assert_allclose(radar.uv[0], [31.2, 22.2], atol=1e-4)
        assert radar.dynamic.all()
        model = RadarCameraSegNet(TINY).eval()
        summary = prepare_masks(scene, tmp_path / "prepared", SegInferConfig(dynamic_source="oracle"), model=model)
    masks = tmp_path / "prepared" / "masks"
    from PIL import Image

    for i in range(3):
        png = np.asarray(Image.open(masks / f"{i:06d}.png"))
        assert png.dtype == np.uint8 and png.shape == (48, 64) and set(np.unique(png)) <= {0, 255}
        assert np.load(masks / f"{i:06d}_prob.npy").shape == (48, 64)
    assert summary["frames"][2]["anchors"] == 0 and summary["frames"][2]["dynamic_pixels"] == 0
    assert summary["frames"][0]["anchors"] == 3


def test_prepared_radar_npz_is_used(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = read_scene(write_rect_scene(tmp_path / "scene"))
        (tmp_path / "prep" / "radar").mkdir(parents=True)
        np.savez(tmp_path / "prep" / "radar" / "000000.npz", dynamic=np.array([False, True, False]),
                 v_r_comp=np.array([0.0, 3.0, 0.0], np.float32))
        radar = load_radar_frame(scene, 0, "auto", tmp_path / "prep")
        assert radar.dynamic.tolist() == [False, True, False] and radar.v_comp[1] == 3.0
        frames = load_train_frames(scene, "oracle")
        assert len(frames) == 3 and frames[0].mask.sum() == 24 * 20


# ---------------------------------------------------------------- command, metrics, export


def test_parse_seeds():
    from radar4dgs.apps.seg_train import parse_seeds

    assert parse_seeds("100-103,7, 9") == [100, 101, 102, 103, 7, 9]


def test_hflip_keeps_points_on_their_pixels():
    from radar4dgs.segment.patches import pixel_index
    from radar4dgs.segment.train import hflip_frame

    frame = _rectangle_frames(1)[0]
    image, mask, radar = hflip_frame(frame.image, frame.mask, frame.radar)
    before, after = pixel_index(frame.radar.uv), pixel_index(radar.uv)
    ok = (before[:, 0] >= 0) & (before[:, 0] < 64) & (before[:, 1] >= 0) & (before[:, 1] < 48)
    assert (frame.mask[before[ok, 1], before[ok, 0]] == mask[after[ok, 1], after[ok, 0]]).all()
    assert (frame.image[before[ok, 1], before[ok, 0]] == image[after[ok, 1], after[ok, 0]]).all()


def test_ray_box_depth_hits_front_face():
    from radar4dgs.segment.metrics import ray_box_depth

    pose = np.eye(4)
    pose[:3, 3] = [0, 0, 10]
    dirs = np.array([[0, 0, 1.0], [0.05, 0, 1.0], [1.0, 0, 1.0]])
    t = ray_box_depth(np.zeros(3), dirs, pose, np.array([1.0, 1.0, 2.0]))
    np.testing.assert_allclose(t[:2], [8.0, 8.0])
    assert np.isinf(t[2])


def test_seg_train_command_end_to_end(tmp_path):
    from radar4dgs import cli

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        a, b = write_rect_scene(tmp_path / "a"), write_rect_scene(tmp_path / "b")
        command = cli.build_command("seg-train", ["--out", str(tmp_path / "run"), "--scenes", str(a), str(b),
                                                  "--preset", "tiny", "--train.epochs", "1",
                                                  "--train.dynamic-source", "oracle"])
        assert command.train.model.backbone_width == 8 and command.train.epochs == 1
        assert command.run() == 0
    assert {"config.json", "last.pt", "best.pt", "history.json"} <= {p.name for p in (tmp_path / "run").iterdir()}


def test_export_and_frontend_metrics(tmp_path):
    from radar4dgs.segment.metrics import segmentation_frontend_metrics
    from radar4dgs.segment.train import export_weights

    torch.manual_seed(0)
    model = RadarCameraSegNet(TINY)
    torch.save(checkpoint_payload(model, synth_seeds=[100, 101]), tmp_path / "best.pt")
    card = export_weights(tmp_path / "best.pt", tmp_path / "w.pt", tmp_path / "w.json")
    assert card["training"]["synth_seeds"] == [100, 101] and card["bytes"] < 2e6
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        scene = read_scene(write_rect_scene(tmp_path / "scene"))
        config = SegInferConfig(checkpoint=tmp_path / "w.pt", dynamic_source="oracle")
        metrics = segmentation_frontend_metrics(scene, tmp_path / "prepared", config)
    assert set(metrics) >= {"model", "baseline", "mask_iou", "static_vehicle_fp"}
    assert metrics["static_vehicle_fp"] is None  # no synthetic metadata in this scene
    assert 0 <= metrics["baseline"]["mask_iou"] <= 1 and 0 <= metrics["mask_iou"] <= 1
    gt_pixels = sum(int(scene.load_optional("gt/dynamic_mask", i).sum()) for i in range(len(scene)))
    assert metrics["model"]["gt_pixels"] == metrics["baseline"]["gt_pixels"] == gt_pixels == len(scene) * 24 * 20
    assert metrics["model"]["intersection"] <= gt_pixels <= metrics["model"]["union"]


def test_anchor_regions_keeps_only_the_anchor_object():
    from radar4dgs.segment.infer import anchor_regions

    masks = np.zeros((1, 21, 21), bool)
    masks[0, 8:13, 8:14] = True  # on the anchor (centre 10, 10)
    masks[0, 0:4, 0:4] = True  # elsewhere in the patch
    kept = anchor_regions(masks, 1)
    assert kept[0, 10, 10] and not kept[0, 1, 1] and kept.sum() == 30
    assert not anchor_regions(np.zeros((2, 5, 5), bool), 1).any()


def test_baseline_drops_isolated_seeds_and_leaks():
    image, mask = rectangle_image()
    lone = radar_at_pixels(np.array([[31.2, 22.2]]), 10.0, np.array([True]))
    assert not baseline_frame(image, None, lone, K, BaselineConfig(max_area_m2=100.0)).any()  # no support
    assert not baseline_frame(image, None, lone, K, BaselineConfig(min_support=0, max_area_m2=1.0)).any()  # too big


def test_shipped_weights_load_by_name_and_an_unknown_name_is_refused(tmp_path, monkeypatch):
    from radar4dgs.segment.infer import load_model, shipped_weight_names

    assert {"segnet-small", "segnet-small-traffic"} <= set(shipped_weight_names())
    monkeypatch.chdir(tmp_path)             # a name, not a file of the working folder
    default, traffic = load_model(), load_model("segnet-small-traffic")
    assert default.config == traffic.config
    # Different weights: the traffic network was trained anew, not copied.
    first = next(iter(default.state_dict()))
    assert not torch.equal(default.state_dict()[first], traffic.state_dict()[first])
    torch.testing.assert_close(load_model("segnet-small").state_dict()[first], default.state_dict()[first])
    with pytest.raises(FileNotFoundError, match="segnet-small-traffic"):
        load_model("segnet-huge")
