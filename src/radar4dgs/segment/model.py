"""The radar–camera dynamic segmentation network (4DRadar-GS, stage 4).

One forward pass segments a batch of square image patches, each centred on a projected dynamic
radar point (the anchor):

    image patch (3, S, S) ──ResNet stem, layer1..layer3──► multi-scale features
    radar points in the patch (P, F) ──mean pool──► (F,) ──Linear──► one radar token (C,)
    layer3 tokens (S/16 · S/16, C) + sine positional encoding
        ──[self-attention on image tokens, cross-attention image ⇄ radar token] × L──►
    U-Net decoder (upsample, concatenate layer2, layer1, stem and full-resolution skips)
        ──► (1, S, S) dynamic-probability logits

The attention is LoFTR's linear attention (Katharopoulos et al. 2020, feature map elu(x)+1),
written here from the formulas; LoFTR's code is not a dependency.

CPU choices (documented in docs/guide.md and the weights card): the patch is resized to a fixed
network input (``input_size``, 48 by default: 43 px patches at 320×180); the ResNet is
truncated after layer3 (layer4 would work on a 2×2 grid at that size) and may be narrowed with
``backbone_width`` (64 = torchvision's width, the only one that accepts ImageNet weights).
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn
from torchvision.models.resnet import BasicBlock

from radar4dgs.segment.config import SegModelConfig

# Per radar point features fed to the radar encoder, in this order (see patches.radar_features).
RADAR_FEATURES = ("du", "dv", "dz", "range", "v_comp", "dynamic", "rcs")
NUM_RADAR_FEATURES = len(RADAR_FEATURES)
# Blocks per ResNet stage up to layer3; layer4 is dropped (see module docstring).
RESNET_BLOCKS = {"resnet18": (2, 2, 2), "resnet34": (3, 4, 6)}


# --------------------------------------------------------------------------------------------
# Linear attention


def elu_feature_map(x: torch.Tensor) -> torch.Tensor:
    """phi(x) = elu(x) + 1 > 0, the kernel feature map of linear attention."""
    return F.elu(x) + 1.0


def linear_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Linear attention ``out_i = phi(q_i)ᵀ Σ_j phi(k_j) v_jᵀ / (phi(q_i)ᵀ Σ_j phi(k_j))``.

    Args:
        q: (B, L, H, D) queries; k: (B, S, H, D) keys; v: (B, S, H, Dv) values.

    Returns:
        (B, L, H, Dv). Cost O((L + S) D Dv) instead of softmax attention's O(L S D).
    """
    q, k = elu_feature_map(q), elu_feature_map(k)
    kv = torch.einsum("bshd,bshv->bhdv", k, v)  # (B, H, D, Dv)
    normaliser = 1.0 / (torch.einsum("blhd,bhd->blh", q, k.sum(dim=1)) + eps)  # (B, L, H)
    return torch.einsum("blhd,bhdv,blh->blhv", q, kv, normaliser)


class AttentionLayer(nn.Module):
    """One LoFTR encoder layer: multi-head linear attention from ``x`` to ``source``, a merge
    projection, and an MLP on ``[x, message]``; residual update ``x + message``.

    ``source is x`` gives self-attention, anything else cross-attention.
    """

    def __init__(self, width: int, heads: int):
        super().__init__()
        if width % heads:
            raise ValueError(f"token width {width} is not divisible by {heads} heads")
        self.heads = heads
        self.q = nn.Linear(width, width, bias=False)
        self.k = nn.Linear(width, width, bias=False)
        self.v = nn.Linear(width, width, bias=False)
        self.merge = nn.Linear(width, width, bias=False)
        self.mlp = nn.Sequential(nn.Linear(2 * width, 2 * width, bias=False), nn.ReLU(inplace=True),
                                 nn.Linear(2 * width, width, bias=False))
        self.norm1 = nn.LayerNorm(width)
        self.norm2 = nn.LayerNorm(width)

    def forward(self, x: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
        """x: (B, L, C) tokens to update; source: (B, S, C) tokens attended to. Returns (B, L, C)."""
        b, length, c = x.shape
        d = c // self.heads
        q = self.q(x).view(b, length, self.heads, d)
        k = self.k(source).view(b, source.shape[1], self.heads, d)
        v = self.v(source).view(b, source.shape[1], self.heads, d)
        message = self.norm1(self.merge(linear_attention(q, k, v).reshape(b, length, c)))
        message = self.norm2(self.mlp(torch.cat([x, message], dim=-1)))
        return x + message


class RadarImageFusion(nn.Module):
    """``layers`` pairs of (self-attention on image tokens, cross-attention image ⇄ radar)."""

    def __init__(self, width: int, heads: int, layers: int):
        super().__init__()
        self.self_layers = nn.ModuleList(AttentionLayer(width, heads) for _ in range(layers))
        self.image_from_radar = nn.ModuleList(AttentionLayer(width, heads) for _ in range(layers))
        self.radar_from_image = nn.ModuleList(AttentionLayer(width, heads) for _ in range(layers))

    def forward(self, image: torch.Tensor, radar: torch.Tensor) -> torch.Tensor:
        """image: (B, L, C) tokens; radar: (B, R, C) tokens (R = 1 here). Returns fused (B, L, C)."""
        for self_layer, to_image, to_radar in zip(self.self_layers, self.image_from_radar, self.radar_from_image,
                                                  strict=True):
            image = self_layer(image, image)
            # LoFTR updates both sides of a cross layer from the same inputs.
            image, radar = to_image(image, radar), to_radar(radar, image)
        return image


def sine_positional_encoding(channels: int, height: int, width: int, device: torch.device,
                             dtype: torch.dtype) -> torch.Tensor:
    """(channels, height, width) 2D sinusoidal encoding (LoFTR / DETR style), so that attention
    knows where each token sits relative to the patch centre (the anchor)."""
    quarter = channels // 4
    freqs = torch.exp(torch.arange(quarter, device=device, dtype=torch.float32)
                      * (-math.log(10000.0) / max(quarter, 1)))
    ys = torch.arange(height, device=device, dtype=torch.float32)[:, None, None] * freqs  # (H, 1, Q)
    xs = torch.arange(width, device=device, dtype=torch.float32)[None, :, None] * freqs  # (1, W, Q)
    ys, xs = ys.expand(height, width, quarter), xs.expand(height, width, quarter)
    encoding = torch.cat([xs.sin(), xs.cos(), ys.sin(), ys.cos()], dim=-1)  # (H, W, 4Q)
    encoding = F.pad(encoding, (0, channels - 4 * quarter))
    return encoding.permute(2, 0, 1).to(dtype)


# --------------------------------------------------------------------------------------------
# Backbone and decoder


class TruncatedResNet(nn.Module):
    """torchvision's ResNet (BasicBlock) up to layer3, with a width multiplier.

    Module names match ``torchvision.models.resnet18/34`` (``conv1``, ``bn1``, ``layer1``…), so
    an ImageNet state_dict loads into it when ``width == 64``.
    """

    def __init__(self, blocks: tuple[int, int, int], width: int):
        super().__init__()
        self.conv1 = nn.Conv2d(3, width, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(width)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.inplanes = width
        self.layer1 = self._make_layer(width, blocks[0], stride=1)
        self.layer2 = self._make_layer(2 * width, blocks[1], stride=2)
        self.layer3 = self._make_layer(4 * width, blocks[2], stride=2)
        self.channels = (width, width, 2 * width, 4 * width)  # stem, layer1, layer2, layer3
        for module in self.modules():  # torchvision's initialisation
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")

    def _make_layer(self, planes: int, count: int, stride: int) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes:
            downsample = nn.Sequential(nn.Conv2d(self.inplanes, planes, 1, stride, bias=False), nn.BatchNorm2d(planes))
        layers = [BasicBlock(self.inplanes, planes, stride, downsample)]
        self.inplanes = planes
        layers += [BasicBlock(planes, planes) for _ in range(1, count)]
        return nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """x: (B, 3, S, S) normalised RGB. Returns features at strides 2, 4, 8, 16:
        (B, w, S/2, S/2), (B, w, S/4, S/4), (B, 2w, S/8, S/8), (B, 4w, S/16, S/16)."""
        stem = self.relu(self.bn1(self.conv1(x)))
        f1 = self.layer1(self.maxpool(stem))
        f2 = self.layer2(f1)
        f3 = self.layer3(f2)
        return [stem, f1, f2, f3]


def conv_block(cin: int, cout: int) -> nn.Sequential:
    """Two 3×3 conv + BN + ReLU (the U-Net decoder unit)."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
                         nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class UNetDecoder(nn.Module):
    """Upsample ×2 four times from stride 16 to stride 1, concatenating the encoder feature of
    each scale (layer2, layer1, stem) and a full-resolution image feature for sharp outlines."""

    def __init__(self, encoder_channels: tuple[int, int, int, int], width: int):
        super().__init__()
        stem_c, c1, c2, c3 = encoder_channels
        w = [max(width // 2 ** i, 16) for i in range(4)]
        self.full_res = nn.Sequential(nn.Conv2d(3, 16, 3, padding=1, bias=False), nn.BatchNorm2d(16),
                                      nn.ReLU(inplace=True))
        self.up3 = conv_block(c3 + c2, w[0])  # → stride 8
        self.up2 = conv_block(w[0] + c1, w[1])  # → stride 4
        self.up1 = conv_block(w[1] + stem_c, w[2])  # → stride 2
        self.up0 = conv_block(w[2] + 16, w[3])  # → stride 1
        self.head = nn.Conv2d(w[3], 1, 1)

    def forward(self, image: torch.Tensor, features: list[torch.Tensor]) -> torch.Tensor:
        """image: (B, 3, S, S); features: [stem, f1, f2, fused f3] as TruncatedResNet.
        Returns (B, 1, S, S) logits."""
        stem, f1, f2, f3 = features

        def up(x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            return torch.cat([x, skip], dim=1)

        x = self.up3(up(f3, f2))
        x = self.up2(up(x, f1))
        x = self.up1(up(x, stem))
        x = self.up0(up(x, self.full_res(image)))
        return self.head(x)


class RadarEncoder(nn.Module):
    """Per-point MLP, masked mean pooling over the patch's points, linear lift to token width.

    The paper mean-pools the raw point attributes and lifts them with one linear layer; a small
    per-point MLP before pooling (``hidden``) lets the pooled vector hold more than the mean
    position and velocity. An empty patch (impossible for the anchor's own patch, which always
    holds the anchor) pools to zeros.
    """

    def __init__(self, features: int, hidden: int, width: int):
        super().__init__()
        self.point = nn.Sequential(nn.Linear(features, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, hidden),
                                   nn.ReLU(inplace=True))
        self.lift = nn.Linear(hidden, width)

    def forward(self, points: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """points: (B, P, F) features; valid: (B, P) bool. Returns (B, 1, width), one token per patch."""
        h = self.point(points) * valid[..., None].to(points.dtype)
        pooled = h.sum(dim=1) / valid.sum(dim=1, keepdim=True).clamp(min=1).to(points.dtype)
        return self.lift(pooled)[:, None, :]


# ImageNet statistics; a pretrained backbone expects them and a scratch one does not mind.
IMAGE_MEAN = (0.485, 0.456, 0.406)
IMAGE_STD = (0.229, 0.224, 0.225)


class RadarCameraSegNet(nn.Module):
    """Patch-wise dynamic segmentation from an image patch and the radar points inside it."""

    def __init__(self, config: SegModelConfig | None = None):
        super().__init__()
        self.config = config or SegModelConfig()
        c = self.config
        if c.input_size % 16:
            raise ValueError(f"input_size must be a multiple of 16, got {c.input_size}")
        self.backbone = TruncatedResNet(RESNET_BLOCKS[c.backbone], c.backbone_width)
        token = self.backbone.channels[3]
        self.radar = RadarEncoder(NUM_RADAR_FEATURES, c.radar_hidden, token)
        self.fusion = RadarImageFusion(token, c.attention_heads, c.attention_layers)
        self.decoder = UNetDecoder(self.backbone.channels, c.decoder_width)
        self.register_buffer("mean", torch.tensor(IMAGE_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGE_STD).view(1, 3, 1, 1), persistent=False)

    def forward(self, patches: torch.Tensor, points: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """Segment B patches.

        Args:
            patches: (B, 3, S, S) RGB in [0, 1], S = ``config.input_size``, centred on the anchors.
            points: (B, P, NUM_RADAR_FEATURES) radar point features (``patches.radar_features``).
            valid: (B, P) bool, which rows of ``points`` are real (the rest is padding).

        Returns:
            (B, 1, S, S) logits of "this pixel belongs to a moving object".
        """
        x = (patches - self.mean) / self.std
        stem, f1, f2, f3 = self.backbone(x)
        b, c, h, w = f3.shape
        f3 = f3 + sine_positional_encoding(c, h, w, f3.device, f3.dtype)
        tokens = f3.flatten(2).transpose(1, 2)  # (B, h*w, C)
        fused = self.fusion(tokens, self.radar(points, valid))
        fused = fused.transpose(1, 2).reshape(b, c, h, w)
        return self.decoder(x, [stem, f1, f2, fused])


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def load_pretrained_backbone(model: RadarCameraSegNet, path: Path) -> list[str]:
    """Load a user-provided torchvision ImageNet ResNet state_dict (``resnet18/34-*.pth``) into the
    backbone; keys of layer4 and fc are ignored. Returns the loaded key names.

    Raises ValueError when the widths do not match (``backbone_width`` must be 64).
    """
    state = torch.load(path, map_location="cpu", weights_only=True)
    if "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    prefixes = ("conv1.", "bn1.", "layer1.", "layer2.", "layer3.")
    wanted = {k: v for k, v in state.items() if k.startswith(prefixes)}
    own = model.backbone.state_dict()
    mismatched = [k for k, v in wanted.items() if k in own and own[k].shape != v.shape]
    missing = [k for k in own if k not in wanted]
    if mismatched or missing:
        raise ValueError(f"{path}: not a torchvision {model.config.backbone} state_dict for width "
                         f"{model.config.backbone_width} ({len(mismatched)} shape mismatches, e.g. "
                         f"{mismatched[:2]}; {len(missing)} missing keys, e.g. {missing[:2]}); "
                         f"ImageNet weights need backbone_width=64")
    model.backbone.load_state_dict(wanted, strict=True)
    return sorted(wanted)


# --------------------------------------------------------------------------------------------
# Checkpoints


def checkpoint_payload(model: RadarCameraSegNet, half: bool = False, **extra) -> dict:
    """A torch.save-able dict: the model config and state_dict (float16 when ``half``) and extras."""
    from radar4dgs.config import to_dict

    state = {k: (v.half() if half and v.is_floating_point() else v).detach().cpu().clone()
             for k, v in model.state_dict().items()}
    return {"format": "radar4dgs-segnet", "version": 1, "model_config": to_dict(model.config), "state_dict": state,
            **extra}


def model_from_checkpoint(payload: dict, device: torch.device | str = "cpu",
                          dtype: torch.dtype = torch.float32) -> RadarCameraSegNet:
    """Rebuild the network of a checkpoint dict (see :func:`checkpoint_payload`) in eval mode."""
    from radar4dgs.config import from_dict

    if payload.get("format") != "radar4dgs-segnet":
        raise ValueError("not a radar4dgs segmentation checkpoint (format key missing)")
    model = RadarCameraSegNet(from_dict(SegModelConfig, payload["model_config"]))
    state = {k: v.to(dtype) if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    model.load_state_dict(state)
    return model.to(device=device, dtype=dtype).eval()
