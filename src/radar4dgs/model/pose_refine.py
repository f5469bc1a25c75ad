"""Camera pose refinement: a learned SE(3) correction per training frame (issue 27).

A correction ``xi = (rho, omega)`` (6,) lives in the Lie algebra se(3) of the CAMERA frame:
``rho`` (m) translates, ``omega`` (rad, axis times angle) rotates, and the corrected pose is

    world_to_camera' = exp(xi) @ world_to_camera

so a zero correction is the recorded pose, and a correction reads directly as "the camera sits
``rho`` metres and ``|omega|`` radians off, in its own axes". The same correction applies to the
sky's ray directions (:func:`corrected_directions`), so the sky map turns with the camera.

The trajectory prior: a car's path at 10 Hz is smooth, the noise of its recorded poses is not
(per-frame jitter), and the images pin a camera's forward position poorly (a 0.1 m step along the
optical axis changes a frame's L1 a fifth as much as one sideways). So the corrections start at,
and a prior (``prior``, mean squared deviation) pulls them toward, :func:`trajectory_target`: the
correction that puts each camera centre on a smoothing spline of the recorded centres over time
(scipy's ``make_smoothing_spline``, its weight chosen by generalised cross-validation, so a
recorded trajectory that is already smooth is kept and real turns are followed). ``smoothness``
(the mean squared difference of consecutive frames' deviations from that target) lets the images
add only a slowly varying correction (drift) on top. Without a target (all zeros) the prior pulls
toward the recorded poses.

Why a hand-written exponential: pytorch3d (which has ``se3_exp_map``) is not a dependency; the
closed form (Rodrigues for the rotation, the left Jacobian ``V`` for the translation) is a dozen
lines, with Taylor expansions near zero so that values and gradients stay finite there.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch
from scipy.interpolate import make_smoothing_spline
from scipy.spatial.transform import Rotation
from torch import Tensor, nn

# Below this angle (rad) the coefficients of the exponential use their Taylor series (to t^4:
# the next term is below 1e-9 here): ``(t - sin t) / t^3`` cancels all but a few float32 digits
# for small t (at 2e-3 rad a 1e-5 error in the translation).
SMALL_ANGLE = 0.05


def skew(v: Tensor) -> Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrices ``[v]_x`` (``[v]_x w = v x w``)."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    rows = (zero, -z, y, z, zero, -x, -y, x, zero)
    return torch.stack(rows, dim=-1).reshape(v.shape[:-1] + (3, 3))


def _coefficients(theta2: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``A = sin t / t``, ``B = (1 - cos t) / t^2``, ``C = (t - sin t) / t^3`` of ``t^2 = theta2``
    (any shape), with their Taylor series below :data:`SMALL_ANGLE`."""
    small = theta2 < SMALL_ANGLE ** 2
    # A safe angle where the closed form is not used, so its gradient is not NaN either.
    t2 = torch.where(small, torch.ones_like(theta2), theta2)
    t = t2.sqrt()
    a = torch.where(small, 1 - theta2 / 6 + theta2 ** 2 / 120, torch.sin(t) / t)
    # 1 - cos t = 2 sin^2(t / 2) keeps its digits where 1 - cos t would cancel.
    b = torch.where(small, 0.5 - theta2 / 24 + theta2 ** 2 / 720, 2 * torch.sin(t / 2) ** 2 / t2)
    c = torch.where(small, 1.0 / 6 - theta2 / 120 + theta2 ** 2 / 5040, (t - torch.sin(t)) / (t2 * t))
    return a, b, c


def so3_exp(omega: Tensor) -> Tensor:
    """(..., 3) axis-angle (rad) -> (..., 3, 3) rotation matrices (Rodrigues)."""
    a, b, _ = _coefficients((omega * omega).sum(-1))
    k = skew(omega)
    eye = torch.eye(3, dtype=omega.dtype, device=omega.device).expand(k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def se3_exp(xi: Tensor) -> Tensor:
    """(..., 6) twists ``(rho, omega)`` -> (..., 4, 4) rigid transforms ``[[R, V rho], [0, 1]]``
    with ``R = exp([omega]_x)`` and ``V = I + B [omega]_x + C [omega]_x^2``. ``se3_exp(0)`` is
    exactly the identity."""
    rho, omega = xi[..., :3], xi[..., 3:]
    a, b, c = _coefficients((omega * omega).sum(-1))
    k = skew(omega)
    kk = k @ k
    eye = torch.eye(3, dtype=xi.dtype, device=xi.device).expand(k.shape)
    rotation = eye + a[..., None, None] * k + b[..., None, None] * kk
    v = eye + b[..., None, None] * k + c[..., None, None] * kk
    top = torch.cat([rotation, (v @ rho[..., None])], dim=-1)
    bottom = torch.zeros(xi.shape[:-1] + (1, 4), dtype=xi.dtype, device=xi.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([top, bottom], dim=-2)


def apply_correction(xi: Tensor, world_to_camera: Tensor) -> Tensor:
    """The corrected (..., 4, 4) world-to-camera ``exp(xi) @ world_to_camera``; ``xi`` (..., 6)."""
    return se3_exp(xi) @ world_to_camera


def corrected_directions(directions: Tensor, world_to_camera: Tensor, delta: Tensor) -> Tensor:
    """(H, W, 3) world ray directions of the camera at ``world_to_camera`` (4, 4) turned to the
    corrected pose ``delta @ world_to_camera`` (``delta`` (4, 4), :func:`se3_exp`):
    ``d' = d + R_wc (dR^T - I) R_cw d``, written as a difference so that a zero correction
    returns ``directions`` bit for bit (``R_cw^T R_cw`` is not exactly I in float32)."""
    r_cw = world_to_camera[:3, :3]
    eye = torch.eye(3, dtype=delta.dtype, device=delta.device)
    change = r_cw.transpose(0, 1) @ (delta[:3, :3].transpose(0, 1) - eye) @ r_cw
    return directions + directions @ change.transpose(0, 1)


def smoothed_series(times: np.ndarray, values: np.ndarray, at: np.ndarray | None = None) -> np.ndarray:
    """(M, K) values at ``at`` (M,) (default ``times``) of a cubic smoothing spline per column
    through ``values`` (N, K) sampled at ``times`` (N,), its weight chosen by generalised
    cross-validation (scipy ``make_smoothing_spline``): independent noise is averaged out, a smooth
    series is kept. Fewer than 5 distinct times: linear interpolation, held at the ends."""
    times = np.asarray(times, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64).reshape(len(times), -1)
    at = times if at is None else np.asarray(at, dtype=np.float64)
    order = np.argsort(times, kind="stable")
    x, y = times[order], values[order]
    if len(x) < 5 or np.any(np.diff(x) <= 0):
        return np.stack([np.interp(at, x, y[:, j]) for j in range(y.shape[1])], axis=1)
    # One spline per column: each axis gets its own weight (along-track and sideways differ).
    return np.stack([make_smoothing_spline(x, y[:, j])(at) for j in range(y.shape[1])], axis=1)


def camera_centres(world_to_camera: np.ndarray) -> np.ndarray:
    """(N, 3) camera centres ``-R^T t`` of (N, 4, 4) world-to-camera poses."""
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    return -np.einsum("nji,nj->ni", w2c[:, :3, :3], w2c[:, :3, 3])


def trajectory_target(times: np.ndarray, world_to_camera: np.ndarray) -> np.ndarray:
    """(N, 6) corrections ``(rho, 0)`` that move each recorded camera (N, 4, 4) onto the smoothed
    trajectory of the camera centres over ``times`` (N,) (:func:`smoothed_series`), its orientation
    unchanged: with ``omega = 0`` the corrected centre is ``c - R^T rho``, so ``rho = -R (s - c)``."""
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    centres = camera_centres(w2c)
    smooth = smoothed_series(times, centres)
    rho = -np.einsum("nij,nj->ni", w2c[:, :3, :3], smooth - centres)
    return np.concatenate([rho, np.zeros_like(rho)], axis=1)


def smoothed_poses(train_times: np.ndarray, world_to_camera: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(M, 4, 4) world-to-camera poses at ``times`` (M,) on the smoothed trajectory through the
    (N, 4, 4) cameras at ``train_times`` (N,): the centre from :func:`smoothed_series` of the
    centres, the orientation from the same smoothing of the rotation vectors relative to the
    middle camera (a car turns by far less than 180 degrees in a clip)."""
    w2c = np.asarray(world_to_camera, dtype=np.float64)
    reference = Rotation.from_matrix(w2c[len(w2c) // 2, :3, :3])
    relative = (Rotation.from_matrix(w2c[:, :3, :3]) * reference.inv()).as_rotvec()
    rotations = (Rotation.from_rotvec(smoothed_series(train_times, relative, times)) * reference).as_matrix()
    centres = smoothed_series(train_times, camera_centres(w2c), times)
    out = np.tile(np.eye(4), (len(centres), 1, 1))
    out[:, :3, :3] = rotations
    out[:, :3, 3] = -np.einsum("nij,nj->ni", rotations, centres)
    return out


def pose_error(estimated: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) error of an estimated (4, 4) world-to-camera against the true
    one: the camera centres' distance and the angle of ``R_est R_true^T``."""
    centre_est = -estimated[:3, :3].T @ estimated[:3, 3]
    centre_true = -truth[:3, :3].T @ truth[:3, 3]
    relative = estimated[:3, :3] @ truth[:3, :3].T
    cosine = np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(centre_est - centre_true)), float(np.degrees(np.arccos(cosine)))


def correction_summary(corrections: np.ndarray) -> dict[str, float]:
    """Mean and max translation (m) and rotation (deg) of (N, 6) corrections."""
    corrections = np.asarray(corrections, dtype=np.float64).reshape(-1, 6)
    if len(corrections) == 0:
        return {"translation_mean_m": 0.0, "translation_max_m": 0.0, "rotation_mean_deg": 0.0,
                "rotation_max_deg": 0.0}
    t = np.linalg.norm(corrections[:, :3], axis=1)
    r = np.degrees(np.linalg.norm(corrections[:, 3:], axis=1))
    return {"translation_mean_m": float(t.mean()), "translation_max_m": float(t.max()),
            "rotation_mean_deg": float(r.mean()), "rotation_max_deg": float(r.max())}


class PoseCorrections(nn.Module):
    """The corrections of N training frames (rows in the order of the scene's ``train_indices``):
    ``translation`` (N, 3) m and ``rotation`` (N, 3) rad, two tensors so that Adam gives each its
    own rate (its step is about the rate whatever the gradient's scale). They start at ``target``
    (N, 6) (:func:`trajectory_target`; zeros when None: the recorded poses), which the regularisers
    keep them near."""

    def __init__(self, num_frames: int, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                 target: Any = None):
        super().__init__()
        target = torch.zeros(num_frames, 6) if target is None else torch.as_tensor(target).reshape(num_frames, 6)
        target = target.to(device=device, dtype=dtype)
        self.register_buffer("target", target)
        self.translation = nn.Parameter(target[:, :3].clone())
        self.rotation = nn.Parameter(target[:, 3:].clone())

    def __len__(self) -> int:
        return int(self.translation.shape[0])

    @property
    def xi(self) -> Tensor:
        """(N, 6) twists ``(rho, omega)``."""
        return torch.cat([self.translation, self.rotation], dim=1)

    def delta(self, row: int) -> Tensor:
        """(4, 4) ``exp(xi)`` of row ``row`` (differentiable)."""
        return se3_exp(torch.cat([self.translation[row], self.rotation[row]]))

    def corrected(self, row: int, world_to_camera: Any) -> Tensor:
        """The differentiable corrected (4, 4) world-to-camera of row ``row``."""
        w2c = torch.as_tensor(world_to_camera, dtype=self.translation.dtype, device=self.translation.device)
        return self.delta(row) @ w2c

    @torch.no_grad()
    def remove_mean(self) -> None:
        """Subtract the mean deviation from the target over the frames (in camera axes; the same
        axes for a straight drive, a first-order gauge for a turning one): the refined trajectory
        keeps the target's mean (the recorded one's: a smoothing spline's residuals sum to zero),
        as moving every camera and the scene together changes no image."""
        self.translation -= (self.translation - self.target[:, :3]).mean(0)
        self.rotation -= (self.rotation - self.target[:, 3:]).mean(0)

    def smoothness(self) -> Tensor:
        """Mean squared difference of consecutive rows' deviations from the target (0 for fewer
        than 2 rows)."""
        deviation = self.xi - self.target
        if len(deviation) < 2:
            return deviation.sum() * 0.0
        return ((deviation[1:] - deviation[:-1]) ** 2).sum(-1).mean()

    def prior(self) -> Tensor:
        """Mean squared deviation of the corrections from the target (pulls the poses the images
        pin poorly, such as the forward position, to the smoothed trajectory)."""
        return ((self.xi - self.target) ** 2).sum(-1).mean()

    def param_groups(self, translation_lr: float, rotation_lr: float) -> list[dict[str, Any]]:
        """Adam groups named ``poses.translation`` and ``poses.rotation``."""
        return [{"params": [self.translation], "lr": translation_lr, "name": "poses.translation"},
                {"params": [self.rotation], "lr": rotation_lr, "name": "poses.rotation"}]

    def state(self) -> dict[str, Tensor]:
        return {"translation": self.translation.detach().cpu(), "rotation": self.rotation.detach().cpu(),
                "target": self.target.detach().cpu()}

    @classmethod
    def from_state(cls, state: Mapping[str, Tensor], device: torch.device | str = "cpu",
                   dtype: torch.dtype = torch.float32) -> "PoseCorrections":
        """The corrections of :meth:`state` (a checkpoint without a target: zeros, as it was trained)."""
        out = cls(len(state["translation"]), device, dtype, state.get("target"))
        with torch.no_grad():
            out.translation.copy_(state["translation"].to(out.translation))
            out.rotation.copy_(state["rotation"].to(out.rotation))
        return out


def poses_from_odometry(source: Mapping[str, Any]) -> bool:
    """Whether a scene's ``source`` record says its poses come from odometry (``convert aimotive``
    integrates the radar's ego-motion and says ``poses_from_radar``; any converter or tool may say
    ``poses_from_odometry``)."""
    return bool(source.get("poses_from_odometry") or source.get("poses_from_radar"))


def refinement_switches(pose_mode: str, appearance_mode: str, source: Mapping[str, Any]) -> tuple[bool, bool]:
    """(pose refinement on, appearance compensation on) for a scene with ``source``: "on" / "off"
    as given; "auto" poses on for odometry poses, "auto" appearance on for recorded scenes (a
    source dataset other than "synthetic")."""
    poses = pose_mode == "on" or (pose_mode == "auto" and poses_from_odometry(source))
    recorded = str(source.get("dataset", "")) != "synthetic"
    appearance = appearance_mode == "on" or (appearance_mode == "auto" and recorded)
    return poses, appearance
