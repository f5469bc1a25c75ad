"""The standalone motion fit's configuration (``radar4dgs fit-motion``): the deformation field, the
flow it is fitted to and the optimisation. Torch-free, so the CLI parses options without torch."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar, Literal, Mapping

from radar4dgs.model.config import FieldConfig
from radar4dgs.motion.config import FlowConfig


@dataclass
class FitConfig:
    """Optimisation of the standalone deformation-field fit."""

    # lambda: weight of L_rad (metres, absolute) against L_flow (m^2, squared). Doppler measures the
    # line-of-sight motion far better than depth-lifted flow does, so it should win that component:
    # on synthetic small seed 1, dynamic EPE 0.197 m at 0.05 and 0.161 m at 0.5 (pixels only); with
    # the radar returns as points too (seeds 1 / 4): 0.168 / 0.191 m at 0.5, 0.144 / 0.174 at 1,
    # 0.146 / 0.188 at 2 (chosen on those two benchmark seeds; held-out seeds 6-8 in docs/guide.md).
    # A 5 m gate instead of 2 m: 0.151 / 0.184 at 1.
    radar_weight: float = 1.0
    # Association gate (m): a point takes the Doppler of its nearest dynamic radar point only if
    # that point is this close (radar positions are noisy by ~1 deg in azimuth: 0.5 m at 30 m).
    radar_gate: float = 2.0
    # Where dynamic radar points and compensated Doppler come from: "prepared" =
    # <prepared>/radar/<frame>.npz (the radar front end); "oracle" = gt/radar_labels and the
    # scene's ego velocity.
    radar_source: Literal["prepared", "oracle"] = "prepared"
    # Dynamic pixels per frame lifted as radar-supervised points (0 = all).
    radar_points_per_frame: int = 2000
    # Also supervise the field at the dynamic radar points themselves (their own position and
    # Doppler; an addition to the paper, whose L_rad covers dynamic Gaussians only): a car the
    # masks miss, or one too small and far for its depth to lift (an oncoming car 60-100 m away), still
    # has radar returns with an exact range. Synthetic small seeds 1-5, both terms, radar_weight
    # 0.5: dynamic EPE 0.176/0.171/0.174/0.222/0.125 m without, 0.168/0.158/0.160/0.191/0.118 m with.
    radar_returns_as_points: bool = True
    # Velocity term L_vel (metrics.losses; issue 21, 3b): the returns of each radar object of
    # <prepared>/radar/objects.json (radar_source "oracle": the generator's objects and velocities)
    # must move by the object's tracked planar velocity times dt. It sees motion across the line of
    # sight where optical flow failed (a fast object) and Doppler cannot. Off without objects.json.
    # Realistic-traffic tuning seeds 101-105 (benchmarks/motion.py, both terms, fit seeds 0 and 1
    # averaged): dynamic EPE 0.254/0.214/0.244/0.191/0.865 m without, 0.130/0.112/0.142/0.136/0.749
    # with (seed 105: a pedestrian at 9 m EPE either way, no radar object of its own).
    velocity: bool = True
    # Weight of L_vel (Huber of a Mahalanobis distance, dimensionless) against L_flow (m^2). Tuning
    # seeds 101-104 (fit seed 0), mean EPE: 0.157 at 0.01, 0.137 at 0.03, 0.136 at 0.1, 0.135 at
    # 0.3, 0.170 at 1 (0.221 without); 0.1 sits in the middle of the flat part.
    velocity_weight: float = 0.1
    # Objects with fewer returns in a frame are not used: 2-3 returns rarely span enough azimuth.
    velocity_min_returns: int = 3
    # Objects whose velocity std sqrt(trace S) (m/s) exceeds this are not used: a radial-only
    # fallback carries 10 m/s across the line of sight, a fresh track a few m/s.
    velocity_max_std: float = 1.0
    # s0 (m): floor of the displacement std, added to S dt^2 (the field's smoothness, a turning
    # car's omega x r dt, the radar's timing).
    velocity_position_std: float = 0.05
    # Huber threshold on the Mahalanobis distance (standard deviations): beyond it a point pulls
    # with a constant force, so a wrong track cannot dominate (3: the same EPE on the tuning seeds).
    velocity_huber: float = 1.0
    # Weight of L_acc (m^2; train.path_prior) against L_flow: the field's paths of the observed moving points
    # (flow pairs, radar points) bent near the time they were seen; 0 = off. The trainer's pre-fit of hard
    # tuning seeds 229 / 230 (1 000 iterations): scene-flow error 0.198 / 0.065 m at 0, 0.168 at 0.3, 0.163 /
    # 0.045 at 1, 0.165 at 3 (on 229).
    acceleration_weight: float = 0.0
    # How many frame steps either side of the time a point was seen its path is checked.
    acceleration_reach: float = 2.0
    # Also give each object's velocity to the dynamic pixels of frame i (lifted with depth_source,
    # radar_points_per_frame at most) whose nearest object return is within radar_gate: "off";
    # "no_flow" only for objects with fewer than velocity_flow_pairs flow pairs starting within
    # radar_gate of their returns (a fast object whose optical flow failed); "all". Tuning seeds
    # 101-105, fit seeds 0 and 1, mean EPE: 0.273 m off, 0.254 no_flow; all (seed 0): 0.309.
    velocity_pixels: Literal["off", "no_flow", "all"] = "no_flow"
    # An object with at least this many flow pairs near its returns counts as covered by L_flow.
    velocity_flow_pairs: int = 20
    # Adam iterations.
    iterations: int = 1000
    # Points per term per iteration (flow pairs and radar points are drawn separately).
    batch_size: int = 1024
    # Adam learning rate at the start.
    learning_rate: float = 3e-3
    # The learning rate decays exponentially to learning_rate * this at the last iteration.
    final_learning_rate_ratio: float = 0.05
    # Seed of the point subsampling and the minibatch draws.
    seed: int = 0
    # Torch intra-op threads during the fit (restored after it); 0 leaves torch's setting. The
    # field's matmuls are small (batch x 64 x 64): on a shared CPU extra threads mostly spin, and
    # we measured 2 threads 5-20x slower than 1 on 2 busy cores.
    threads: int = 1
    # Torch device of the fit ("cpu", "cuda", ...).
    device: str = "cpu"
    # Precision of the field during the fit.
    dtype: Literal["float32", "float64"] = "float32"

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        "tiny": {"iterations": 200, "batch_size": 512, "radar_points_per_frame": 500},
        "small": {},
        "paper": {"iterations": 5000, "batch_size": 8192, "radar_points_per_frame": 10000},
    }


@dataclass
class MotionConfig:
    """Everything the standalone motion fit needs: the field, the pseudo scene flow, the fit."""

    # Sizes of the invertible deformation field.
    field: FieldConfig = dataclasses.field(default_factory=FieldConfig)
    # Optical flow and lifting (used when <prepared>/flow is missing or recomputed).
    flow: FlowConfig = dataclasses.field(default_factory=FlowConfig)
    # Optimisation.
    fit: FitConfig = dataclasses.field(default_factory=FitConfig)

    PRESETS: ClassVar[Mapping[str, Mapping[str, Any]]] = {
        name: {"field": dict(FieldConfig.PRESETS[name]), "flow": dict(FlowConfig.PRESETS[name]),
               "fit": dict(FitConfig.PRESETS[name])} for name in ("tiny", "small", "paper")}
