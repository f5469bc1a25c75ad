"""The training loss of one iteration: its named terms, their weights and their weighted sum.

``(1 - l_r) L1 + l_r (1 - SSIM) + l_d L_invdepth + l_obj BCE(dyn, mask) [stage 3] + l_sky BCE(alpha,
not sky) + w_flow L_flow + w_rad L_rad + w_vel L_vel`` (the trainer's module docstring has the stages),
with ``losses.over_movers_weight`` the static Gaussians drawn over movers (``static_over_movers``), plus,
where the run refines poses or appearance, ``w_s L_pose_smooth + w_p L_pose_prior + w_a L_app``,
and with ``losses.dynamic_depth_weight`` a log-depth L1 on the dynamic-mask pixels where the image trains them.
With ``losses.dynamic_l1_weight`` w (ours only; the baselines keep their own plain L1) each dynamic-mask pixel
counts 1 + w times in L1; ``losses.dynamic_l1_dilation`` widens (or narrows) that mask by a few pixels.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from radar4dgs.metrics.image import ssim_loss_value
from radar4dgs.metrics.losses import (
    binary_cross_entropy,
    flow_loss,
    inverse_depth_l1,
    log_depth_l1,
    radar_loss,
    static_over_movers,
    velocity_loss,
)
from radar4dgs.model.config import TrainConfig
from radar4dgs.model.field import DeformationField
from radar4dgs.train.data import FrameTargets, MotionTargets
from radar4dgs.train.path_prior import path_loss


def image_losses(render: dict[str, Any], target: FrameTargets, config: TrainConfig, stage: int,
                 ignore_dynamic: bool) -> dict[str, Tensor]:
    """The image terms (unweighted) of one iteration. With ``ignore_dynamic`` (stage 1 of the full
    method) the dynamic-mask pixels of the target take the render's own (detached) colour, so they
    give neither L1 nor SSIM gradient, and they are left out of the depth term."""
    rgb, image = render["rgb"], target.image
    if ignore_dynamic:
        image = torch.where(target.dynamic[..., None], rgb.detach(), image)
    absolute_error = (rgb - image).abs()
    if config.losses.dynamic_l1_weight > 0 and config.method == "ours" and not ignore_dynamic:
        weighted = dilate(target.dynamic, config.losses.dynamic_l1_dilation)
        absolute_error = absolute_error * (1.0 + config.losses.dynamic_l1_weight * weighted[..., None])
    losses = {"l1": absolute_error.mean(), "ssim": 1.0 - ssim_loss_value(rgb, image)}
    depth_valid = ~target.sky & ~target.dynamic if ignore_dynamic else ~target.sky
    losses["depth"] = inverse_depth_l1(render["depth"], render["alpha"], target.depth, depth_valid)
    if config.losses.dynamic_depth_weight > 0 and not ignore_dynamic:
        losses["dynamic_depth"] = log_depth_l1(render["depth"], render["alpha"], target.depth,
                                               target.dynamic & ~target.sky)
    losses["sky"] = binary_cross_entropy(render["alpha"], ~target.sky)
    if config.losses.over_movers_weight > 0 and config.method == "ours":
        over = over_movers(render, target, config.losses.over_movers_margin)
        if over is not None:
            losses["over_movers"] = over
    if stage == 3:
        losses["object"] = binary_cross_entropy(render["dynamic"], target.dynamic)
    return losses


def dilate(mask: Tensor, radius: int) -> Tensor:
    """``mask`` (H, W) bool widened by ``radius`` pixels (a square max filter), narrowed by ``-radius`` where
    it is negative (the max filter of the complement); float (H, W)."""
    mask = mask.to(torch.float32)
    if radius == 0:
        return mask
    if radius < 0:
        return 1.0 - dilate(mask < 0.5, -radius)
    return torch.nn.functional.max_pool2d(mask[None, None], 2 * radius + 1, stride=1, padding=radius)[0, 0]


def over_movers(render: dict[str, Any], target: FrameTargets, margin: float) -> Tensor | None:
    """:func:`static_over_movers` of the render's static Gaussians (the first ``n_static`` of its
    rasterizer ``meta``) on the prepared mask and depth; None when they take no gradient (the static
    set frozen, as in stage 2, or none drawn)."""
    meta, n = render["meta"], render["n_static"]
    opacities = meta["opacities"][0, :n]
    if render["static_frozen"] or not opacities.requires_grad or n == 0:
        return None
    return static_over_movers(meta["means2d"][0, :n], meta["radii"][0, :n], meta["depths"][0, :n], opacities,
                              target.dynamic, target.depth, margin)


def image_phase(config: TrainConfig, stage: int, step: int) -> tuple[bool, bool]:
    """``(ignore_dynamic, detach_static)`` of iteration ``step`` of ``stage``: how its render is
    scored and what it trains. Stage 1 of the full method ignores the dynamic-mask pixels and
    stage 2 freezes the static Gaussians. In stage 3 with ``config.static_outside_masks`` odd
    iterations ignore the dynamic-mask pixels and even ones freeze the static Gaussians, so no
    dynamic-mask pixel ever gives a static Gaussian an image gradient; without it, neither. (Odd:
    densification runs after iterations ``k * densify.every - 1``, which must train the static set.)"""
    if config.method != "ours":
        return False, False
    if stage == 3 and config.static_outside_masks:
        return step % 2 == 1, step % 2 == 0
    return stage == 1, stage == 2


def motion_losses(deformation: DeformationField, motion: MotionTargets, batch: int,
                  generator: torch.Generator, device: torch.device, dtype: torch.dtype) -> dict[str, Tensor]:
    """``L_flow``, ``L_rad``, ``L_vel`` and ``L_acc`` (each when it has samples) on a random minibatch of
    the field's supervision; the draws are made in that order."""
    def draw(n: int) -> Tensor:
        return torch.randint(n, (min(batch, n),), generator=generator)

    def tensor(array: np.ndarray) -> Tensor:
        return torch.as_tensor(array, dtype=dtype, device=device)

    losses = {}
    if motion.flow is not None:
        f = motion.flow
        i = draw(len(f)).numpy()
        losses["flow"] = flow_loss(deformation, tensor(f.x_i[i]), tensor(f.x_j[i]), tensor(f.t_i[i]), tensor(f.t_j[i]))
    if motion.radar is not None:
        r = motion.radar
        i = draw(len(r)).numpy()
        losses["radar"] = radar_loss(deformation, tensor(r.x[i]), tensor(r.t_i[i]), tensor(r.t_j[i]),
                                     tensor(r.dt[i]), tensor(r.centre[i]), tensor(r.v_r[i]))
    if motion.velocity is not None:
        v = motion.velocity
        i = draw(len(v)).numpy()
        losses["velocity"] = velocity_loss(deformation, tensor(v.x[i]), tensor(v.t_i[i]), tensor(v.t_j[i]),
                                           tensor(v.dt[i]), tensor(v.velocity[i]), tensor(v.covariance[i]),
                                           motion.velocity_position_std, motion.velocity_huber)
    if motion.path is not None:
        losses["acceleration"] = path_loss(deformation, motion.path, draw(len(motion.path)), generator, dtype, device)
    return losses


def loss_weights(config: TrainConfig) -> dict[str, float]:
    """The weight of each named loss term (the keys are :data:`radar4dgs.model.run.LOSS_TERMS`)."""
    c = config.losses
    return {"l1": 1.0 - c.ssim_weight, "ssim": c.ssim_weight, "depth": c.depth_weight,
            "dynamic_depth": c.dynamic_depth_weight, "over_movers": c.over_movers_weight,
            "object": c.object_weight, "sky": c.sky_weight, "flow": c.flow_weight, "radar": c.radar_weight,
            "velocity": c.velocity_weight, "acceleration": c.acceleration_weight,
            "pose_smooth": config.poses.smooth_weight,
            "pose_prior": config.poses.prior_weight, "appearance": config.poses.appearance_weight,
            "actor_smooth": config.rigid_actors_smoothness, "actor_heading": config.rigid_actors_heading}


def total_loss(losses: dict[str, Tensor], config: TrainConfig) -> Tensor:
    """The weighted sum of the named terms (absent terms count 0)."""
    weights = loss_weights(config)
    return sum(weights[name] * value for name, value in losses.items())


def refinement_losses(poses: Any, appearance: Any) -> dict[str, Tensor]:
    """The regularisers of the pose corrections (``pose_smooth``, ``pose_prior``) and of the colour
    transforms (``appearance``: deviation from the identity), for the parts present (None = absent)."""
    losses = {}
    if poses is not None:
        losses["pose_smooth"] = poses.smoothness()
        losses["pose_prior"] = poses.prior()
    if appearance is not None:
        losses["appearance"] = appearance.regularizer()
    return losses
