"""What a removed actor leaves: the static layer, and the pixels of it no training frame saw.

A pixel of a rendered view counts as **never observed** when the static surface there (the static
layer's expected depth, back-projected) was visible in no training frame: in each training camera it
falls outside the image, behind a nearer static surface (its depth there differs from the static render's
by more than ``DEPTH_TOLERANCE``), or under a dynamic object of that frame (the full render's dynamic
weight above 0.5 there). So does a surface a dynamic object hid in at least ``HIDDEN_SHARE`` of the
training frames it was in view in (in the image, at the same depth): the road behind a followed car,
glimpsed in a frame or two where the car's edge is thin, holds the car's dark residue, not the road.
Pixels where the static layer holds next to nothing (alpha below 0.5: the sky map shows through where
road should be) count as never observed too.

The sky map has the same blind spots: the sky behind a car the ego follows is seen in no frame, and the
texels there learn the car's colours through its not quite opaque Gaussians (on realistic tuning seed
103 the removed lead car left a sky patch at 0.3-0.6 where the sky is 0.8). :func:`background_sky`
gives every texel that training pixels free of dynamic objects did not fit the colour of the nearest
texel they did.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Relative and absolute depth tolerance (fraction of the depth, metres) for "the same surface". Wide,
# because the test compares the static layer's own depths, and a short training's static geometry is
# rough: on the hard tuning seeds 214 / 218 (600 iterations) 23 % of its depths near movers are within
# 10 % of the truth. At (0.05, 0.3 m) the mask marked 22 % / 47 % of the pixels under removed movers
# where the generator's geometry says 10 % / 2.6 % were never seen; (0.2, 1 m) marks 15 % / 14 % and
# has the best agreement with the truth (F1 0.64 / 0.21; 0.52 / 0.10 before, 0.64 / 0.20 at (0.3, 1.5 m)).
DEPTH_TOLERANCE = (0.2, 1.0)
STATIC_ALPHA = 0.5
DYNAMIC_WEIGHT = 0.5
# On the tuning runs (repaired sky, Telea 7) marking surfaces hidden in >= 90 % of their frames raised the
# filled PSNR under removed movers by 0.54 dB (realistic 101-105; +2.0 on 103, whose lead car left a dark
# copy on the road) and 0.19 dB (hard 214-216), no run worse by more than 0.09; at 80 %, -0.39 dB on 214.
# Counting a surface as unseen below 2 / 3 / 5 seeing frames instead cost up to 0.7 / 1.0 / 2.0 dB.
HIDDEN_SHARE = 0.9
# Telea inpainting's neighbourhood (pixels) for never-observed pixels. On the tuning runs (sky repaired)
# radius 7 scored 0.27 dB (realistic 101-105) and 0.21 dB (hard 214-216) above radius 3 under removed
# movers, every run higher; Navier-Stokes at 3 or 7 was no better than Telea at 3, 11 and 15 no better than 7.
FILL_RADIUS = 7
# A sky texel whose fit came less than half from pixels with no dynamic object in front holds what was
# in front of it instead.
SKY_CLEAN_SHARE = 0.5


@dataclass
class TrainingView:
    """One training frame as the model renders it: ``world_to_camera`` (4, 4), ``K`` (3, 3), static-only
    ``depth`` (H, W) metres (NaN where the static alpha is low) and the full render's ``dynamic`` (H, W)."""

    world_to_camera: np.ndarray
    K: np.ndarray
    depth: np.ndarray
    dynamic: np.ndarray


def training_visibility(run, scale: float = 0.5) -> list[TrainingView]:
    """Render ``run``'s training frames at ``scale`` (static layer alone, and everything) once."""
    import torch

    from radar4dgs.io.scene import normalized_times
    from radar4dgs.model.view import frame_view

    times = normalized_times(run.scene)
    out = []
    for i in run.scene.train_indices:
        view = frame_view(run.scene, i, scale, times)
        with torch.no_grad():
            static = run.model.render(view, run.config.raster, include_dynamic=False)
            full = run.model.render(view, run.config.raster)
        alpha = static["alpha"].double().cpu().numpy()
        depth = np.where(alpha >= STATIC_ALPHA, static["depth"].double().cpu().numpy(), np.nan)
        out.append(TrainingView(np.asarray(view.world_to_camera), np.asarray(view.K), depth,
                                full["dynamic"].double().cpu().numpy()))
    return out


def backproject(depth: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(P, 3) world points of ``pixels`` (P, 2) integer (row, col) at z-``depth`` (H, W) of a camera with
    intrinsics ``K`` (3, 3) (pixel centres at integers) and pose ``world_to_camera`` (4, 4)."""
    rows, cols = pixels[:, 0], pixels[:, 1]
    z = depth[rows, cols]
    cam = np.stack([(cols - K[0, 2]) / K[0, 0] * z, (rows - K[1, 2]) / K[1, 1] * z, z], axis=1)
    R, t = world_to_camera[:3, :3], world_to_camera[:3, 3]
    return (cam - t) @ R


def seen_in(points: np.ndarray, view: TrainingView, tolerance: tuple[float, float] | None = None) -> np.ndarray:
    """(P,) bool: world ``points`` (P, 3) visible, unoccluded, in the training ``view``: inside its image,
    at its depth there within ``tolerance`` (relative, metres; ``DEPTH_TOLERANCE`` when None) and not under a
    dynamic object."""
    seen, _ = seen_or_hidden_in(points, view, tolerance)
    return seen


def seen_or_hidden_in(points: np.ndarray, view: TrainingView,
                      tolerance: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(seen, hidden)``, each (P,) bool: world ``points`` (P, 3) inside the training ``view``'s image at its
    depth there (within ``tolerance``, as :func:`seen_in`), with no dynamic object in front (seen) or under
    one (hidden)."""
    relative, absolute = DEPTH_TOLERANCE if tolerance is None else tolerance
    cam = points @ view.world_to_camera[:3, :3].T + view.world_to_camera[:3, 3]
    z = cam[:, 2]
    height, width = view.depth.shape
    safe = np.where(z > 1e-3, z, 1.0)
    u = np.round(view.K[0, 0] * cam[:, 0] / safe + view.K[0, 2]).astype(np.int64)
    v = np.round(view.K[1, 1] * cam[:, 1] / safe + view.K[1, 2]).astype(np.int64)
    inside = (z > 0.1) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    seen, hidden = np.zeros(len(points), dtype=bool), np.zeros(len(points), dtype=bool)
    ui, vi, zi = u[inside], v[inside], z[inside]
    there = view.depth[vi, ui]
    same = np.abs(there - zi) <= relative * zi + absolute
    under = view.dynamic[vi, ui] >= DYNAMIC_WEIGHT
    seen[inside] = same & ~under
    hidden[inside] = same & under
    return seen, hidden


def never_observed_mask(run, view, region: np.ndarray, visibility: list[TrainingView]) -> np.ndarray:
    """(H, W) bool: the pixels of ``region`` (H, W) bool in ``view`` whose static surface no training
    frame of ``visibility`` saw, or dynamic objects hid in most of them (:func:`never_seen`, module docstring)."""
    import torch

    with torch.no_grad():
        static = run.model.render(view, run.config.raster, include_dynamic=False)
    alpha = static["alpha"].double().cpu().numpy()
    depth = static["depth"].double().cpu().numpy()
    never = region & (alpha < STATIC_ALPHA)
    pixels = np.argwhere(region & (alpha >= STATIC_ALPHA))
    if len(pixels) == 0:
        return never
    unseen = never_seen(backproject(depth, np.asarray(view.K), np.asarray(view.world_to_camera), pixels), visibility)
    never[pixels[unseen, 0], pixels[unseen, 1]] = True
    return never


def never_seen(points: np.ndarray, visibility: list[TrainingView], hidden_share: float = HIDDEN_SHARE) -> np.ndarray:
    """(P,) bool: world ``points`` (P, 3) that no training frame of ``visibility`` saw, or that a dynamic
    object hid in at least ``hidden_share`` of the frames they were in view in."""
    seen, hidden = np.zeros(len(points), dtype=np.int64), np.zeros(len(points), dtype=np.int64)
    for training in visibility:
        seen_here, hidden_here = seen_or_hidden_in(points, training)
        seen += seen_here
        hidden += hidden_here
    return (seen == 0) | (hidden >= hidden_share * (seen + hidden))


def fill_never_observed(rgb: np.ndarray, never: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 ``rgb`` with the ``never`` (H, W) bool pixels inpainted from their surroundings
    (OpenCV's Telea method, ``FILL_RADIUS``); ``rgb`` itself when none is set."""
    import cv2

    if not never.any():
        return rgb
    return cv2.inpaint(rgb, never.astype(np.uint8), FILL_RADIUS, cv2.INPAINT_TELEA)


def sky_fit_weights(sky, directions, clean, sky_share) -> tuple:
    """How much the pixels of one training frame fit each texel of ``sky`` (a
    :class:`~radar4dgs.model.sky.SkyEnvironment` with T texels): ``(clean, total)``, each (T,) float64.
    ``directions`` (H, W, 3) world rays, ``clean`` (H, W) bool pixels with nothing dynamic in front,
    ``sky_share`` (H, W) the sky's part of each rendered pixel (1 - alpha), which scales its gradient."""
    import torch

    device = sky.logits.device
    index, weights = sky.texel_weights(torch.as_tensor(directions, device=device))
    weights = weights.double() * torch.as_tensor(np.asarray(sky_share, dtype=np.float64), device=device).reshape(1, -1)
    texels = sky.height * sky.width
    kw = {"dtype": torch.float64, "device": device}
    total = torch.zeros(texels, **kw).index_add_(0, index.reshape(-1), weights.reshape(-1))
    kept = torch.as_tensor(np.asarray(clean, dtype=bool), device=device).reshape(1, -1).expand_as(weights)
    clean_sum = torch.zeros(texels, **kw).index_add_(0, index[kept], weights[kept])
    return clean_sum.cpu().numpy(), total.cpu().numpy()


def trusted_texels(clean: np.ndarray, total: np.ndarray, share: float = SKY_CLEAN_SHARE) -> np.ndarray:
    """(T,) bool: texels fitted at all (``total`` (T,) > 0) and at least ``share`` of it by ``clean`` (T,)
    pixels (:func:`sky_fit_weights` summed over the frames)."""
    return (total > 0) & (clean >= share * total)


def repaired_sky(sky, trusted: np.ndarray):
    """A copy of ``sky`` in which every texel outside ``trusted`` (H, W) bool takes the colour of the
    nearest trusted texel (``sky`` itself when none is trusted). The distance ignores the longitude wrap:
    the sky a camera sees spans far less than the map."""
    import copy

    import torch
    from scipy.ndimage import distance_transform_edt

    if trusted.all() or not trusted.any():
        return sky
    rows, cols = distance_transform_edt(~trusted, return_distances=False, return_indices=True)
    out = copy.deepcopy(sky)
    device = sky.logits.device
    with torch.no_grad():
        out.logits.copy_(sky.logits[:, torch.as_tensor(rows, device=device), torch.as_tensor(cols, device=device)])
    return out


def background_sky(run, scale: float = 1.0):
    """``run``'s sky map with the texels that dynamic objects fitted repaired (:func:`repaired_sky`): a
    texel is trusted when at least ``SKY_CLEAN_SHARE`` of its fit over the training frames (rendered at
    ``scale``) came from pixels outside the prepared dynamic masks (``prepared/masks``, when there) where
    the full render has no dynamic object either. The sky mask is not used: the sky map also holds the
    far background (beyond the initial points' depth), which that mask does not call sky."""
    import torch

    from radar4dgs.io.scene import normalized_times, read_mask_png
    from radar4dgs.model.sky import camera_ray_directions
    from radar4dgs.model.view import frame_view, resize_nearest

    scene, sky = run.scene, run.model.sky
    times = normalized_times(scene)
    shape = (scene.camera.height, scene.camera.width)
    masks = run.prepared / "masks"
    masks = masks if masks.is_dir() else None
    clean_sum = np.zeros(sky.height * sky.width)
    total = np.zeros(sky.height * sky.width)
    for i in scene.train_indices:
        view = frame_view(scene, i, scale, times)
        # The render's own rays, computed once here: the sky fit is measured along them.
        directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width,
                                           device=sky.logits.device, dtype=sky.logits.dtype)
        with torch.no_grad():
            full = run.model.render(view, run.config.raster, directions=directions)
        clean = full["dynamic"].cpu().numpy() < DYNAMIC_WEIGHT
        if masks is not None:
            mask = read_mask_png(masks / f"{scene.frames[i].name}.png", shape)
            clean &= ~resize_nearest(mask, (view.width, view.height))
        c, t = sky_fit_weights(sky, directions, clean, 1.0 - full["alpha"].double().cpu().numpy())
        clean_sum += c
        total += t
    return repaired_sky(sky, trusted_texels(clean_sum, total).reshape(sky.height, sky.width))
