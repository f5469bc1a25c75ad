"""Adaptive density control of a :class:`GaussianSet` (3DGS, Kerbl et al. 2023, section 5.2).

Written here rather than taken from gsplat's ``DefaultStrategy``: this project never imports gsplat
on a CPU-only machine. The rules are the same: accumulate the norm of each Gaussian's screen-space
mean gradient (in NDC units: pixel gradient times half the image size); every few hundred steps
clone the small Gaussians whose average exceeds a threshold and split the large ones in two
(samples from the Gaussian, scales divided by 1.6), then prune the transparent and the huge.
The optimizer's Adam moments follow every row (kept rows keep theirs, new rows start at zero).
"""

from __future__ import annotations

import math
from typing import Callable

import torch
from torch import Tensor, nn

from radar4dgs.model.config import DensifyConfig
from radar4dgs.model.gaussians import MOTION_PARAM_NAMES, PARAM_NAMES, GaussianSet
from radar4dgs.render.projection import _rotmat_components

SPLIT_SCALE_DIVISOR = 1.6  # 3DGS: each of the two halves gets the scale / (0.8 * 2)


class GradientStats:
    """Running sum of the NDC-unit mean-gradient norm and visibility count of N Gaussians."""

    def __init__(self, n: int, device: torch.device | str = "cpu"):
        self.grad = torch.zeros(n, dtype=torch.float64, device=device)
        self.count = torch.zeros(n, dtype=torch.float64, device=device)

    def add(self, means2d_grad: Tensor, visible: Tensor, width: int, height: int) -> None:
        """Accumulate (N, 2) pixel-space gradients of the (N,) visible Gaussians."""
        g = means2d_grad.detach().double()
        norm = torch.stack([g[:, 0] * width / 2.0, g[:, 1] * height / 2.0], dim=-1).norm(dim=-1)
        self.grad += torch.where(visible, norm, torch.zeros_like(norm))
        self.count += visible.double()

    def average(self) -> Tensor:
        return self.grad / self.count.clamp_min(1.0)

    def reset(self, n: int) -> None:
        self.grad = torch.zeros(n, dtype=torch.float64, device=self.grad.device)
        self.count = torch.zeros(n, dtype=torch.float64, device=self.grad.device)

    def state_dict(self) -> dict[str, Tensor]:
        return {"grad": self.grad.cpu(), "count": self.count.cpu()}

    def load_state_dict(self, state: dict[str, Tensor]) -> None:
        self.grad = state["grad"].to(self.grad.device)
        self.count = state["count"].to(self.grad.device)


def _group_name(group: dict) -> str:
    """The parameter name of an optimizer group made by :meth:`GaussianSet.param_groups`."""
    name = group["name"].rsplit(".", 1)[-1]
    if name not in PARAM_NAMES + MOTION_PARAM_NAMES:
        raise KeyError(f"optimizer group {group['name']!r} is not a Gaussian parameter")
    return name


def edit_rows(gaussians: GaussianSet, optimizer: torch.optim.Optimizer,
              edit: Callable[[str, Tensor, bool], Tensor]) -> None:
    """Replace every parameter ``p`` of ``gaussians`` by ``edit(name, p, False)`` and each of its
    Adam moments ``m`` by ``edit(name, m, True)`` (the flag says "moment": new rows must be 0)."""
    groups = {_group_name(g): g for g in optimizer.param_groups}
    for name in gaussians.names:
        old = gaussians.params[name]
        new = nn.Parameter(edit(name, old.detach(), False))
        group = groups.get(name)
        if group is not None:
            state = optimizer.state.pop(old, {})
            for key in ("exp_avg", "exp_avg_sq"):
                if key in state:
                    state[key] = edit(name, state[key], True)
            group["params"] = [new]
            if state:
                optimizer.state[new] = state
        gaussians.params[name] = new


def keep_rows(gaussians: GaussianSet, optimizer: torch.optim.Optimizer, keep: Tensor) -> None:
    """Keep the rows where the (N,) bool ``keep`` is True."""
    edit_rows(gaussians, optimizer, lambda name, t, moment: t[keep].clone())


def append_rows(gaussians: GaussianSet, optimizer: torch.optim.Optimizer, rows: dict[str, Tensor]) -> None:
    """Append new Gaussians (a tensor per parameter name, M rows each); their moments start at 0."""
    def edit(name: str, t: Tensor, moment: bool) -> Tensor:
        extra = torch.zeros_like(rows[name]) if moment else rows[name].to(t)
        return torch.cat([t, extra], dim=0)

    edit_rows(gaussians, optimizer, edit)


def split_samples(params: dict[str, Tensor], generator: torch.Generator) -> dict[str, Tensor]:
    """Two children per Gaussian of ``params`` (rows to split): means sampled from the Gaussian,
    log-scales reduced by log(1.6), everything else copied. Returns 2M rows."""
    scales = torch.exp(params["log_scales"])
    noise = torch.randn((2,) + tuple(scales.shape), generator=generator, dtype=scales.dtype).to(scales.device)
    rot = _rotmat_components(params["quats"]).permute(2, 0, 1)  # (M, 3, 3)
    offsets = torch.einsum("mij,kmj->kmi", rot, noise * scales[None])
    children = {name: value.repeat(2, *([1] * (value.dim() - 1))) for name, value in params.items()}
    children["means"] = (params["means"][None] + offsets).reshape(-1, 3)
    children["log_scales"] = children["log_scales"] - math.log(SPLIT_SCALE_DIVISOR)
    return children


@torch.no_grad()
def densify_and_prune(gaussians: GaussianSet, optimizer: torch.optim.Optimizer, stats: GradientStats,
                      extent: float, config: DensifyConfig, generator: torch.Generator,
                      prune_large: bool = False) -> dict[str, int]:
    """One round of clone / split / prune; resets ``stats``. Returns the counts of each action.

    Gaussians larger than ``prune_scale`` x ``extent`` are pruned only with ``prune_large`` (as
    gsplat: after the first opacity reset), since the initial kNN scales of far, sparse points are
    legitimately large."""
    n = len(gaussians)
    if n == 0:
        return {"cloned": 0, "split": 0, "pruned": 0}
    params = {name: gaussians.params[name].detach() for name in gaussians.names}
    grow = stats.average().to(params["means"].device) > config.grad_threshold
    # Room left under the cap: the strongest gradients first.
    room = max(config.max_gaussians - n, 0)
    if int(grow.sum()) > room:
        order = torch.argsort(stats.average(), descending=True)[:room]
        grow = torch.zeros_like(grow)
        grow[order.to(grow.device)] = True
    largest = torch.exp(params["log_scales"]).max(dim=-1).values
    clone = grow & (largest <= config.clone_max_scale * extent)
    split = grow & ~clone
    new_rows = {name: value[clone] for name, value in params.items()}
    if split.any():
        children = split_samples({name: value[split] for name, value in params.items()}, generator)
        new_rows = {name: torch.cat([new_rows[name], children[name]], dim=0) for name in params}
    # Split parents leave; transparent and huge Gaussians are pruned.
    opacity = torch.sigmoid(params["opacity_logits"])
    prune = opacity < config.prune_opacity
    if prune_large:
        prune |= largest > config.prune_scale * extent
    keep = ~(split | prune)
    keep_rows(gaussians, optimizer, keep)
    if len(new_rows["means"]):
        append_rows(gaussians, optimizer, new_rows)
    stats.reset(len(gaussians))
    return {"cloned": int(clone.sum()), "split": int(split.sum()), "pruned": int((prune & ~split).sum())}


@torch.no_grad()
def reset_opacities(gaussians: GaussianSet, optimizer: torch.optim.Optimizer, value: float) -> None:
    """Clamp every opacity to at most ``value`` (and zero its Adam moments), as 3DGS does."""
    logit = math.log(value) - math.log1p(-value)

    def edit(name: str, t: Tensor, moment: bool) -> Tensor:
        if name != "opacity_logits":
            return t.clone()
        return torch.zeros_like(t) if moment else t.clamp(max=logit)

    edit_rows(gaussians, optimizer, edit)
