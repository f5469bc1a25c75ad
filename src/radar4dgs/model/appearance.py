"""Exposure / appearance compensation: a per-frame affine colour transform learned in training
(issue 27), as drivestudio's per-image affine and gsplat's ``app_opt`` do.

The render of training frame ``k`` is compared with its image after

    rgb' = (I + A_k) rgb + b_k,     A_k (3, 3), b_k (3,), both zero-initialised,

so a camera whose exposure or white balance changes from frame to frame does not have to bake
those changes into the Gaussians' colours. The transform is regularised toward the identity (mean
squared entries of ``A`` and ``b``) and never used at test time: a test view has no learned
transform, so evaluation renders the scene's own colours (the identity).
"""

from __future__ import annotations

from typing import Any, Mapping

import torch
from torch import Tensor, nn


def affine_colors(rgb: Tensor, matrix: Tensor, bias: Tensor) -> Tensor:
    """(H, W, 3) colours through ``(I + matrix) rgb + bias``; ``matrix`` (3, 3), ``bias`` (3,)."""
    return rgb + rgb @ matrix.transpose(0, 1) + bias


class FrameAppearance(nn.Module):
    """Zero-initialised per-frame affine colour corrections of N training frames (rows in the
    order of the scene's ``train_indices``): ``matrix`` (N, 3, 3) and ``bias`` (N, 3)."""

    def __init__(self, num_frames: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32):
        super().__init__()
        self.matrix = nn.Parameter(torch.zeros(num_frames, 3, 3, device=device, dtype=dtype))
        self.bias = nn.Parameter(torch.zeros(num_frames, 3, device=device, dtype=dtype))

    def __len__(self) -> int:
        return int(self.bias.shape[0])

    def forward(self, rgb: Tensor, row: int | None) -> Tensor:
        """(H, W, 3) ``rgb`` through row ``row``'s transform; ``row`` None (a test view) is the
        identity and returns ``rgb`` itself."""
        if row is None:
            return rgb
        return affine_colors(rgb, self.matrix[row], self.bias[row])

    @torch.no_grad()
    def remove_mean(self) -> None:
        """Subtract the mean transform over the frames: the scene's colours are the average frame's,
        which test views (identity) render; a common offset in every frame's transform would
        otherwise leave the Gaussians' colours off by it."""
        self.matrix -= self.matrix.mean(0)
        self.bias -= self.bias.mean(0)

    def regularizer(self) -> Tensor:
        """Mean squared deviation from the identity (entries of ``matrix`` and ``bias``)."""
        return (self.matrix ** 2).sum((1, 2)).mean() + (self.bias ** 2).sum(1).mean()

    def param_groups(self, lr: float) -> list[dict[str, Any]]:
        return [{"params": [self.matrix, self.bias], "lr": lr, "name": "appearance"}]

    def state(self) -> dict[str, Tensor]:
        return {"matrix": self.matrix.detach().cpu(), "bias": self.bias.detach().cpu()}

    @classmethod
    def from_state(cls, state: Mapping[str, Tensor], device: torch.device | str = "cpu",
                   dtype: torch.dtype = torch.float32) -> "FrameAppearance":
        out = cls(len(state["bias"]), device, dtype)
        with torch.no_grad():
            out.matrix.copy_(state["matrix"].to(out.matrix))
            out.bias.copy_(state["bias"].to(out.bias))
        return out

    def gains(self) -> Tensor:
        """(N, 3) per-channel gain (diagonal of ``I + matrix``), for reports."""
        return 1.0 + torch.diagonal(self.matrix.detach(), dim1=1, dim2=2)
