"""The methods the trainer can run, by name: the full method, the baselines and the ablations.

Each name maps to the :class:`TrainConfig` fields it changes on top of a preset; the same table
drives ``radar4dgs train --method NAME`` and the ``radar4dgs bench`` grid, so a cell of the
benchmark is exactly the run a user gets with that name. Everything not named here (the
initialisation, the masks, the iteration budget, the rasterizer) is shared by every method.
"""

from __future__ import annotations

from typing import Any, Literal, Mapping, get_args

from radar4dgs.config import PresetName, merge, preset

MethodName = Literal[
    "ours", "static", "deformable", "pvg", "bspline",
    "ours-no-radar", "ours-no-flow", "ours-field-only", "ours-no-dropout", "ours-no-depth",
    "ours-no-masks", "ours-no-lifespan", "ours-lidar-init", "ours-radar-masks", "ours-gt-masks",
]
METHOD_NAMES: tuple[str, ...] = get_args(MethodName)

# name -> (what it is, TrainConfig fields it sets).
VARIANTS: Mapping[str, tuple[str, Mapping[str, Any]]] = {
    "ours": ("static + dynamic Gaussians moved by the invertible field, L_flow + L_rad", {}),
    "static": ("3DGS with no dynamics", {"method": "static"}),
    "deformable": ("time-conditioned MLP offsets of every Gaussian (Deformable-GS style)",
                   {"method": "deformable"}),
    "pvg": ("periodic vibration Gaussians (PVG)", {"method": "pvg"}),
    "bspline": ("masked dynamic Gaussians on B-spline trajectories (AD-GS style)", {"method": "bspline"}),
    "ours-no-radar": ("ours without L_rad (flow only)", {"losses": {"radar_weight": 0.0}}),
    "ours-no-flow": ("ours without L_flow (radar only)", {"losses": {"flow_weight": 0.0}}),
    "ours-field-only": ("ours without L_flow and L_rad (the field learns from images only)",
                        {"losses": {"flow_weight": 0.0, "radar_weight": 0.0}}),
    "ours-no-dropout": ("ours without Gaussian dropout", {"optim": {"dropout": 0.0}}),
    "ours-no-depth": ("ours without the inverse-depth loss", {"losses": {"depth_weight": 0.0}}),
    "ours-no-masks": ("ours without the object and sky losses and the moving pixels' extra L1 weight",
                      {"losses": {"object_weight": 0.0, "sky_weight": 0.0, "dynamic_l1_weight": 0.0}}),
    "ours-no-lifespan": ("ours with dynamic Gaussians visible at every time (the paper's)",
                         {"dynamic_lifespan": 0.0}),
    "ours-lidar-init": ("ours initialised from LiDAR instead of radar-scaled depth",
                        {"init": {"source": "lidar"}}),
    "ours-radar-masks": ("ours with the non-learned radar baseline's masks", {"mask_source": "baseline"}),
    "ours-gt-masks": ("ours with ground-truth masks (oracle)", {"mask_source": "gt"}),
}


def variant_values(name: str) -> Mapping[str, Any]:
    """The TrainConfig fields method ``name`` sets; a ValueError lists the names for an unknown one."""
    if name not in VARIANTS:
        raise ValueError(f"unknown method {name!r}; methods are {list(METHOD_NAMES)}")
    return VARIANTS[name][1]


def apply_variant(config, name: str):
    """``config`` (a :class:`TrainConfig`) with the fields of method ``name`` set."""
    from radar4dgs.config import from_dict, to_dict
    from radar4dgs.model.config import TrainConfig

    return from_dict(TrainConfig, merge(to_dict(config), variant_values(name)), partial=False)


def variant_config(preset_name: PresetName, name: str, **overrides: Any):
    """The :class:`TrainConfig` of method ``name`` on preset ``preset_name``, with ``overrides``
    (nested dicts merged, as :func:`radar4dgs.config.preset`) applied before the method's own
    fields, so a method always is what its name says."""
    from radar4dgs.model.config import TrainConfig

    return apply_variant(preset(TrainConfig, preset_name, **overrides), name)
