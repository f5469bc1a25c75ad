"""``radar4dgs fit-motion SCENE``: the standalone fit of the VGPT deformation field."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, ClassVar, Optional

import tyro

from radar4dgs.apps.options import default_is
from radar4dgs.config import PresetName
from radar4dgs.train.config import MotionConfig


@dataclass
class FitMotionCommand:
    """Fit the invertible deformation field to a scene's prepared flow and radar; report the scene-flow error."""

    # The scene folder.
    scene: tyro.conf.Positional[Path]
    # The prepared folder (depth, masks, radar, flow).
    prepared: Annotated[Optional[Path], default_is("SCENE/prepared")] = None
    # Output folder for results.json, field.pt and config.json.
    out: Annotated[Optional[Path], default_is("PREPARED/motion")] = None
    # Supervise with the lifted optical flow (L_flow).
    use_flow: bool = True
    # Supervise with the radar's compensated Doppler (L_rad).
    use_radar: bool = True
    # Recompute <prepared>/flow even when it exists.
    recompute_flow: bool = False
    # Preset the config starts from.
    preset: PresetName = "small"
    # Field sizes, flow options and optimisation (filled from --preset).
    config: MotionConfig = field(default_factory=MotionConfig)
    # Hide the progress bars.
    quiet: bool = False

    PRESET_FIELDS: ClassVar[dict[str, type]] = {"config": MotionConfig}

    def run(self) -> int:
        from radar4dgs.evaluate.field_objects import ObjectErrors, format_objects
        from radar4dgs.io.scene import read_scene
        from radar4dgs.radar.sync import prepared_synced_scene
        from radar4dgs.train.fit_motion import run_fit, write_motion_outputs

        prepared = self.prepared if self.prepared is not None else self.scene / "prepared"
        out = self.out if self.out is not None else prepared / "motion"
        # A missing or malformed scene or prepared file raises a user error: one line (radar4dgs.cli).
        # The radar scans re-stamped by the clock offset prepare applied (radar4dgs.radar.sync).
        scene = prepared_synced_scene(read_scene(self.scene), prepared / "radar")
        by_object = ObjectErrors(scene)
        deformation, result = run_fit(scene, prepared, self.config, self.use_flow, self.use_radar,
                                      self.recompute_flow, evaluate=scene.has("gt/flow")
                                      and scene.has("gt/depth") and scene.has("gt/dynamic_mask"),
                                      progress=not self.quiet, on_pair=by_object.add)
        if result.get("sceneflow"):
            result["sceneflow_by_object"] = by_object.summary()
        write_motion_outputs(out, deformation, result, self.config)
        terms = " + ".join(name for name, on in (("flow", self.use_flow), ("radar", self.use_radar)) if on)
        print(f"fit ({terms}) in {result['fit_seconds']:.1f} s")
        metrics = result.get("sceneflow")
        if metrics and metrics.get("epe") is not None:
            print(f"dynamic scene-flow EPE {metrics['epe']:.3f} m over {metrics['points']} pixels of "
                  f"{metrics['pairs']} adjacent pairs (not moving: {metrics['zero_motion_epe']:.3f} m)")
            if result["sceneflow_by_object"]["objects"]:
                print("per moving object of the generator's truth:", *format_objects(result["sceneflow_by_object"]),
                      sep="\n")
        else:
            print("no gt/flow, gt/depth and gt/dynamic_mask: scene-flow error not evaluated")
        print(f"wrote {out / 'results.json'} and {out / 'field.pt'}")
        return 0
