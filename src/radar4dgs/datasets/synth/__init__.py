"""Procedural driving scenes with exact ground truth: ray-cast camera, 4D radar and lidar.

``synthesize(preset(SynthConfig, "small", seed=1), Path("scene"))`` writes a scene folder
(SCENE_FORMAT.md) with ``gt/`` and ``priors/``; ``radar4dgs synth OUT --preset small --seed 1``
does the same from the command line; ``--traffic realistic`` (``TrafficConfig.PROFILES``) gives
traffic that moves as fast across the image as real traffic at 10 Hz.
"""

from radar4dgs.datasets.synth.config import (
                                         LidarSimConfig,
                                         MonoPriorConfig,
                                         RadarReflectivity,
                                         RadarSimConfig,
                                         SynthConfig,
                                         TrafficConfig,
                                         traffic_profile,
)
from radar4dgs.datasets.synth.generate import synthesize

__all__ = ["LidarSimConfig", "MonoPriorConfig", "RadarReflectivity", "RadarSimConfig", "SynthConfig",
           "TrafficConfig", "synthesize", "traffic_profile"]
