import json
import math

import numpy as np
import pytest
import torch

# Imported here, at collection, so that its one-time cost (seconds: it loads torchvision's model
# zoo) is not charged to whichever test happens to call ssim or LpipsScorer first.
import torchmetrics.functional.image  # noqa: F401
from hypothesis import given, settings
from hypothesis import strategies as st

import radar4dgs.metrics.image as im
from radar4dgs.metrics.image import (
    LpipsScorer,
    lpips_or_none,
    psnr,
    ssim,
    ssim_loss_value,
    ssim_map,
    summarize_frames,
)


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Shared 2-core CI machine: OpenMP threads spinning against other processes make small
    convolutions many times slower; one thread for these tests, restored afterwards."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _images(seed, shape=(12, 15, 3), dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=g, dtype=dtype), torch.rand(shape, generator=g, dtype=dtype)


# --- PSNR --------------------------------------------------------------------------------------


def test_psnr_of_a_constant_offset_is_the_closed_form():
    gt, _ = _images(0)
    gt = gt * 0.9
    assert psnr(gt + 0.1, gt) == pytest.approx(20.0, abs=1e-9)  # MSE 0.01
    assert psnr(gt + 0.01, gt) == pytest.approx(40.0, abs=1e-9)


def test_psnr_of_identical_images_is_capped_at_100_db():
    gt, _ = _images(1)
    assert psnr(gt, gt) == pytest.approx(100.0)
    json.dumps(psnr(gt, gt), allow_nan=False)


def test_masked_psnr_against_a_hand_computed_value():
    gt = torch.zeros(4, 5, 3, dtype=torch.float64)
    pred = torch.full((4, 5, 3), 0.5, dtype=torch.float64)  # unmasked pixels: far off
    pred[1, 2] = torch.tensor([0.1, 0.1, 0.1], dtype=torch.float64)
    pred[3, 0] = torch.tensor([0.3, 0.0, 0.0], dtype=torch.float64)
    mask = torch.zeros(4, 5, dtype=torch.bool)
    mask[1, 2] = mask[3, 0] = True
    # MSE over the 2 pixels x 3 channels: (3 * 0.01 + 0.09) / 6 = 0.02
    assert psnr(pred, gt, mask) == pytest.approx(-10 * math.log10(0.02), abs=1e-9)
    assert psnr(pred, gt) == pytest.approx(-10 * math.log10(((4 * 5 - 2) * 3 * 0.25 + 0.12) / 60), abs=1e-9)


def test_psnr_with_an_empty_mask_is_none_and_bad_masks_are_refused():
    pred, gt = _images(2)
    assert psnr(pred, gt, torch.zeros(12, 15, dtype=torch.bool)) is None
    with pytest.raises(TypeError, match="bool"):
        psnr(pred, gt, torch.ones(12, 15))
    with pytest.raises(ValueError, match="mask"):
        psnr(pred, gt, torch.ones(12, 14, dtype=torch.bool))
    with pytest.raises(ValueError, match="shape"):
        psnr(pred, gt[:-1])
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        psnr(pred[..., :2], gt[..., :2])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 9), w=st.integers(1, 9),
       dtype=st.sampled_from([torch.float32, torch.float64]))  # fmt: skip
def test_psnr_is_symmetric_and_an_all_true_mask_changes_nothing(seed, h, w, dtype):
    pred, gt = _images(seed, (h, w, 3), dtype)
    value = psnr(pred, gt)
    assert psnr(gt, pred) == pytest.approx(value, rel=1e-6)
    assert psnr(pred, gt, torch.ones(h, w, dtype=torch.bool)) == pytest.approx(value, rel=1e-6)
    mse = float(((pred - gt).double() ** 2).mean())
    assert value == pytest.approx(-10 * math.log10(mse), rel=1e-5)


# --- SSIM --------------------------------------------------------------------------------------


def _naive_ssim_map(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Wang et al.'s SSIM at every pixel of (H, W, C) images, window by window: an 11x11 Gaussian
    window of sigma 1.5, the image reflected at the borders (edge pixel not repeated)."""
    r = 5
    t = np.arange(-r, r + 1, dtype=np.float64)
    w1 = np.exp(-(t**2) / (2 * 1.5**2))
    w = np.outer(w1, w1)
    w /= w.sum()
    c1, c2 = 0.01**2, 0.03**2
    xp = np.pad(x, ((r, r), (r, r), (0, 0)), mode="reflect")
    yp = np.pad(y, ((r, r), (r, r), (0, 0)), mode="reflect")
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            px = xp[i : i + 2 * r + 1, j : j + 2 * r + 1]  # (11, 11, C)
            py = yp[i : i + 2 * r + 1, j : j + 2 * r + 1]
            mx = np.einsum("ab,abc->c", w, px)
            my = np.einsum("ab,abc->c", w, py)
            vx = np.einsum("ab,abc->c", w, (px - mx) ** 2)
            vy = np.einsum("ab,abc->c", w, (py - my) ** 2)
            cxy = np.einsum("ab,abc->c", w, (px - mx) * (py - my))
            out[i, j] = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))
    return out


def test_ssim_matches_a_naive_window_by_window_reference():
    pred, gt = _images(3, (12, 15, 3))
    pred = 0.6 * gt + 0.4 * pred  # correlated, so that all terms matter
    reference = _naive_ssim_map(pred.numpy(), gt.numpy())
    np.testing.assert_allclose(ssim_map(pred, gt).numpy(), reference, atol=1e-12)
    assert ssim(pred, gt) == pytest.approx(reference.mean(), abs=1e-12)
    assert float(ssim_loss_value(pred, gt)) == pytest.approx(reference.mean(), abs=1e-12)


def test_ssim_of_identical_and_of_constant_images():
    pred, _ = _images(4)
    assert ssim(pred, pred) == pytest.approx(1.0, abs=1e-12)
    assert float(ssim_loss_value(pred, pred)) == pytest.approx(1.0, abs=1e-12)
    a, b = 0.3, 0.5
    flat_a = torch.full((9, 10, 3), a, dtype=torch.float64)
    flat_b = torch.full((9, 10, 3), b, dtype=torch.float64)
    # No variance: only the luminance term (2ab + C1) / (a^2 + b^2 + C1) is left.
    expected = (2 * a * b + 1e-4) / (a * a + b * b + 1e-4)
    assert ssim(flat_a, flat_b) == pytest.approx(expected, abs=1e-12)
    assert float(ssim_loss_value(flat_a, flat_b)) == pytest.approx(expected, abs=1e-12)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(6, 20), w=st.integers(6, 20))
def test_ssim_is_symmetric_at_most_one_and_the_loss_agrees_with_torchmetrics(seed, h, w):
    pred, gt = _images(seed, (h, w, 3), torch.float32)
    value = ssim(pred, gt)
    assert ssim(gt, pred) == pytest.approx(value, abs=1e-6)
    assert value <= 1.0 + 1e-6
    assert float(ssim_loss_value(pred, gt)) == pytest.approx(value, abs=1e-5)


def test_ssim_loss_gradient_is_right():
    pred, gt = _images(5, (9, 13, 3))
    pred.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: ssim_loss_value(p, gt), (pred,))
    # Against autograd through the map, with flat regions (clamped variances) and batches.
    x, y = _images(6, (2, 16, 20, 3))
    x[0, :8, :10] = 0.25
    y[0, :8, :10] = 0.75
    p_fused, p_auto = x.clone().requires_grad_(True), x.clone().requires_grad_(True)
    ssim_loss_value(p_fused, y).backward()
    ssim_map(p_auto, y).mean().backward()
    fused_grad = p_fused.grad
    np.testing.assert_allclose(fused_grad.numpy(), p_auto.grad.numpy(), atol=1e-15)
    # Both images trainable: the autograd path.
    p, q = x.clone().requires_grad_(True), y.clone().requires_grad_(True)
    ssim_loss_value(p, q).backward()
    assert q.grad is not None and torch.isfinite(q.grad).all()
    np.testing.assert_allclose(p.grad.numpy(), fused_grad.numpy(), atol=1e-15)


def test_ssim_loss_follows_the_input_dtype_and_refuses_tiny_images():
    pred, gt = _images(7, (10, 11, 3), torch.float32)
    pred.requires_grad_(True)
    value = ssim_loss_value(pred, gt)
    value.backward()
    assert value.dtype == torch.float32 and pred.grad.dtype == torch.float32
    with pytest.raises(ValueError, match="too small"):
        ssim(*_images(8, (5, 20, 3)))
    with pytest.raises(ValueError, match="too small"):
        ssim_loss_value(*_images(8, (20, 5, 3)))


# --- LPIPS -------------------------------------------------------------------------------------


@pytest.fixture
def no_downloads(monkeypatch, tmp_path):
    """An empty torch hub cache and every download entry point made to fail loudly."""
    import torchvision.models._api as tv_api

    def refuse(*args, **kwargs):
        raise AssertionError("a download was attempted")

    monkeypatch.setattr(torch.hub, "_hub_dir", str(tmp_path / "hub"))
    monkeypatch.setattr(torch.hub, "load_state_dict_from_url", refuse)
    monkeypatch.setattr(torch.hub, "download_url_to_file", refuse)
    monkeypatch.setattr(tv_api, "load_state_dict_from_url", refuse)
    return tmp_path / "hub" / "checkpoints"


def test_lpips_weight_files_are_torchvisions(no_downloads):
    assert LpipsScorer.weights_path("vgg") == no_downloads / "vgg16-397923af.pth"
    assert LpipsScorer.weights_path("alex") == no_downloads / "alexnet-owt-7be5be79.pth"
    with pytest.raises(ValueError, match="squeeze"):
        LpipsScorer.weights_path("squeeze")


def test_lpips_without_cached_weights_is_unavailable_and_never_downloads(no_downloads):
    for net in ("vgg", "alex"):
        assert not LpipsScorer.available(net)
        assert lpips_or_none(net) is None
        with pytest.raises(FileNotFoundError, match="nothing is downloaded"):
            LpipsScorer(net)


# Output channels of the five slices torchmetrics cuts torchvision's ``features`` into, and the
# index where each slice starts (torchmetrics.functional.image.lpips.Vgg16 / Alexnet).
_SLICES = {"vgg16": ([64, 128, 256, 512, 512], [0, 4, 9, 16, 23, 30]),
           "alexnet": ([64, 192, 384, 256, 256], [0, 2, 5, 8, 10, 12])}


def tiny_backbone(name):
    """A torchvision builder stand-in: ``features`` with torchvision's layer indices and the
    slices' channel counts, one random 1x1 convolution + ReLU per slice (a few hundred thousand
    parameters instead of 15 M); the ``weights`` asked for are ignored (nothing is loaded)."""
    channels, starts = _SLICES[name]

    def build(weights=None, **kwargs):
        layers, previous = [], 3
        for out, (lo, hi) in zip(channels, zip(starts[:-1], starts[1:], strict=True), strict=True):
            layers += [torch.nn.Conv2d(previous, out, 1), torch.nn.ReLU()] + [torch.nn.Identity()] * (hi - lo - 2)
            previous = out
        model = torch.nn.Module()
        model.features = torch.nn.Sequential(*layers)
        return model

    return build


@pytest.fixture
def tiny_backbones(no_downloads, monkeypatch):
    """torchvision's vgg16 / alexnet builders replaced by ``tiny_backbone`` (seeded)."""
    import torchvision

    torch.manual_seed(0)
    for name in _SLICES:
        monkeypatch.setattr(torchvision.models, name, tiny_backbone(name))


def _recording(scorer):
    """What reaches the LPIPS network (its first layer, the ImageNet scaling layer) and its
    backbone, recorded at every call."""
    seen = {"lpips": [], "backbone": []}
    net = scorer.metric.net
    net.scaling_layer.register_forward_pre_hook(lambda module, args: seen["lpips"].append(args[0].clone()))
    # _LPIPS calls its backbone's forward() directly (no hooks): the first slice is hooked instead.
    net.net.slice1.register_forward_pre_hook(lambda module, args: seen["backbone"].append(args[0].clone()))
    return seen


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_lpips_is_torchmetrics_public_metric_in_the_field_convention(tiny_backbones, net):
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

    scorer = LpipsScorer(net, metric=im.lpips_metric(net))
    assert isinstance(scorer.metric, LearnedPerceptualImagePatchSimilarity)
    assert scorer.name == f"lpips_{net}"
    assert scorer.metric.normalize is (net == "alex")
    pred, gt = _images(9, (48, 64, 3), torch.float32)
    seen = _recording(scorer)
    value = scorer(pred, gt)
    assert value > 1e-6
    # The input scaling: VGG gets the [0, 1] images as they are (3DGS / gsplat), AlexNet 2x - 1.
    as_nchw = [pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None]]
    expected = as_nchw if net == "vgg" else [2 * image - 1 for image in as_nchw]
    assert len(seen["lpips"]) == 2
    for got, want in zip(seen["lpips"], expected, strict=True):
        torch.testing.assert_close(got, want)
    scaling = scorer.metric.net.scaling_layer
    for got, want in zip(seen["backbone"], expected, strict=True):
        torch.testing.assert_close(got, scaling(want))
    assert scorer(gt, gt) == pytest.approx(0.0, abs=1e-7)
    # The metric keeps no state between frames, and the input dtype does not matter.
    assert scorer(pred.double(), gt.double()) == pytest.approx(value, rel=1e-5)
    assert scorer(pred, gt) == pytest.approx(value, rel=1e-6)


def test_lpips_refuses_a_metric_of_another_convention(tiny_backbones):
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

    with pytest.raises(ValueError, match="normalize=False"):
        LpipsScorer("vgg", metric=LearnedPerceptualImagePatchSimilarity(net_type="vgg", normalize=True))


def test_lpips_with_cached_weights_builds_the_public_metric(tiny_backbones, monkeypatch):
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

    monkeypatch.setattr(LpipsScorer, "available", classmethod(lambda cls, net: net == "alex"))
    assert lpips_or_none("vgg") is None
    scorer = lpips_or_none("alex")
    assert isinstance(scorer.metric, LearnedPerceptualImagePatchSimilarity)
    assert scorer.metric.normalize is True


def test_lpips_convention_is_stated():
    convention = im.lpips_convention()
    assert convention["lpips_vgg"]["net_type"] == "vgg" and convention["lpips_vgg"]["normalize"] is False
    assert convention["lpips_alex"]["net_type"] == "alex" and convention["lpips_alex"]["normalize"] is True
    assert "LearnedPerceptualImagePatchSimilarity" in convention["implementation"]
    assert convention["torchmetrics_version"]
    json.dumps(convention, allow_nan=False)


# --- summary -----------------------------------------------------------------------------------


def test_summarize_frames():
    frames = [
        {"psnr": 20.0, "ssim": 0.8, "lpips_vgg": None, "lpips_alex": 0.1, "psnr_dyn": 15.0},
        {"psnr": 30.0, "ssim": 0.9, "lpips_vgg": None, "lpips_alex": 0.3, "psnr_dyn": None},
        {"psnr": 25.0, "ssim": 1.0, "lpips_alex": 0.2, "psnr_dyn": 25.0},
    ]
    summary = summarize_frames(frames)
    assert summary == pytest.approx({
        "psnr": 25.0, "ssim": 0.9, "lpips_vgg": None, "lpips_alex": 0.2,
        "psnr_dyn": 20.0, "n_frames": 3, "n_frames_dyn": 2,
    })  # fmt: skip
    json.dumps(summary, allow_nan=False)

    frames[1]["lpips_alex"] = None
    frames[0]["psnr_dyn"] = frames[2]["psnr_dyn"] = None
    summary = summarize_frames(frames)
    assert summary["lpips_alex"] is None and summary["psnr_dyn"] is None and summary["n_frames_dyn"] == 0
    assert summarize_frames([]) == {
        "psnr": None, "ssim": None, "lpips_vgg": None, "lpips_alex": None,
        "psnr_dyn": None, "n_frames": 0, "n_frames_dyn": 0,
    }  # fmt: skip


def test_the_metrics_stay_on_the_inputs_device_and_dtype():
    pred, gt = _images(11, (16, 16, 3), torch.float32)
    mask = torch.ones(16, 16, dtype=torch.bool)
    assert isinstance(psnr(pred, gt, mask), float) and isinstance(ssim(pred, gt), float)
    assert ssim_map(pred, gt).dtype == torch.float32 and ssim_map(pred, gt).shape == (16, 16, 3)
    assert im.gaussian_window_1d(torch.float64, "cpu").sum().item() == pytest.approx(1.0)
