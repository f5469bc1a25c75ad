"""Image-quality metrics of rendered frames against the camera images (DESIGN.md section 8).

Every function takes channels-last images, ``(H, W, 3)`` floats in ``[0, 1]`` (the rendered image
clamped to ``[0, 1]`` by the caller: nothing here clamps, so that an out-of-range render is not
silently flattered), on any device and in any float dtype; the computation stays on the inputs'
device and in their dtype (LPIPS excepted: its networks are float32).

Definitions, so that a reported number can be reproduced:

``psnr``
    ``10 log10(1 / MSE)``, the MSE over all pixels and the 3 channels (data range 1). With a mask,
    over the masked pixels only (all 3 channels of each). The MSE is clamped to ``1e-10``, so
    identical images give 100 dB, not ``inf``: the JSON reports stay finite (they are written with
    ``allow_nan=False``).
``ssim``
    The Gaussian-window SSIM of Wang et al. 2004: an 11x11 window of sigma 1.5 (separable, the 1-D
    weights normalised to sum 1), ``K1 = 0.01``, ``K2 = 0.03``, data range 1, population (biased)
    local variances clamped at 0, the image padded by 5 pixels with reflection (``d c b | a b c d``,
    the edge pixel not repeated) and the SSIM map averaged over all ``H x W`` pixels and channels.
    This is torchmetrics' ``structural_similarity_index_measure`` (1.9) with ``data_range=1``;
    scikit-image's ``structural_similarity`` averages over the interior only (a 5-pixel border
    cropped), a slightly different number.
``ssim_loss_value``
    The same SSIM, differentiable, computed here (separable convolutions and a closed-form
    gradient: ~10 ms forward+backward at 320x180 on one CPU thread) without importing torchmetrics,
    whose import takes seconds. The trainer's D-SSIM term is ``1 - ssim_loss_value(pred, gt)``, so
    training and evaluation measure the same SSIM.
``lpips_vgg`` / ``lpips_alex``
    LPIPS v0.1 (Zhang et al. 2018) through torchmetrics' public
    ``LearnedPerceptualImagePatchSimilarity`` (the VGG-16 or AlexNet ImageNet backbone of
    torchvision and the linear calibration layers shipped with torchmetrics; features of the
    full-resolution image, spatially averaged), in the field's convention (``LPIPS_CONVENTION``,
    as gsplat's trainer): ``lpips_vgg`` is given the ``[0, 1]`` images as they are
    (``normalize=False``, the 3DGS convention), ``lpips_alex`` the images mapped to ``[-1, 1]``
    (``normalize=True``). Available only when the backbone file is already in the torch hub cache
    (``LpipsScorer.weights_path``): nothing here downloads, and the metric is ``None`` otherwise.
``psnr_dyn`` (PSNR*)
    ``psnr`` over the pixels of a frame's dynamic mask, averaged over the frames whose mask is not
    empty (``summarize_frames``); which mask (gt or predicted) is the caller's to state.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Literal, Optional, Sequence
from urllib.parse import urlparse

import torch
import torch.nn.functional as F
from torch import Tensor
from torch.autograd.function import once_differentiable

# 1e-10 = 100 dB: far above any real reconstruction, and a finite number for JSON.
MIN_MSE = 1e-10

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03

LpipsNet = Literal["vgg", "alex"]

# The per-frame keys that summarize_frames averages over every frame.
FRAME_METRICS = ("psnr", "ssim", "lpips_vgg", "lpips_alex")


def _check_pair(pred: Tensor, gt: Tensor, name: str) -> None:
    if not (isinstance(pred, Tensor) and isinstance(gt, Tensor)):
        raise TypeError(f"{name}: expected torch tensors, got {type(pred).__name__} and {type(gt).__name__}")
    if pred.shape != gt.shape:
        raise ValueError(f"{name}: pred {tuple(pred.shape)} and gt {tuple(gt.shape)} differ in shape")
    if pred.ndim != 3 or pred.shape[-1] != 3:
        raise ValueError(f"{name}: expected (H, W, 3) images, got {tuple(pred.shape)}")
    if not pred.is_floating_point() or not gt.is_floating_point():
        raise TypeError(f"{name}: expected float images in [0, 1], got {pred.dtype} and {gt.dtype}")


def mse_to_psnr(mse: float) -> float:
    """PSNR in dB of images in [0, 1] from their mean squared error, at most 100 dB (module doc)."""
    return float(-10.0 * math.log10(max(mse, MIN_MSE)))


def psnr(pred: Tensor, gt: Tensor, mask: Optional[Tensor] = None) -> Optional[float]:
    """PSNR in dB of ``pred`` against ``gt``, both ``(H, W, 3)`` in ``[0, 1]``.

    ``mask``: optional bool ``(H, W)``; the MSE is then taken over the masked pixels only (their
    3 channels). Returns ``None`` when the mask selects no pixel, at most 100 dB (module doc).
    """
    _check_pair(pred, gt, "psnr")
    diff = pred - gt
    if mask is not None:
        if not isinstance(mask, Tensor) or mask.dtype != torch.bool:
            raise TypeError(f"psnr: the mask must be a bool tensor, got {getattr(mask, 'dtype', type(mask))}")
        if mask.shape != pred.shape[:2]:
            raise ValueError(f"psnr: mask {tuple(mask.shape)} does not match the images "
                             f"{tuple(pred.shape[:2])}")
        diff = diff[mask.to(diff.device)]  # (n, 3)
        if diff.numel() == 0:
            return None
    return mse_to_psnr(float(diff.square().mean()))


def ssim(pred: Tensor, gt: Tensor) -> float:
    """SSIM (module doc) of ``pred`` against ``gt``, both ``(H, W, 3)`` in ``[0, 1]``, H, W >= 6.

    Computed by torchmetrics, the reference the trainer's ``ssim_loss_value`` is tested against.
    """
    from torchmetrics.functional.image import structural_similarity_index_measure

    _check_pair(pred, gt, "ssim")
    _check_ssim_size(pred.shape[0], pred.shape[1])
    value = structural_similarity_index_measure(
        pred.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None],
        gaussian_kernel=True, sigma=SSIM_SIGMA, kernel_size=SSIM_WINDOW, data_range=1.0,
        k1=SSIM_K1, k2=SSIM_K2,
    )  # fmt: skip
    return float(value)


def _check_ssim_size(height: int, width: int) -> None:
    # Reflection padding needs more pixels than the 5-pixel pad on each side.
    pad = SSIM_WINDOW // 2
    if height <= pad or width <= pad:
        raise ValueError(f"ssim: images of {height}x{width} are too small for the "
                         f"{SSIM_WINDOW}x{SSIM_WINDOW} window")


def gaussian_window_1d(dtype: torch.dtype, device: torch.device | str) -> Tensor:
    """The SSIM window's 1-D weights, ``(11,)``, summing to 1; the 2-D window is their outer product."""
    x = torch.arange(SSIM_WINDOW, dtype=dtype, device=device) - (SSIM_WINDOW - 1) / 2
    w = torch.exp(-0.5 * (x / SSIM_SIGMA) ** 2)
    return w / w.sum()


def _valid_blur(padded: Tensor, g: Tensor, zero_pad: int = 0) -> Tensor:
    """``(B, K, H + 10 - 2p, W + 10 - 2p)`` -> ``(B, K, H, W)``: each channel correlated with the
    2-D window ``g g^T`` where it fits (a 'valid' convolution) after padding ``p = zero_pad``
    zeros on every side; channels-last in and out."""
    k, size = padded.shape[1], SSIM_WINDOW
    padded = padded.contiguous(memory_format=torch.channels_last)
    out = F.conv2d(padded, g.view(1, 1, size, 1).expand(k, 1, size, 1), padding=(zero_pad, 0), groups=k)
    out = F.conv2d(out, g.view(1, 1, 1, size).expand(k, 1, 1, size), padding=(0, zero_pad), groups=k)
    return out.contiguous(memory_format=torch.channels_last)


def _blur(planes: Tensor, g: Tensor) -> Tensor:
    """``(B, K, H, W)`` -> ``(B, K, H, W)``: local Gaussian means, reflection at the borders."""
    pad = SSIM_WINDOW // 2
    return _valid_blur(F.pad(planes, (pad, pad, pad, pad), mode="reflect"), g)


def _blur_adjoint(grad: Tensor, g: Tensor) -> Tensor:
    """The transpose of ``_blur`` applied to ``grad`` ``(B, K, H, W)`` -> ``(B, K, H, W)``.

    The window is symmetric, so the transposed 'valid' correlation is the same correlation of the
    gradient padded with 10 zeros; the transposed reflection padding then folds the border back.
    """
    pad, full = SSIM_WINDOW // 2, SSIM_WINDOW - 1
    padded_grad = _valid_blur(grad, g, zero_pad=full)
    return torch.ops.aten.reflection_pad2d_backward(padded_grad, grad, [pad, pad, pad, pad])


def _to_planes(pred: Tensor, gt: Tensor, name: str) -> tuple[Tensor, Tensor, bool]:
    """``(H, W, C)`` or ``(B, H, W, C)`` pairs -> channels-last ``(B, C, H, W)`` pairs, batched flag."""
    if pred.shape != gt.shape:
        raise ValueError(f"{name}: pred {tuple(pred.shape)} and gt {tuple(gt.shape)} differ in shape")
    if pred.ndim not in (3, 4):
        raise ValueError(f"{name}: expected (H, W, C) or (B, H, W, C), got {tuple(pred.shape)}")
    batched = pred.ndim == 4
    # Channels-last (B, C, H, W) views of the (B, H, W, C) images, no copy: the layout that
    # torch's CPU depthwise convolution is fastest in (~4x), kept through the element-wise steps,
    # which are slow on mixed layouts.
    cl = torch.channels_last
    x = (pred if batched else pred[None]).permute(0, 3, 1, 2).contiguous(memory_format=cl)
    y = (gt if batched else gt[None]).permute(0, 3, 1, 2).to(x.dtype).contiguous(memory_format=cl)
    _check_ssim_size(x.shape[2], x.shape[3])
    return x, y, batched


def _ssim_terms(x: Tensor, y: Tensor, g: Tensor) -> dict[str, Tensor]:
    """The blurred moments and the factors of ``SSIM = A1 A2 / (B1 B2)``, each ``(B, C, H, W)``."""
    c = x.shape[1]
    mu_x, mu_y, xx, yy, xy = _blur(torch.cat((x, y, x * x, y * y, x * y), dim=1), g).split(c, dim=1)
    mu_xy = mu_x * mu_y
    # Rounding makes E[x^2] - E[x]^2 slightly negative in flat regions.
    raw_var_x = xx - mu_x * mu_x
    var_x = raw_var_x.clamp_min(0.0)
    var_y = (yy - mu_y * mu_y).clamp_min(0.0)
    return {
        "mu_x": mu_x, "mu_y": mu_y, "raw_var_x": raw_var_x,
        "a1": 2 * mu_xy + SSIM_K1**2,
        "a2": 2 * (xy - mu_xy) + SSIM_K2**2,
        "b1": mu_x * mu_x + mu_y * mu_y + SSIM_K1**2,
        "b2": var_x + var_y + SSIM_K2**2,
    }  # fmt: skip


def ssim_map(pred: Tensor, gt: Tensor) -> Tensor:
    """Per-pixel, per-channel SSIM (module doc), differentiable (autograd) in both inputs.

    ``pred``, ``gt``: ``(H, W, C)`` or ``(B, H, W, C)``, same shape, floats in ``[0, 1]``, H, W >= 6.
    Returns a tensor of the input's shape; its mean is ``ssim``.
    """
    x, y, batched = _to_planes(pred, gt, "ssim_map")
    t = _ssim_terms(x, y, gaussian_window_1d(x.dtype, x.device))
    value = (t["a1"] * t["a2"] / (t["b1"] * t["b2"])).permute(0, 2, 3, 1)
    return value if batched else value[0]


class _MeanSsim(torch.autograd.Function):
    """Mean SSIM with a hand-written gradient with respect to ``pred`` (``gt`` is a constant).

    With the blurred moments ``m1 = G x``, ``m2 = G x^2``, ``m3 = G xy`` (``G`` the padded blur),
    ``s = A1 A2 / (B1 B2)`` depends on ``x`` through them only, so
    ``ds/dx = G^T ds/dm1 + 2 x G^T ds/dm2 + y G^T ds/dm3``: one blur of three planes instead of
    autograd's trip back through every intermediate (~10 ms instead of ~17 ms forward+backward at
    320x180 on one CPU thread).
    """

    @staticmethod
    def forward(ctx, x: Tensor, y: Tensor) -> Tensor:  # type: ignore[override]
        g = gaussian_window_1d(x.dtype, x.device)
        t = _ssim_terms(x, y, g)
        inv_b = 1.0 / (t["b1"] * t["b2"])
        value = t["a1"] * t["a2"] * inv_b
        ctx.save_for_backward(x, y, g, value, inv_b, t["mu_x"], t["mu_y"], t["raw_var_x"],
                              t["a1"], t["a2"], t["b1"], t["b2"])  # fmt: skip
        return value.mean()

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out: Tensor):  # type: ignore[override]
        x, y, g, s, inv_b, mu_x, mu_y, raw_var_x, a1, a2, b1, b2 = ctx.saved_tensors
        scale = grad_out / s.numel()
        # clamp_min's gradient convention: the variance term passes gradient where >= 0.
        s_over_b2 = torch.where(raw_var_x >= 0, s / b2, 0.0)
        d_m1 = 2 * mu_y * (a2 - a1) * inv_b - 2 * mu_x * (s / b1 - s_over_b2)
        d_m2 = -s_over_b2
        d_m3 = 2 * a1 * inv_b
        g1, g2, g3 = _blur_adjoint(torch.cat((d_m1, d_m2, d_m3), dim=1) * scale, g).split(x.shape[1], dim=1)
        return g1 + 2 * x * g2 + y * g3, None


def ssim_loss_value(pred: Tensor, gt: Tensor) -> Tensor:
    """Mean SSIM as a differentiable 0-d tensor (higher is better): the loss is ``1 - value``.

    ``pred``, ``gt``: ``(H, W, C)`` or ``(B, H, W, C)`` floats in ``[0, 1]``, H, W >= 6; equals
    ``ssim`` for ``(H, W, 3)`` images up to rounding. The gradient with respect to ``pred`` is
    computed in closed form (``_MeanSsim``); when ``gt`` requires grad too, autograd through
    ``ssim_map`` is used instead.
    """
    if gt.requires_grad:
        return ssim_map(pred, gt).mean()
    x, y, _ = _to_planes(pred, gt, "ssim_loss_value")
    return _MeanSsim.apply(x, y)


# --- LPIPS -------------------------------------------------------------------------------------

# LPIPS backbone name -> (torchvision builder name, torchvision weights enum name): the
# ImageNet backbones torchmetrics' LearnedPerceptualImagePatchSimilarity builds.
_BACKBONES = {"vgg": ("vgg16", "VGG16_Weights"), "alex": ("alexnet", "AlexNet_Weights")}

# How each LPIPS figure is computed (written to metrics.json as "lpips_convention"). The field's
# convention, so that a figure sits beside 3DGS, PVG or a gsplat run: gsplat's trainer feeds the
# [0, 1] images unchanged to LPIPS-VGG (normalize=False: "The 3DGS official repo uses lpips vgg,
# which is equivalent with the following") and maps them to [-1, 1] for AlexNet (normalize=True).
LPIPS_CONVENTION: dict[str, dict[str, Any]] = {
    "lpips_vgg": {"net_type": "vgg", "normalize": False,
                  "input": "[0, 1] images fed as-is (the 3DGS / gsplat convention for LPIPS-VGG)"},
    "lpips_alex": {"net_type": "alex", "normalize": True,
                   "input": "[0, 1] images mapped to [-1, 1] (2x - 1; gsplat's LPIPS-Alex)"},
}


def lpips_convention() -> dict[str, Any]:
    """:data:`LPIPS_CONVENTION` with the implementation and the torchmetrics version that ran it."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        torchmetrics_version: Optional[str] = version("torchmetrics")
    except PackageNotFoundError:  # pragma: no cover - torchmetrics is a dependency
        torchmetrics_version = None
    return {**{key: dict(value) for key, value in LPIPS_CONVENTION.items()},
            "implementation": "torchmetrics.image.lpip.LearnedPerceptualImagePatchSimilarity "
                              "(reduction='mean'; LPIPS v0.1 linear layers)",
            "torchmetrics_version": torchmetrics_version}


def _check_net(net: str) -> None:
    if net not in _BACKBONES:
        raise ValueError(f"LPIPS net must be one of {sorted(_BACKBONES)}, got {net!r}")


def lpips_metric(net: LpipsNet) -> Any:
    """torchmetrics' public ``LearnedPerceptualImagePatchSimilarity`` for ``net`` in the field's
    convention (:data:`LPIPS_CONVENTION`). torchmetrics has torchvision build the ImageNet backbone,
    which reads it from the torch hub cache, or downloads it when it is not there: call it only
    when ``LpipsScorer.available(net)`` (or with torchvision's builder replaced, in tests)."""
    from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity

    _check_net(net)
    return LearnedPerceptualImagePatchSimilarity(net_type=net, reduction="mean",
                                                 normalize=LPIPS_CONVENTION[f"lpips_{net}"]["normalize"])


class LpipsScorer:
    """LPIPS (module doc) with the ``"vgg"`` or ``"alex"`` backbone; built once, reused per frame.

    ``LpipsScorer(net)`` needs the torchvision ImageNet backbone in the torch hub cache
    (``weights_path(net)``) and raises ``FileNotFoundError`` otherwise: nothing is downloaded
    (torchvision's loader reads the cached file). ``metric``: a metric built by the caller
    instead (tests give one with a random backbone); its ``normalize`` must be the convention's.

    ``scorer(pred, gt)``: ``(H, W, 3)`` images in ``[0, 1]``, any device (the network follows the
    inputs), returns a float >= 0, 0 for identical images.
    """

    def __init__(self, net: LpipsNet = "vgg", device: torch.device | str | None = None,
                 metric: Any = None) -> None:  # fmt: skip
        _check_net(net)
        self.net = net
        if metric is None:
            if not self.available(net):
                raise FileNotFoundError(
                    f"LPIPS-{net}: no backbone weights at {self.weights_path(net)} (torchvision's ImageNet "
                    f"{_BACKBONES[net][0]}); copy the file there, nothing is downloaded"
                )
            metric = lpips_metric(net)
        expected = LPIPS_CONVENTION[self.name]["normalize"]
        if getattr(metric, "normalize", None) is not expected:
            raise ValueError(f"{self.name}: the metric must have normalize={expected} (LPIPS_CONVENTION)")
        metric.eval().requires_grad_(False)
        self.metric = metric.to(device) if device is not None else metric

    @staticmethod
    def weights_path(net: LpipsNet) -> Path:
        """Where torchvision keeps the backbone: ``<torch.hub.get_dir()>/checkpoints/<file>``.

        The file name is torchvision's (the basename of its weights URL), today
        ``vgg16-397923af.pth`` and ``alexnet-owt-7be5be79.pth``.
        """
        import torchvision.models

        _check_net(net)
        weights = getattr(torchvision.models, _BACKBONES[net][1]).DEFAULT
        return Path(torch.hub.get_dir()) / "checkpoints" / os.path.basename(urlparse(weights.url).path)

    @classmethod
    def available(cls, net: LpipsNet) -> bool:
        """Whether the backbone weights are in the torch hub cache (no network access)."""
        return cls.weights_path(net).is_file()

    @property
    def name(self) -> str:
        return f"lpips_{self.net}"

    def __call__(self, pred: Tensor, gt: Tensor) -> float:
        _check_pair(pred, gt, self.name)
        if self.metric.device != pred.device:
            self.metric.to(pred.device)
        with torch.inference_mode():
            x = pred.to(torch.float32).permute(2, 0, 1)[None]
            y = gt.to(torch.float32).permute(2, 0, 1)[None]
            self.metric.reset()
            self.metric.update(x, y)
            value = float(self.metric.compute())
            self.metric.reset()
        return value


def lpips_or_none(net: LpipsNet, device: torch.device | str | None = None) -> Optional[LpipsScorer]:
    """An ``LpipsScorer`` for ``net`` when its backbone weights are cached, else ``None``."""
    return LpipsScorer(net, device=device) if LpipsScorer.available(net) else None


# --- aggregation -------------------------------------------------------------------------------


def _mean_or_none(values: Sequence[Optional[float]]) -> Optional[float]:
    if not values or any(v is None for v in values):
        return None
    return float(sum(values) / len(values))


def summarize_frames(per_frame: list[dict]) -> dict:
    """Average the per-frame metrics of one split.

    ``per_frame``: one dict per frame with ``psnr``, ``ssim``, ``lpips_vgg``, ``lpips_alex`` and
    ``psnr_dyn`` (float or ``None``; a missing key counts as ``None``).
    Returns ``psnr``, ``ssim``, ``lpips_vgg``, ``lpips_alex`` (the mean over all frames, ``None``
    when any frame has ``None``), ``psnr_dyn`` (the mean over the frames whose value is not
    ``None``, i.e. whose dynamic mask is not empty; ``None`` when there are none), ``n_frames`` and
    ``n_frames_dyn``.
    """
    summary: dict = {key: _mean_or_none([frame.get(key) for frame in per_frame]) for key in FRAME_METRICS}
    dyn = [frame["psnr_dyn"] for frame in per_frame if frame.get("psnr_dyn") is not None]
    summary["psnr_dyn"] = _mean_or_none(dyn)
    summary["n_frames"] = len(per_frame)
    summary["n_frames_dyn"] = len(dyn)
    return summary
