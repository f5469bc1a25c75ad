"""EWA projection of 3D Gaussians to the image plane, in plain differentiable PyTorch.

Mirrors gsplat 1.5.3's ``fully_fused_projection`` (pinhole camera, ``packed=False``, classic
mode) as found in its CUDA sources (``gsplat/cuda/csrc/ProjectionEWA3DGSFused.cu`` and
``gsplat/cuda/include/Utils.cuh``, the ``gsplat-1.5.3-py3-none-any.whl`` on PyPI):

- covariance ``Sigma = R S S^T R^T`` from the (normalised) wxyz quaternion and activated scales;
- world-to-camera ``mu_c = R_cw mu + t_cw``, ``Sigma_c = R_cw Sigma R_cw^T``;
- cull when ``z < near_plane`` or ``z > far_plane``;
- Jacobian of the pinhole projection at the mean, with ``x/z`` clamped to
  ``[-(cx/fx + 0.3 tan_fovx), (W - cx)/fx + 0.3 tan_fovx]`` (the same for y), ``tan_fovx = W/(2 fx)``:
  that is +-1.3 tan(fov/2) for a centred principal point (``persp_proj``);
- ``cov2d = J Sigma_c J^T + eps2d I`` ("classic": opacity not compensated; ``add_blur``), cull when
  its determinant is <= 0;
- cull when the opacity is below ALPHA_THRESHOLD = 1/255;
- opacity-aware extent ``extend = min(3.33, sqrt(2 ln(opacity / (1/255))))`` and per-axis radii
  ``ceil(extend * sqrt(cov2d_xx))``, ``ceil(extend * sqrt(cov2d_yy))`` (so radii are (C, N, 2));
- cull when both radii are <= ``radius_clip``, or the box lies outside the image.

gsplat leaves the outputs of culled Gaussians uninitialised; here they are zero (radii 0 marks
them as culled, exactly as in gsplat).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

# gsplat 1.5.3, gsplat/cuda/include/Common.h: `#define ALPHA_THRESHOLD (1.f / 255.f)`.
ALPHA_THRESHOLD = 1.0 / 255.0
# gsplat 1.5.3, ProjectionEWA3DGSFused.cu: `float extend = 3.33f;` (max extent in std devs).
MAX_EXTEND = 3.33
# gsplat 1.5.3, Utils.cuh persp_proj: the clamp margin `0.3f * tan_fovx` beyond the image edge.
FOV_MARGIN = 0.3


class Projection(NamedTuple):
    """Per-camera projected Gaussians, gsplat's ``packed=False`` layout."""

    radii: Tensor  # (C, N, 2) int32, 0 when culled (not differentiable)
    means2d: Tensor  # (C, N, 2) pixel coordinates (pixel centres at +0.5)
    depths: Tensor  # (C, N) camera-space z
    conics: Tensor  # (C, N, 3) inverse 2D covariance (xx, xy, yy)
    visible: Tensor  # (C, N) bool, radii > 0 on both axes


def _rotmat_components(quats: Tensor) -> Tensor:
    """Rotation matrices of wxyz quaternions (normalised first, as gsplat), component-major:
    quats (N, 4) -> (3, 3, N)."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip
    return torch.stack(rows, dim=0).reshape((3, 3) + q.shape[:-1])


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    eps2d: float = 0.3,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    radius_clip: float = 0.0,
) -> Projection:
    """Project N Gaussians into C pinhole cameras (see the module docstring for the rules).

    means (N, 3), quats (N, 4) wxyz, scales (N, 3), opacities (N,), viewmats (C, 4, 4)
    world-to-camera (OpenCV axes), Ks (C, 3, 3). Differentiable in means, quats, scales and
    viewmats through means2d, depths and conics; radii are integers.
    """
    rot = viewmats[:, :3, :3]  # (C, 3, 3)
    trans = viewmats[:, :3, 3]  # (C, 3)
    means_c = torch.einsum("cij,nj->cni", rot, means) + trans[:, None, :]  # (C, N, 3)
    # R S of each Gaussian, component-major (3, 3, N) so that every op below runs along N
    # (vectorised); its covariance is (R S)(R S)^T.
    rs = _rotmat_components(quats) * scales.transpose(0, 1)[None]  # (3, 3, N): R_ik s_k

    x, y, z = means_c.unbind(-1)  # (C, N)
    in_depth = (z >= near_plane) & (z <= far_plane)
    # Culled Gaussians can sit at z <= 0; divide by a safe z so no inf/NaN enters the graph
    # (a NaN in an unselected torch.where branch still poisons the gradient).
    z_safe = torch.where(in_depth, z, torch.ones_like(z))

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]  # (C, 1)
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + FOV_MARGIN * tan_fovx
    lim_x_neg = cx / fx + FOV_MARGIN * tan_fovx
    lim_y_pos = (height - cy) / fy + FOV_MARGIN * tan_fovy
    lim_y_neg = cy / fy + FOV_MARGIN * tan_fovy
    rz = 1.0 / z_safe
    # The clamp only enters the Jacobian (off-screen Gaussians would otherwise blow up).
    tx = z_safe * torch.minimum(lim_x_pos, torch.maximum(-lim_x_neg, x * rz))
    ty = z_safe * torch.minimum(lim_y_pos, torch.maximum(-lim_y_neg, y * rz))
    # cov2d = J W (R S)(R S)^T W^T J^T with J the (2, 3) Jacobian (two zeros) and W the camera
    # rotation: V = J W R S by broadcast products, then cov2d = V V^T, all component-major
    # (..., N). Batched 3x3 matmuls (bmm) and ops over tiny trailing dimensions are slow on CPU.
    ja = torch.stack((fx * rz, fy * rz), dim=1)  # (C, 2, N): J[0, 0], J[1, 1]
    jb = torch.stack((-fx * tx * rz * rz, -fy * ty * rz * rz), dim=1)  # J[0, 2], J[1, 2]
    jw = ja[:, :, None] * rot[:, :2, :, None] + jb[:, :, None] * rot[:, 2:3, :, None]  # (C,2,3,N)
    v = (jw[:, :, :, None] * rs[None, None]).sum(dim=2)  # (C, 2, 3, N): (J W R S)[a, k]
    cov2d = (v[:, :, None] * v[:, None]).sum(dim=3).permute(0, 3, 1, 2)  # (C, N, 2, 2)
    means2d = torch.stack((fx * x * rz + cx, fy * y * rz + cy), dim=-1)  # (C, N, 2)

    c00 = cov2d[..., 0, 0] + eps2d
    c11 = cov2d[..., 1, 1] + eps2d
    c01 = cov2d[..., 0, 1]
    det = c00 * c11 - c01 * cov2d[..., 1, 0]
    ok = in_depth & (det > 0)
    det_safe = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack((c11 / det_safe, -c01 / det_safe, c00 / det_safe), dim=-1)

    radii = _radii(c00.detach(), c11.detach(), opacities.detach(), ok, means2d.detach(),
                   width, height, radius_clip)  # fmt: skip
    visible = (radii > 0).all(dim=-1)
    vis_f = visible.to(means.dtype)
    return Projection(
        radii=radii,
        means2d=means2d * vis_f[..., None],
        depths=z * vis_f,
        conics=conics * vis_f[..., None],
        visible=visible,
    )


def _radii(
    c00: Tensor, c11: Tensor, opacities: Tensor, ok: Tensor, means2d: Tensor,
    width: int, height: int, radius_clip: float,
) -> Tensor:  # fmt: skip
    """Per-axis integer radii (C, N, 2), 0 where culled. Not differentiable (gsplat neither).

    c00, c11: blurred 2D variances (C, N); opacities (N,); ok (C, N) depth/determinant test;
    means2d (C, N, 2).
    """
    opac = opacities[None, :].expand_as(c00)
    ok = ok & (opac >= ALPHA_THRESHOLD)
    # Where opacity * exp(-sigma) drops below 1/255: the box then holds every pixel that the
    # compositor can blend, so tile binning loses nothing (see torch_backend).
    ratio = torch.clamp(opac / ALPHA_THRESHOLD, min=1.0)
    extend = torch.clamp(torch.sqrt(2.0 * torch.log(ratio)), max=MAX_EXTEND)
    rx = torch.ceil(extend * torch.sqrt(torch.clamp(c00, min=0.0)))
    ry = torch.ceil(extend * torch.sqrt(torch.clamp(c11, min=0.0)))
    ok = ok & ~((rx <= radius_clip) & (ry <= radius_clip))
    mx, my = means2d.unbind(-1)
    inside = (mx + rx > 0) & (mx - rx < width) & (my + ry > 0) & (my - ry < height)
    ok = ok & inside
    radii = torch.stack((rx, ry), dim=-1) * ok[..., None]
    radii = torch.nan_to_num(radii, nan=0.0, posinf=0.0, neginf=0.0)
    return radii.to(torch.int32)
