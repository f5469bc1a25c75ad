"""Options of the procedural scene generator: one typed dataclass tree with named presets.

Every noise level is a field, so a test can set it to 0 and get exact data.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar


@dataclass
class RadarReflectivity:
    """Detection probability at normal incidence and close range, per material (0..1)."""

    vehicle: float = 0.9  # car bodies, cabins and wheels: strong metal returns
    building: float = 0.35  # facades and roofs
    pole: float = 0.8  # lamp posts: small but metallic
    trunk: float = 0.4  # tree trunks
    foliage: float = 0.12  # tree crowns: weak, diffuse
    sidewalk: float = 0.25  # sidewalk slabs and curb faces
    ground: float = 0.05  # asphalt and grass: seen at grazing angles, mostly invisible
    person: float = 0.3  # pedestrians and cyclists' riders: weak, soft returns
    bicycle: float = 0.6  # bicycle frames and wheels: thin metal


@dataclass
class RadarSimConfig:
    """A 4D imaging radar: ray casting on an azimuth/elevation grid, then detection and noise."""

    mount_xyz: tuple[float, float, float] = (3.6, 0.0, 0.5)  # position in the ego frame (m): front bumper
    # |yaw| and |pitch| mount error drawn in this range (deg), random sign; recorded exactly in radar_to_ego
    misalignment_deg: tuple[float, float] = (0.5, 1.0)
    azimuth_fov_deg: float = 120.0  # full horizontal field of view (deg)
    elevation_fov_deg: float = 20.0  # full vertical field of view (deg)
    azimuth_step_deg: float = 0.5  # ray grid spacing in azimuth (deg); each ray is jittered inside its cell
    elevation_step_deg: float = 1.0  # ray grid spacing in elevation (deg)
    max_range: float = 150.0  # no detections beyond this range (m)
    range_half: float = 70.0  # range at which the detection probability has fallen to one half (m)
    incidence_power: float = 0.5  # detection probability scales with |cos(incidence)| ** this
    reflectivity: RadarReflectivity = field(default_factory=RadarReflectivity)  # per-material detection
    max_points: int = 800  # true detections above this are subsampled at random
    range_std: float = 0.05  # Gaussian range noise (m)
    azimuth_std_deg: float = 0.3  # Gaussian azimuth noise (deg)
    elevation_std_deg: float = 1.0  # Gaussian elevation noise (deg)
    v_r_std: float = 0.08  # Gaussian Doppler noise (m/s)
    rcs_std_db: float = 2.0  # Gaussian noise on the rcs column (dB)
    clutter_fraction: float = 0.05  # expected clutter points per true detection (Poisson), label -1
    clutter_v_r_max: float = 15.0  # clutter Doppler drawn uniformly in +- this (m/s)
    ghost_count: int = 4  # at most this many multipath ghosts per frame (car points mirrored below the road), label -1


@dataclass
class LidarSimConfig:
    """A spinning lidar for `lidar/`: points in the ego frame with an intensity column."""

    mount_xyz: tuple[float, float, float] = (1.2, 0.0, 1.9)  # position in the ego frame (m): roof
    beams: int = 32  # number of laser rows
    elevation_range_deg: tuple[float, float] = (-25.0, 10.0)  # lowest and highest beam (deg)
    azimuth_step_deg: float = 0.4  # horizontal resolution over 360 deg (deg)
    max_range: float = 100.0  # returns beyond this are dropped (m)
    range_std: float = 0.02  # Gaussian range noise (m)
    intensity_std: float = 0.02  # Gaussian noise on the intensity column (0..1)


@dataclass
class MonoPriorConfig:
    """A Depth-Anything-like relative inverse depth `a / z * (1 + distortion + noise) + b`."""

    scale_range: tuple[float, float] = (10.0, 40.0)  # a, drawn once per scene
    shift_range: tuple[float, float] = (0.05, 0.5)  # b, drawn once per scene (the value of the sky)
    distortion: float = 0.05  # amplitude of the smooth multiplicative distortion (0.05 = +-5 %)
    noise_std: float = 0.01  # per-pixel multiplicative Gaussian noise
    # Gaussian blur of the prior, as a fraction of the image width (soft edges as a network's)
    blur_sigma: float = 0.003
    sky_jitter_px: int = 1  # the sky-mask prior grows or shrinks by up to this many pixels per frame


@dataclass
class TrafficConfig:
    """The moving objects. The defaults are the calm traffic of SynthConfig (``moving_cars``,
    ``crossing_probability``: a few cars moving a few pixels per frame), unchanged for every seed.

    The named profiles (``PROFILES``; ``radar4dgs synth --traffic realistic``) turn on traffic
    that moves tens to hundreds of pixels per frame, as real traffic at 10 Hz does: a lead car,
    a cut-in, oncoming and crossing cars passing close, pedestrians and cyclists. Those movers
    are drawn from their own random stream, in road-frame seconds and metres (any fps).
    """

    # keep the calm generator's parked and moving cars; False: parked cars (SynthConfig.parked_cars)
    # and the movers below, placed without overlaps
    calm_cars: bool = True
    # put the crossing road just ahead of the ego's last position (instead of 35-70 m beyond it)
    near_intersection: bool = False
    # gap from the ego's front bumper at the last frame to the crossing road's near edge (m)
    intersection_gap: tuple[float, float] = (0.5, 5.0)
    lead_probability: float = 0.0  # chance of a slower lead car in the ego lane that the ego closes in on
    lead_closing_speed: tuple[float, float] = (2.0, 6.0)  # ego speed minus lead speed (m/s)
    lead_gap_end: tuple[float, float] = (8.0, 40.0)  # lead car's gap ahead of the ego at the last frame (m)
    min_gap: float = 5.0  # nothing ahead of the ego in its lane comes closer than this (bumper to bumper, m)
    cut_in_probability: float = 0.0  # chance of a car changing from the adjacent lane into the ego lane
    cut_in_duration: tuple[float, float] = (2.0, 4.0)  # lane change duration (s), at most 0.8 of the sequence
    # fraction of the sequence at which the cut-in car crosses the lane line
    cut_in_time: tuple[float, float] = (0.3, 0.6)
    cut_in_gap: tuple[float, float] = (6.0, 14.0)  # its gap ahead of the ego when it crosses the lane line (m)
    cut_in_relative_speed: tuple[float, float] = (-2.0, 3.0)  # its speed minus the ego speed (m/s)
    oncoming_cars: tuple[int, int] = (0, 0)  # cars passing the ego in the oncoming lane next to it, inclusive
    oncoming_speed: tuple[float, float] = (8.0, 18.0)  # their speed (m/s)
    oncoming_pass: tuple[float, float] = (0.3, 0.85)  # fraction of the sequence at which one passes the camera
    crossing_cars: tuple[int, int] = (0, 0)  # cars crossing at the intersection, inclusive range
    crossing_speed: tuple[float, float] = (6.0, 14.0)  # their speed (m/s)
    # fraction of the sequence at which one crosses the ego lane's line (late: the ego is close)
    crossing_time: tuple[float, float] = (0.6, 1.2)
    pedestrians: tuple[int, int] = (0, 0)  # pedestrians crossing the road or walking along it, inclusive
    pedestrian_speed: tuple[float, float] = (1.0, 2.5)  # walking to running (m/s)
    cyclists: tuple[int, int] = (0, 0)  # cyclists along the road or across the intersection, inclusive
    cyclist_speed: tuple[float, float] = (3.0, 7.0)  # (m/s)
    attempts: int = 80  # random placements tried per mover before it is left out (overlaps, gaps)

    PROFILES: ClassVar[dict[str, dict[str, Any]]] = {
        "calm": {},
        "realistic": {"calm_cars": False, "near_intersection": True, "lead_probability": 1.0,
                      "cut_in_probability": 1.0, "oncoming_cars": (1, 2), "crossing_cars": (1, 2),
                      "pedestrians": (1, 2), "cyclists": (0, 1)},
        # Rush hour on a fast road: the realistic mix with more and faster oncoming and crossing
        # cars and a lead car closed in on quickly, so that most dynamic pixels belong to a close
        # mover crossing much of the image in a few frames (p90 of tens of px per frame at 320 px).
        "rush": {"calm_cars": False, "near_intersection": True, "lead_probability": 0.5,
                 "lead_closing_speed": (4.0, 9.0), "lead_gap_end": (15.0, 40.0),
                 "cut_in_probability": 1.0, "oncoming_cars": (2, 3), "oncoming_speed": (14.0, 25.0),
                 "crossing_cars": (1, 2), "crossing_speed": (10.0, 18.0),
                 "pedestrians": (1, 2), "cyclists": (1, 1)},
    }


def traffic_profile(name: str, base: TrafficConfig | None = None) -> TrafficConfig:
    """``base`` (default: calm) with profile ``name`` applied to the fields that hold their calm
    default, so explicit options (``--scene.traffic.oncoming-cars 3 3``) win over the profile."""
    if name not in TrafficConfig.PROFILES:
        raise ValueError(f"unknown traffic profile {name!r}; choose one of {list(TrafficConfig.PROFILES)}")
    base = base or TrafficConfig()
    calm = TrafficConfig()
    values = {f.name: v for f in fields(TrafficConfig) if (v := TrafficConfig.PROFILES[name].get(f.name)) is not None
              and getattr(base, f.name) == getattr(calm, f.name)}
    return replace(base, **values)


@dataclass
class SynthConfig:
    """The procedural driving-scene generator (``radar4dgs synth``)."""

    seed: int = 0  # layout, speeds, colours, textures and all noise draws
    width: int = 320  # image width (px)
    height: int = 180  # image height (px)
    num_frames: int = 50  # camera frames (radar and lidar share the timestamps)
    fps: float = 10.0  # frame rate (Hz)
    hfov_deg: float = 70.0  # camera horizontal field of view (deg)
    camera_xyz: tuple[float, float, float] = (1.5, 0.0, 1.5)  # camera position in the ego frame (m)
    camera_pitch_deg: float = 3.0  # camera looks down by this much (deg)
    ego_speed: tuple[float, float] = (5.0, 20.0)  # ego speed drawn in this range (m/s)
    # lateral S-curve amplitude drawn in this range (m): gentle curves, non-zero yaw rate
    weave_amplitude: tuple[float, float] = (0.0, 0.6)
    weave_wavelength: tuple[float, float] = (60.0, 150.0)  # S-curve wavelength drawn in this range (m)
    parked_cars: tuple[int, int] = (2, 4)  # number of parked cars, inclusive range
    moving_cars: tuple[int, int] = (2, 4)  # number of moving cars, inclusive range
    crossing_probability: float = 0.7  # chance that one moving car crosses at the intersection ahead
    image_noise_std: float = 1.0  # Gaussian pixel noise (8-bit units)
    # Each pixel's colour is the mean of supersample x supersample rays spread over it, as a camera integrates
    # light over its pixel; 1 (the default, which every recorded benchmark uses) samples the pixel centre once, so
    # thin features (a car roof seen edge-on, a lane line far off) appear and vanish between frames. Only
    # the image changes: gt/ (depth, masks, flow) stays that of the pixel centre.
    supersample: int = 1
    radar: RadarSimConfig = field(default_factory=RadarSimConfig)  # 4D radar simulation
    lidar: LidarSimConfig = field(default_factory=LidarSimConfig)  # lidar simulation
    prior: MonoPriorConfig = field(default_factory=MonoPriorConfig)  # priors/ (mono depth, sky mask)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)  # moving objects: calm (default) or a profile
    # The ego speed swings by +- this (m/s) with a period of `ego_speed_period` s (0: constant speed, as
    # always); a changing speed is what makes a camera-radar clock offset observable (radar/sync.py).
    ego_speed_swing: float = 0.0
    ego_speed_period: float = 4.0  # period of that swing (s)
    # The radar's clock is off by this (s): a scan is taken at the camera frame's time t (the scans and
    # gt/ are those of t) but stamped radar_timestamp = t - offset, with radar_ego_to_world the pose at
    # that wrong stamp, as a converter reading a skewed clock would write it. Positive: the radar's
    # stamps run early, the camera's late relative to them, the sign of radar/sync.py's tau.
    radar_time_offset: float = 0.0
    # The same scene with every moving object left out (parked cars stay): same world, camera path, noise
    # and radar draws, so each frame is the scene's gt/background render. Trained at a run's budget, it is
    # the ceiling of what a static layer can score under removed actors (benchmarks/actors.py --oracle).
    without_movers: bool = False

    PRESETS: ClassVar[dict[str, dict]] = {
        "tiny": {"width": 160, "height": 90, "num_frames": 20,
                 "lidar": {"beams": 16, "azimuth_step_deg": 1.0}},
        "small": {"width": 320, "height": 180, "num_frames": 50},
        "paper": {"width": 1920, "height": 1080, "num_frames": 50},
    }
