"""Pose refinement's and exposure compensation's configuration (issue 27), nested in
:class:`radar4dgs.model.config.TrainConfig` as ``poses``; no torch, like the other configs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Mapping

# "auto": on for scenes whose poses come from odometry (scene.json's source says
# "poses_from_odometry" or "poses_from_radar": radar integration, `convert aimotive`), off for the
# rest (exact simulator poses); "on" / "off" force it. Pose refinement defaults to "auto": on
# synthetic scenes with odometry-sized pose noise it recovers 3 dB of novel-view PSNR, and on the
# one recorded clip measured (aiMotive night, tiny, the hood cut off) it is neutral (28.19 dB ->
# 28.13 at the recorded test poses, 28.27 with the test views optimised). Exposure compensation
# defaults to "off": on that clip it cost 0.3 dB (docs/pipeline/training.md).
RefineMode = Literal["auto", "on", "off"]


@dataclass
class PoseRefineConfig:
    """Pose refinement (a learned SE(3) correction per training frame) and exposure compensation
    (a learned per-frame affine colour transform), issue 27; radar4dgs.model.pose_refine and
    radar4dgs.model.appearance."""

    # Learn a camera pose correction per training frame: "auto" = when scene.json's source says the
    # poses come from odometry (poses_from_odometry / poses_from_radar, as `convert aimotive`).
    refine: RefineMode = "auto"
    # Adam rates of the corrections' translation (m) and rotation (rad) at the end of the warm-up,
    # decayed log-linearly to lr_final_ratio of themselves at the end of the run. Tuned on synthetic
    # tiny seed 1 with 0.10 m / 0.3 deg pose noise (benchmarks/poses.py, 600 iterations): 6e-3
    # left 0.069 m of translation error, 2e-3 0.079 m (0.110 m before); rotation 0.14 / 0.15 deg
    # (0.49 before).
    translation_lr: float = 6e-3
    rotation_lr: float = 2e-4
    lr_final_ratio: float = 0.1
    # Fraction of the run before the poses learn: the scene must look like something first.
    warmup: float = 0.2
    # Start the corrections at, and pull them toward, the correction that puts each training camera
    # on a smoothing spline of the recorded camera centres over time (its weight chosen by
    # generalised cross-validation; model.pose_refine.trajectory_target): a car's path is smooth at
    # 10 Hz, per-frame pose noise is not, and the images pin a camera's forward position poorly.
    # False: start at and pull toward the recorded poses.
    smooth_trajectory: bool = True
    # Weight of the mean squared difference of consecutive training frames' deviations from that
    # target (m^2 and rad^2): what the images add on top should drift smoothly.
    smooth_weight: float = 0.01
    # Weight of the mean squared deviation of the corrections from the target. Tuned on synthetic
    # tiny seed 1 (0.10 m / 0.3 deg noise, 600 iterations): the training cameras' translation error
    # 0.061 / 0.056 / 0.053 / 0.053 m at 0.01 / 0.1 / 0.3 / 1 (0.050 on the target alone, 0.110
    # recorded); novel-view PSNR flat within 0.3 dB. A frame's L1 is about 5x less sensitive to a
    # step along the optical axis than sideways, so a weight that holds the forward position
    # leaves the sideways one to the images.
    prior_weight: float = 0.3
    # After every step, subtract the mean deviation from the target over the frames (and the mean colour
    # transform): the refined trajectory keeps the recorded one's mean and the scene's colours are
    # the average frame's. Without it the whole trajectory drifted: synthetic tiny seed 2 with
    # noisy poses, 0.10-0.14 m between a refined run's frame and the exact test poses;
    # the aiMotive clip, every frame 0.1 m down and back and the colours 0.02 too bright.
    zero_mean: bool = True
    # Learn a per-frame affine colour transform (exposure, white balance) of the render before the
    # image loss: "auto" = on for recorded scenes (source dataset other than "synthetic"); "off" by default.
    appearance: RefineMode = "off"
    appearance_lr: float = 1e-3
    # Weight of the transform's mean squared deviation from the identity.
    appearance_weight: float = 0.01
    # Evaluation of a refined run: Adam steps and rate (translation m, rotation rate / 10) of the
    # test-time pose optimisation of each test view against its image, the scene frozen.
    test_steps: int = 40
    test_lr: float = 5e-3

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "tiny": {"test_steps": 20},
        "small": {},
        "paper": {"warmup": 0.1, "test_steps": 100, "test_lr": 2e-3},
    }

    def __post_init__(self) -> None:
        if not 0.0 <= self.warmup < 1.0:
            raise ValueError(f"poses.warmup must lie in [0, 1), got {self.warmup}")
        for name in ("translation_lr", "rotation_lr", "appearance_lr", "smooth_weight", "prior_weight",
                     "appearance_weight", "test_lr", "test_steps"):
            if getattr(self, name) < 0:
                raise ValueError(f"poses.{name} must be >= 0, got {getattr(self, name)}")
