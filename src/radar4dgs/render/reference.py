"""Naive reference rasterizer: per Gaussian, per pixel, no tiles, written plainly for tests.

Slow (a Python loop over Gaussians, every pixel evaluated for every Gaussian) and meant for tiny
scenes in float64. It is written independently of :mod:`projection` and :mod:`torch_backend`
(no shared helpers) so that agreement between the two is evidence, and follows gsplat 1.5.3's
rules literally (see those modules' docstrings for the sources): projection with the clamped
Jacobian and ``eps2d`` blur, opacity-aware per-axis radii and culling, depth order with ties by
index, ``alpha = min(0.999, o exp(-sigma))``, skip when ``sigma < 0`` or ``alpha < 1/255``, stop
(exclusive) when ``T (1 - alpha) <= 1e-4``. Differentiable by autograd.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def _rotation(q: Tensor) -> Tensor:
    """(4,) wxyz, any norm -> (3, 3)."""
    w, x, y, z = q / torch.sqrt((q * q).sum())
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
        ]
    )


def _project_one(mean, quat, scale, opacity, view, K, width, height, eps2d, near, far, clip):
    """One Gaussian into one camera: (visible, mean2d (2,), depth, conic (a, b, c))."""
    p = view[:3, :3] @ mean + view[:3, 3]
    x, y, z = p[0], p[1], p[2]
    if z.item() < near or z.item() > far:
        return False, None, None, None
    M = _rotation(quat) @ torch.diag(scale)
    cov_c = view[:3, :3] @ (M @ M.T) @ view[:3, :3].T
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lim_xp = (width - cx) / fx + 0.3 * (0.5 * width / fx)
    lim_xn = cx / fx + 0.3 * (0.5 * width / fx)
    lim_yp = (height - cy) / fy + 0.3 * (0.5 * height / fy)
    lim_yn = cy / fy + 0.3 * (0.5 * height / fy)
    tx = z * torch.clamp(x / z, -lim_xn, lim_xp)
    ty = z * torch.clamp(y / z, -lim_yn, lim_yp)
    zero = torch.zeros((), dtype=p.dtype)
    J = torch.stack(
        [
            torch.stack([fx / z, zero, -fx * tx / (z * z)]),
            torch.stack([zero, fy / z, -fy * ty / (z * z)]),
        ]
    )
    cov2 = J @ cov_c @ J.T + eps2d * torch.eye(2, dtype=p.dtype)
    det = cov2[0, 0] * cov2[1, 1] - cov2[0, 1] * cov2[1, 0]
    if det.item() <= 0.0:
        return False, None, None, None
    o = opacity.item()
    if o < 1.0 / 255.0:
        return False, None, None, None
    extend = min(3.33, math.sqrt(2.0 * math.log(o * 255.0)))
    rx = math.ceil(extend * math.sqrt(cov2[0, 0].item()))
    ry = math.ceil(extend * math.sqrt(cov2[1, 1].item()))
    if rx <= clip and ry <= clip:
        return False, None, None, None
    mean2d = torch.stack([fx * x / z + cx, fy * y / z + cy])
    u, v = mean2d[0].item(), mean2d[1].item()
    if u + rx <= 0 or u - rx >= width or v + ry <= 0 or v - ry >= height:
        return False, None, None, None
    conic = torch.stack([cov2[1, 1] / det, -cov2[0, 1] / det, cov2[0, 0] / det])
    return True, mean2d, z, conic


def reference_rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    backgrounds: Tensor | None = None,
    render_mode: str = "RGB",
    eps2d: float = 0.3,
    radius_clip: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor]:
    """Same contract as :func:`radar4dgs.render.rasterize` for colours (N, D); returns
    render_colors (C, H, W, X), render_alphas (C, H, W, 1) and the visibility (C, N) bool."""
    C, N = viewmats.shape[0], means.shape[0]
    D = colors.shape[-1]
    dt = means.dtype
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dt) + 0.5, torch.arange(width, dtype=dt) + 0.5, indexing="ij"
    )
    images, alphas, visible = [], [], torch.zeros((C, N), dtype=torch.bool)
    for c in range(C):
        projected = []
        for n in range(N):
            ok, m2, z, conic = _project_one(
                means[n], quats[n], scales[n], opacities[n], viewmats[c], Ks[c],
                width, height, eps2d, near_plane, far_plane, radius_clip,
            )  # fmt: skip
            if ok:
                visible[c, n] = True
                projected.append((z.item(), n, m2, z, conic))
        projected.sort(key=lambda item: (item[0], item[1]))  # depth, ties by index

        with_depth = render_mode in ("D", "ED", "RGB+D", "RGB+ED")
        with_rgb = render_mode in ("RGB", "RGB+D", "RGB+ED")
        X = (D if with_rgb else 0) + (1 if with_depth else 0)
        out = torch.zeros((height, width, X), dtype=dt)
        T = torch.ones((height, width), dtype=dt)
        done = torch.zeros((height, width), dtype=torch.bool)
        for _, n, m2, z, conic in projected:
            feats = []
            if with_rgb:
                feats.append(colors[n])
            if with_depth:
                feats.append(z[None])
            feat = torch.cat(feats)
            dx = m2[0] - xs
            dy = m2[1] - ys
            sigma = 0.5 * (conic[0] * dx * dx + conic[2] * dy * dy) + conic[1] * dx * dy
            alpha = torch.clamp(opacities[n] * torch.exp(-sigma), max=0.999)
            active = ~done & ~((sigma < 0) | (alpha < 1.0 / 255.0))
            next_T = T * (1 - alpha)
            stop = active & (next_T <= 1e-4)
            blend = active & ~stop
            out = out + torch.where(blend[..., None], (alpha * T)[..., None] * feat, 0.0)
            T = torch.where(blend, next_T, T)
            done = done | stop
        if backgrounds is not None:
            bg = backgrounds[c] if with_rgb else backgrounds.new_zeros(0)
            if with_depth:
                bg = torch.cat([bg, backgrounds.new_zeros(1)])
            out = out + T[..., None] * bg
        alpha_img = (1 - T)[..., None]
        if render_mode in ("ED", "RGB+ED"):
            out = torch.cat([out[..., :-1], out[..., -1:] / alpha_img.clamp(min=1e-10)], -1)
        images.append(out)
        alphas.append(alpha_img)
    return torch.stack(images), torch.stack(alphas), visible
