"""Test-view alignment of a run that refined its training poses (issue 27).

A run that learned pose corrections renders its training frames at the corrected poses; its
test frames have only their recorded poses, which carry the same odometry error the training
poses had. Two ways the field aligns them, both reported in ``metrics.json`` beside the plain
score at the recorded pose:

- ``interpolated``: each test camera put on the refined training trajectory at its time
  (:func:`smoothed_poses`: the centre from a smoothing spline of the corrected training cameras'
  centres over time, the orientation likewise); no image of the test frame is used, nor its
  recorded pose, which carries the odometry's own noise. Linear interpolation of the two
  neighbours' corrections, applied to the recorded test pose, did worse than no alignment where
  the pose noise is independent per frame (synthetic tiny seed 2: 22.9 against 24.6 dB): the
  neighbours' corrections undo THEIR noise, not the test frame's; and the trajectory is where the
  scene was fitted (its mean included), which the recorded test pose is not.
- ``optimised``: starting from the interpolated pose, a short Adam optimisation of the test
  frame's pose alone (an SE(3) correction, the scene frozen) against the test image's L1, as
  BARF / NeRF-- evaluate; ``poses.test_steps`` steps at ``poses.test_lr`` (rotation a tenth).
  It uses the test image, so it measures the scene, not the pose the run would predict.

Exposure is aligned separately, for every run (:func:`exposure_aligned`): a run that learned
per-frame colour transforms keeps its scene at the training frames' mean exposure, which no
training image can pin to the test frames' (a gauge freedom, as the pose mean is for poses), so
the field scores such runs with a colour transform fitted to each test image (NeRF-W fits its
appearance code on half the test image and scores the other half).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from radar4dgs.metrics.image import summarize_frames
from radar4dgs.model.pose_refine import corrected_directions, se3_exp, smoothed_poses
from radar4dgs.model.run import POSES_FILE, Run
from radar4dgs.model.sky import camera_ray_directions
from radar4dgs.model.view import View

ALIGNMENTS = ("interpolated", "optimised")
EXPOSURE_ALIGNMENT = ("per test frame, an affine colour transform (3x3 matrix and offset) fitted by least squares "
                      "on one half of the image (left or right columns) and applied to the other half, both ways, "
                      "so no pixel is scored through a transform fitted on itself; clamped to [0, 1]")


def _homogeneous(rgb: np.ndarray) -> np.ndarray:
    """(..., 4) ``rgb`` (..., 3) with a column of ones, for an affine map as one (4, 3) matrix."""
    return np.concatenate([rgb, np.ones(rgb.shape[:-1] + (1,))], axis=-1)


def _affine_fit(rgb: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(4, 3) least-squares affine map taking ``rgb`` (N, 3) to ``gt`` (N, 3); rank-deficient
    inputs (a flat half) get numpy's minimum-norm solution, not an error."""
    return np.linalg.lstsq(_homogeneous(rgb), gt, rcond=None)[0]


def exposure_aligned(rgb: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """``rgb`` (H, W, 3) in [0, 1] with each column half mapped by the affine colour transform
    fitted (least squares, toward ``gt`` (H, W, 3)) on the other half; (H, W, 3), clamped.

    Cross-fitting keeps a pixel's own value out of its transform: a render that is wrong in a way
    a colour transform cannot fix stays wrong, only a global exposure or white-balance offset is
    taken out. Hand-written: 12 parameters of ordinary least squares, which no metric library
    offers with this split."""
    width = rgb.shape[1]
    if width < 2:
        raise ValueError(f"exposure_aligned needs at least 2 columns, got an image of shape {tuple(rgb.shape)}")
    x = rgb.detach().double().cpu().numpy()
    y = gt.detach().double().cpu().numpy()
    half = width // 2
    out = np.empty_like(x)
    for fit, apply in ((slice(half, None), slice(None, half)), (slice(None, half), slice(half, None))):
        coef = _affine_fit(x[:, fit].reshape(-1, 3), y[:, fit].reshape(-1, 3))
        out[:, apply] = _homogeneous(x[:, apply]) @ coef
    return torch.as_tensor(np.clip(out, 0.0, 1.0), dtype=rgb.dtype, device=rgb.device)


def learned_corrections(run: Run) -> tuple[list[int], np.ndarray] | None:
    """(training frame indices, their (N, 4, 4) corrected world-to-camera) from ``RUN/poses.json``;
    None when the run did not refine its poses."""
    path = Path(run.root) / POSES_FILE
    if not path.is_file():
        return None
    payload = json.loads(path.read_text(encoding="utf-8"))
    if not payload.get("poses_refined"):
        return None
    frames = payload["frames"]
    return [int(f["index"]) for f in frames], np.array([f["world_to_camera"] for f in frames], dtype=np.float64)


def interpolated_view(view: View, train_times: np.ndarray, train_poses: np.ndarray) -> View:
    """``view`` moved onto the smoothed trajectory of the corrected training cameras ``train_poses``
    (N, 4, 4) at ``train_times`` (N,) (normalised, as ``view.time``), at its own time."""
    w2c = smoothed_poses(train_times, train_poses, np.array([view.time]))[0]
    return dataclasses.replace(view, world_to_camera=w2c)


def optimise_view(run: Run, view: View, image: torch.Tensor, steps: int, lr: float) -> tuple[View, dict[str, Any]]:
    """``view`` with its pose optimised against ``image`` (H, W, 3) in [0, 1] for ``steps`` Adam
    steps (translation rate ``lr`` m, rotation ``lr / 10`` rad), the model frozen. Returns the
    optimised view and ``{"l1_start", "l1_end", "translation_m", "rotation_deg"}``."""
    model = run.model
    device = image.device
    dtype = torch.float32
    start = torch.as_tensor(view.world_to_camera, dtype=dtype, device=device)
    directions = camera_ray_directions(view.K, view.world_to_camera, view.height, view.width, device=device,
                                       dtype=dtype)
    rho = torch.zeros(3, dtype=dtype, device=device, requires_grad=True)
    omega = torch.zeros(3, dtype=dtype, device=device, requires_grad=True)
    optimiser = torch.optim.Adam([{"params": [rho], "lr": lr}, {"params": [omega], "lr": lr / 10}])
    frozen = [p for p in model.parameters() if p.requires_grad]
    for p in frozen:
        p.requires_grad_(False)
    losses = []
    try:
        for _ in range(max(int(steps), 0)):
            delta = se3_exp(torch.cat([rho, omega]))
            moved = dataclasses.replace(view, world_to_camera=delta @ start)
            rgb = model.render(moved, run.config.raster, corrected_directions(directions, start, delta))["rgb"]
            loss = (rgb - image).abs().mean()
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            losses.append(float(loss.detach()))
    finally:
        for p in frozen:
            p.requires_grad_(True)
    with torch.no_grad():
        delta = se3_exp(torch.cat([rho, omega]))
        w2c = (delta.double() @ start.double()).cpu().numpy()
    info = {"l1_start": losses[0] if losses else None, "l1_end": losses[-1] if losses else None,
            "translation_m": float(rho.detach().norm()), "rotation_deg": math.degrees(float(omega.detach().norm()))}
    return dataclasses.replace(view, world_to_camera=w2c), info


def aligned_views(run: Run, view: View, image: torch.Tensor, train_times: np.ndarray, train_poses: np.ndarray
                  ) -> tuple[dict[str, View], dict[str, Any]]:
    """The test ``view`` under each of :data:`ALIGNMENTS`, and the optimisation's record."""
    interpolated = interpolated_view(view, train_times, train_poses)
    c = run.config.poses
    optimised, info = optimise_view(run, interpolated, image, c.test_steps, c.test_lr)
    return {"interpolated": interpolated, "optimised": optimised}, info


def alignment_record(run: Run) -> dict[str, Any]:
    """What ``metrics.json`` says about the alignment (``test_view_alignment``)."""
    c = run.config.poses
    return {"methods": list(ALIGNMENTS),
            "interpolated": "test camera on the refined training trajectory at its time: centre and orientation "
                            "from smoothing splines (weight by generalised cross-validation) through the corrected "
                            "training cameras",
            "optimised": f"from the interpolated pose, {c.test_steps} Adam steps (translation lr {c.test_lr} m, "
                         f"rotation lr {c.test_lr / 10} rad) of the test pose alone against the test image's L1, "
                         "the scene frozen",
            "nvs": "the plain nvs scores render the recorded test poses"}


def score_aligned(run: Run, view: View, image: torch.Tensor, train_times: np.ndarray, train_poses: np.ndarray,
                  score: Any, out: dict[str, list[dict]], name: str) -> None:
    """Append to ``out[alignment]`` the scores (``score(rgb)``, a dict) of test ``view`` rendered
    under each alignment, with the test-time optimisation's record on the "optimised" entry."""
    views, info = aligned_views(run, view, image, train_times, train_poses)
    for alignment, moved in views.items():
        with torch.no_grad():
            rgb = run.model.render(moved, run.config.raster)["rgb"].clamp(0, 1)
        entry = {"frame": name, **score(rgb)}
        if alignment == "optimised":
            entry["optimisation"] = info
        out.setdefault(alignment, []).append(entry)


def aligned_metrics(run: Run, aligned: dict[str, list[dict]]) -> dict[str, Any]:
    """``metrics.json``'s ``nvs_aligned`` (per alignment, the test frames' summary as ``nvs``'s)
    and ``test_view_alignment`` (:func:`alignment_record` and the per-frame entries)."""
    return {"nvs_aligned": {name: summarize_frames(entries) for name, entries in aligned.items()},
            "test_view_alignment": {**alignment_record(run), "per_frame": aligned}}
