"""How far the dynamic Gaussians sit from the true surface in the frames that saw them.

A car drawn by Gaussians 2 m behind it looks right from the training camera that saw it (they lie on
the same rays), but moves wrongly in the image between frames and from any other viewpoint: its
parallax is that of a farther object. Images alone hardly constrain depth along the rays, so this is
measured against the generator's true depth: each dynamic Gaussian, at the time of the training frame
nearest its life peak, is projected into that frame; where it lands on a true moving pixel, its camera
depth is compared with the true depth there. The prepared (radar-scaled) depth, which the depth term
pulls the Gaussians toward, is measured on the same pixels, so input error and training drift can be
told apart.

Counting Gaussians counts the faint and hidden ones as much as those that draw the car. What the images
show is the rendered (alpha-blended) depth: :func:`run_rendered_depth` compares it with the truth on
the same moving pixels, frame by frame.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from radar4dgs.evaluate.reconstruction import render_view
from radar4dgs.io.scene import Scene, normalized_times, read_json_file, read_scene
from radar4dgs.io.scene_files import OBJECT_DEPTH, prepared_depth_path
from radar4dgs.model.run import load_run
from radar4dgs.model.scene_model import load_model
from radar4dgs.model.view import frame_view
from radar4dgs.motion.flow import load_depth
from radar4dgs.motion.truth import project


def depth_errors_in_frame(points: np.ndarray, world_to_camera: np.ndarray, K: np.ndarray, depth: np.ndarray,
                          moving: np.ndarray) -> np.ndarray:
    """Relative depth errors ``(z - z_true) / z_true`` of the points that land on a moving pixel.

    Args:
        points: (N, 3) world positions at the frame's time.
        world_to_camera: (4, 4). K: (3, 3) pinhole intrinsics (pixel centres at integers).
        depth: (H, W) true z-depth (m). moving: (H, W) bool, the true dynamic mask.
    Returns:
        (M,) float64, M <= N: positive where a point lies behind the surface.
    """
    uv, z = project(np.asarray(points, dtype=np.float64), K, world_to_camera)
    front = z > 1e-6
    pixel = np.round(uv[front]).astype(np.int64)
    height, width = depth.shape
    inside = (pixel[:, 0] >= 0) & (pixel[:, 1] >= 0) & (pixel[:, 0] < width) & (pixel[:, 1] < height)
    pixel, z = pixel[inside], z[front][inside]
    return pixel_depth_errors(z, depth[pixel[:, 1], pixel[:, 0]], moving[pixel[:, 1], pixel[:, 0]])


def pixel_depth_errors(depth: np.ndarray, truth: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Relative errors ``(depth - truth) / truth`` on the moving pixels where both are finite and > 0.

    Args:
        depth, truth: z-depth (m), (H, W) images or (N,) samples. moving: bool, the same shape.
    Returns:
        (M,) float64: positive where ``depth`` is too far.
    """
    depth, truth = np.asarray(depth, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        on = moving.astype(bool) & np.isfinite(depth) & np.isfinite(truth) & (depth > 0) & (truth > 0)
    return (depth[on] - truth[on]) / truth[on]


def object_depth_metrics(scene: Scene, prepared_dir: str | Path, max_depth: float = np.inf) -> dict:
    """The prepared depth on the truly moving pixels (``gt/dynamic_mask``, ``gt/depth`` below
    ``max_depth``) before the object-depth stage (``<prepared>/depth``) and after it, pooled over every
    frame: ``mover_absrel_before`` / ``_after`` (median ``|d / d_true - 1|``), ``mover_bias_before`` /
    ``_after`` (median ``d / d_true - 1``: positive = too deep; None without such pixels),
    ``mover_pixels``, and the stage's ``objects`` and ``rescaled`` counts. The stage multiplies a
    finite positive depth by a positive scale, so both are scored on the same pixels."""
    prepared_dir = Path(prepared_dir)
    before, after = [], []
    for index, frame in enumerate(scene.frames):
        truth = scene.load_optional("gt/depth", index).astype(np.float64)
        moving = scene.load_optional("gt/dynamic_mask", index) & (truth < max_depth)
        before.append(pixel_depth_errors(np.load(prepared_dir / "depth" / f"{frame.name}.npy"), truth, moving))
        after.append(pixel_depth_errors(np.load(prepared_depth_path(prepared_dir, frame.name)), truth, moving))
    b, a = np.concatenate(before), np.concatenate(after)
    summary = read_json_file(prepared_dir / OBJECT_DEPTH / "summary.json")

    def median(x: np.ndarray) -> float | None:
        return float(np.median(x)) if len(x) else None

    return {"mover_absrel_before": median(np.abs(b)), "mover_absrel_after": median(np.abs(a)),
            "mover_bias_before": median(b), "mover_bias_after": median(a), "mover_pixels": int(len(b)),
            "objects": int(summary.get("objects", 0)), "rescaled": int(summary.get("rescaled", 0))}


def summarize(errors: np.ndarray, counted: str = "gaussians") -> dict:
    """``median`` relative error (signed), ``p90_abs`` (90th percentile of its size), ``behind``
    (share more than 10 % behind the surface) and, under ``counted``, how many were counted."""
    if len(errors) == 0:
        return {"median": None, "p90_abs": None, "behind": None, counted: 0}
    return {"median": float(np.median(errors)), "p90_abs": float(np.percentile(np.abs(errors), 90)),
            "behind": float(np.mean(errors > 0.1)), counted: int(len(errors))}


def _run_scene_with_depth_truth(root: Path) -> tuple[dict, Scene]:
    """A run's ``run.json`` paths and its scene; ValueError where the scene lacks ``gt/depth`` or
    ``gt/dynamic_mask``."""
    paths = json.loads((root / "run.json").read_text())
    scene = read_scene(paths["scene"])
    for name in ("gt/depth", "gt/dynamic_mask"):
        if not scene.has(name):
            raise ValueError(f"{scene.root}: no {name}, so no true depth of the movers to compare with")
    return paths, scene


@torch.no_grad()
def run_dynamic_depth(run_dir: str | Path) -> dict:
    """:func:`summarize` of a run's dynamic Gaussians against its synthetic scene's ``gt/depth`` and
    ``gt/dynamic_mask`` (each Gaussian at its nearest training frame). Raises ValueError for a run
    without dynamic Gaussians or a scene without that ground truth."""
    root = Path(run_dir)
    _, scene = _run_scene_with_depth_truth(root)
    model = load_model(root / "model.pt")
    if model.dynamic is None or len(model.dynamic) == 0 or not model.dynamic.has("tau"):
        raise ValueError(f"{root}: no dynamic Gaussians with life peaks (a baseline or static run?)")
    times = np.asarray(normalized_times(scene))
    frames = np.asarray(scene.train_indices)
    tau = model.dynamic.params["tau"].detach().double().cpu().numpy()
    nearest = frames[np.abs(tau[:, None] - times[frames][None, :]).argmin(axis=1)]
    errors = []
    for frame in np.unique(nearest):
        means = model.set_at("dynamic", float(times[frame]))["means"].double().cpu().numpy()[nearest == frame]
        errors.append(depth_errors_in_frame(means, scene.world_to_camera(int(frame)), scene.camera.K,
                                            scene.load_optional("gt/depth", int(frame)),
                                            scene.load_optional("gt/dynamic_mask", int(frame)) > 0))
    return summarize(np.concatenate(errors))


def run_prepared_depth(run_dir: str | Path) -> dict:
    """:func:`summarize` of the run's prepared depth on the true moving pixels of its training frames
    (its count under ``pixels``). Raises ValueError for a scene without that ground truth."""
    paths, scene = _run_scene_with_depth_truth(Path(run_dir))
    errors = [pixel_depth_errors(load_depth(scene, index, "prepared", paths["prepared"]),
                                 scene.load_optional("gt/depth", index),
                                 scene.load_optional("gt/dynamic_mask", index) > 0)
              for index in scene.train_indices]
    return summarize(np.concatenate(errors), counted="pixels")


@torch.no_grad()
def run_rendered_depth(run_dir: str | Path, device: str | None = None) -> dict:
    """:func:`summarize` of the run's rendered depth on the true moving pixels of its training frames
    (under ``pixels``), ``dynamic_share`` (the mean share of those pixels' blend weight the dynamic
    set draws: below 1, static Gaussians behind a car show through and pull its depth back), and
    ``by_frame``: each frame's ``frame`` index, ``median``, ``dynamic_share`` and ``pixels``.
    Raises ValueError for a scene without that ground truth."""
    root = Path(run_dir)
    _run_scene_with_depth_truth(root)
    run = load_run(root, device=device or "cpu")
    times = normalized_times(run.scene)
    errors, shares, by_frame = [], [], []
    for index in run.scene.train_indices:
        out = render_view(run, frame_view(run.scene, index, 1.0, times))
        truth = run.scene.load_optional("gt/depth", index)
        moving = run.scene.load_optional("gt/dynamic_mask", index) > 0
        frame_errors = pixel_depth_errors(out["depth"].double().cpu().numpy(), truth, moving)
        share = out["dynamic"].double().cpu().numpy()[moving]
        errors.append(frame_errors)
        shares.append(share)
        by_frame.append({"frame": int(index), "median": float(np.median(frame_errors)) if len(frame_errors) else None,
                         "dynamic_share": float(share.mean()) if len(share) else None,
                         "pixels": int(len(frame_errors))})
    share = np.concatenate(shares)
    return {**summarize(np.concatenate(errors), counted="pixels"),
            "dynamic_share": float(share.mean()) if len(share) else None, "by_frame": by_frame}
