"""A learnable sky: an equirectangular environment map looked up by world ray direction.

Pure torch (a bilinear lookup written as gathers), so it runs wherever the trainer runs;
composited behind the Gaussians as ``rgb + (1 - alpha) * sky(direction)``.

Map convention (world axes, z up as in the scene format's ego and world frames): longitude
``phi = atan2(d_y, d_x)`` in (-pi, pi], latitude ``lat = asin(d_z)`` in [-pi/2, pi/2]. Texel
``(row i, column j)`` of a (H, W) map is centred on ``phi_j = -pi + (j + 0.5) 2 pi / W`` and
``lat_i = pi/2 - (i + 0.5) pi / H`` (row 0 at the zenith). Lookup is bilinear in colour; longitude
wraps (the last column neighbours the first), latitude is clamped at the poles.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np
import torch
from torch import Tensor, nn


class SkyEnvironment(nn.Module):
    """Learnable (3, H, W) equirectangular map of colour logits; ``forward(dirs)`` -> rgb in [0, 1]."""

    def __init__(self, height: int = 64, width: int = 128, init_color: Sequence[float] | Any = None,
                 device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32):
        super().__init__()
        if height < 2 or width < 2:
            raise ValueError(f"the map needs at least 2x2 texels, got {height}x{width}")
        color = torch.full((3,), 0.5, dtype=torch.float64) if init_color is None else \
            torch.as_tensor(np.asarray(init_color, dtype=np.float64).reshape(3))
        color = color.clamp(1e-3, 1 - 1e-3)
        logits = (torch.log(color) - torch.log1p(-color)).to(device=device, dtype=dtype)
        self.logits = nn.Parameter(logits[:, None, None].expand(3, height, width).clone())

    @classmethod
    def from_sky_pixels(cls, images: Sequence[np.ndarray], sky_masks: Sequence[np.ndarray],
                        **kwargs: Any) -> "SkyEnvironment":
        """A map initialised to the mean colour of the sky pixels of uint8 (H, W, 3) ``images``
        under bool (H, W) ``sky_masks`` (grey when there is no sky pixel)."""
        total, count = np.zeros(3), 0
        for image, mask in zip(images, sky_masks, strict=True):
            pixels = np.asarray(image)[np.asarray(mask, dtype=bool)]
            total += pixels.reshape(-1, 3).astype(np.float64).sum(axis=0) / 255.0
            count += len(pixels)
        return cls(init_color=total / count if count else None, **kwargs)

    @property
    def height(self) -> int:
        return int(self.logits.shape[1])

    @property
    def width(self) -> int:
        return int(self.logits.shape[2])

    def colors(self) -> Tensor:
        """(3, H, W) map colours in [0, 1]."""
        return torch.sigmoid(self.logits)

    def texel_directions(self) -> Tensor:
        """(H, W, 3) world unit directions of the texel centres."""
        H, W = self.height, self.width
        kw = {"device": self.logits.device, "dtype": self.logits.dtype}
        lat = math.pi / 2 - (torch.arange(H, **kw) + 0.5) * math.pi / H
        phi = -math.pi + (torch.arange(W, **kw) + 0.5) * 2 * math.pi / W
        lat, phi = torch.meshgrid(lat, phi, indexing="ij")
        return torch.stack([lat.cos() * phi.cos(), lat.cos() * phi.sin(), lat.sin()], dim=-1)

    def texel_weights(self, directions: Tensor) -> tuple[Tensor, Tensor]:
        """The bilinear lookup of (..., 3) world ``directions`` (normalised here): ``index`` (4, M) long
        flat texel indices (row * W + column) and ``weights`` (4, M), M the number of directions."""
        d = directions.reshape(-1, 3).to(self.logits.dtype)
        d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        H, W = self.height, self.width
        phi = torch.atan2(d[:, 1], d[:, 0])
        lat = torch.asin(d[:, 2].clamp(-1.0, 1.0))
        # Texel-index coordinates (texel centres at integers). Written as four gathers rather
        # than grid_sample over the whole map: a map fine enough for the sky's clouds has millions
        # of texels, and a sigmoid and a padded copy of all of them every lookup cost more than the
        # few texels a frame sees.
        x = (phi + math.pi) / (2 * math.pi) * W - 0.5
        y = ((math.pi / 2 - lat) / math.pi * H - 0.5).clamp(0.0, H - 1.0)
        x0, y0 = torch.floor(x), torch.floor(y).clamp(max=H - 2)
        fx, fy = x - x0, y - y0
        c0 = torch.remainder(x0.long(), W)
        c1 = torch.remainder(c0 + 1, W)
        r0 = y0.long() * W
        r1 = r0 + W
        index = torch.stack([r0 + c0, r0 + c1, r1 + c0, r1 + c1])
        weights = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
        return index, weights

    def forward(self, directions: Tensor) -> Tensor:
        """(..., 3) world directions (normalised here) -> (..., 3) rgb in [0, 1], differentiable in
        the map (not in the directions' angles at the poles)."""
        shape = directions.shape[:-1]
        index, weights = self.texel_weights(directions)
        # index_select: its backward (index_add) sums repeated texels in a fixed order, whatever the
        # thread count, so a resumed run on other threads matches (advanced indexing does not).
        texels = torch.sigmoid(self.logits.reshape(3, -1).index_select(1, index.reshape(-1)))
        texels = texels.reshape(3, 4, -1)  # (3, 4, M)
        return (texels * weights).sum(dim=1).T.reshape(*shape, 3)

    def composite(self, rgb: Tensor, alpha: Tensor, directions: Tensor) -> Tensor:
        """``rgb + (1 - alpha) * sky(directions)``: rgb (H, W, 3) premultiplied by the Gaussians'
        accumulated ``alpha`` (H, W, 1), directions (H, W, 3) world rays."""
        return rgb + (1.0 - alpha) * self(directions)


def camera_ray_directions(K: Any, world_to_cam: Any, height: int, width: int,
                          device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                          pixel_offset: float = 0.0) -> Tensor:
    """(H, W, 3) world unit ray directions of the pixels of a pinhole camera.

    ``K`` (3, 3) and ``world_to_cam`` (4, 4, OpenCV axes) as in the scene format. Pixel ``(i, j)``
    sits at ``(j + pixel_offset, i + pixel_offset)``: 0 for the scene's convention (centres at
    integer coordinates), 0.5 with intrinsics in the rasterizer's convention.
    """
    K = torch.as_tensor(np.asarray(K, dtype=np.float64))
    w2c = torch.as_tensor(np.asarray(world_to_cam, dtype=np.float64))
    v, u = torch.meshgrid(torch.arange(height, dtype=torch.float64) + pixel_offset,
                          torch.arange(width, dtype=torch.float64) + pixel_offset, indexing="ij")
    d_cam = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], dim=-1)
    d_world = d_cam @ w2c[:3, :3]  # R^T d for each row: camera-to-world rotation
    d_world = d_world / d_world.norm(dim=-1, keepdim=True)
    return d_world.to(device=device, dtype=dtype)
