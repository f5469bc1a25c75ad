"""``synthesize``: draw a world, render every frame and write a scene folder with ground truth."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from radar4dgs.config import to_dict
from radar4dgs.datasets.synth import camera as C
from radar4dgs.datasets.synth import lidar as L
from radar4dgs.datasets.synth import priors as P
from radar4dgs.datasets.synth import radar as R
from radar4dgs.datasets.synth import world as W
from radar4dgs.datasets.synth.background import background_world
from radar4dgs.datasets.synth.config import RadarReflectivity, SynthConfig, TrafficConfig
from radar4dgs.datasets.synth.street import build_world
from radar4dgs.io.scene import Camera, Frame, RadarSpec, SceneWriter

GENERATOR = "radar4dgs.synth"
# Streams of np.random.default_rng([seed, stream, frame]): each output draws from its own stream,
# so changing one option (say radar noise) leaves the layout and every other output unchanged.
# The layout uses stream 0 and the traffic profiles street.TRAFFIC_STREAM.
_CAMERA, _RADAR, _LIDAR, _PRIOR, _MOUNT, _SCENE_PRIOR = 1, 2, 3, 4, 5, 6


def validate(config: SynthConfig) -> None:
    """Raise ValueError naming the first bad option."""
    checks = [
        (config.seed >= 0, f"seed must be >= 0, got {config.seed}"),
        (config.width >= 8 and config.height >= 8, f"image must be at least 8x8, got {config.width}x{config.height}"),
        (config.num_frames >= 1, f"num_frames must be >= 1, got {config.num_frames}"),
        (config.supersample >= 1, f"supersample must be >= 1, got {config.supersample}"),
        (config.fps > 0, f"fps must be > 0, got {config.fps}"),
        (0 < config.hfov_deg < 170, f"hfov_deg must be in (0, 170), got {config.hfov_deg}"),
        (config.camera_xyz[2] > 0, "camera_xyz z must be above the road (> 0)"),
        (config.radar.mount_xyz[2] > 0, "radar.mount_xyz z must be above the road (> 0)"),
        (config.lidar.mount_xyz[2] > 0, "lidar.mount_xyz z must be above the road (> 0)"),
        (config.ego_speed[0] >= 0, "ego_speed must be >= 0"),
        (config.ego_speed_period > 0, f"ego_speed_period must be > 0, got {config.ego_speed_period}"),
        (config.parked_cars[0] >= 0 and config.moving_cars[0] >= 0, "car counts must be >= 0"),
        (config.lidar.beams >= 1, "lidar.beams must be >= 1"),
        (config.traffic.attempts >= 1 and config.traffic.min_gap >= 0, "traffic.attempts must be >= 1, "
         "traffic.min_gap >= 0"),
        (config.radar.max_points >= 0 and config.radar.ghost_count >= 0,
         "radar.max_points and ghost_count must be >= 0"),
    ]
    for name in ("ego_speed", "weave_amplitude", "weave_wavelength", "parked_cars", "moving_cars"):
        lo, hi = getattr(config, name)
        checks.append((lo <= hi, f"{name} must be (low, high) with low <= high, got {(lo, hi)}"))
    for name in TRAFFIC_RANGES:
        lo, hi = getattr(config.traffic, name)
        checks.append((0 <= lo <= hi, f"traffic.{name} must be (low, high) with 0 <= low <= high, got {(lo, hi)}"))
    stds = {"radar.range_std": config.radar.range_std, "radar.azimuth_std_deg": config.radar.azimuth_std_deg,
            "radar.elevation_std_deg": config.radar.elevation_std_deg, "radar.v_r_std": config.radar.v_r_std,
            "radar.rcs_std_db": config.radar.rcs_std_db, "radar.clutter_fraction": config.radar.clutter_fraction,
            "lidar.range_std": config.lidar.range_std, "image_noise_std": config.image_noise_std,
            "prior.noise_std": config.prior.noise_std}
    checks += [(v >= 0, f"{k} must be >= 0, got {v}") for k, v in stds.items()]
    for ok, message in checks:
        if not ok:
            raise ValueError(f"SynthConfig: {message}")


TRAFFIC_RANGES = ("intersection_gap", "lead_closing_speed", "lead_gap_end", "cut_in_duration", "cut_in_time",
                  "cut_in_gap", "oncoming_speed", "oncoming_pass", "crossing_speed", "crossing_time", "pedestrians",
                  "pedestrian_speed", "cyclists", "cyclist_speed", "oncoming_cars", "crossing_cars")


def config_record(config: SynthConfig) -> dict:
    """``to_dict(config)`` for scene.json. With calm traffic, the options added for the traffic
    profiles are left out while they hold their defaults, so calm scenes keep the exact scene.json
    they had before those options existed."""
    record = to_dict(config)
    # Options added later are recorded only when set, so existing scenes keep their exact scene.json.
    for name, default in (("ego_speed_swing", 0.0), ("ego_speed_period", 4.0), ("radar_time_offset", 0.0),
                          ("without_movers", False)):
        if record.get(name) == default and (name != "ego_speed_period" or not config.ego_speed_swing):
            del record[name]
    if config.traffic == TrafficConfig():
        del record["traffic"]
        defaults, reflectivity = RadarReflectivity(), config.radar.reflectivity
        for name in ("person", "bicycle"):
            if getattr(reflectivity, name) == getattr(defaults, name):
                del record["radar"]["reflectivity"][name]
    return record


def _mover_metadata(mover: W.Mover, to_world: np.ndarray, times: np.ndarray) -> dict:
    """Ground truth of one mover (traffic profiles): its class, and per frame its world pose,
    velocity (m/s) and yaw rate (rad/s); ``velocity`` and ``speed`` too when they are constant."""
    moving = any(mover.moving_at(float(t)) for t in times)
    entry = {"id": mover.index, "kind": "moving" if moving else "parked", "class": mover.category, "role": mover.role,
             "dims": [mover.length, mover.width, mover.height], "color": np.round(mover.color, 4).tolist()}
    if mover.trajectory.constant:
        entry.update(speed=mover.speed(0.0), velocity=(to_world[:3, :3] @ mover.velocity(0.0)).tolist())
    entry["velocities"] = [(to_world[:3, :3] @ mover.velocity(float(t))).tolist() for t in times]
    entry["yaw_rates"] = [mover.trajectory.yaw_rate(float(t)) for t in times]
    entry["boxes"] = [{"center": c.tolist(), "half_size": h.tolist(), "part": W.MATERIAL_NAMES[m]}
                      for c, h, m in zip(mover.local_center, mover.local_half, mover.local_material, strict=True)]
    entry["poses"] = [(to_world @ mover.pose(float(t))).tolist() for t in times]
    return entry


def _object_metadata(world: W.World, times: np.ndarray, calm: bool = True) -> list[dict]:
    """Per-object ground truth in the world frame: the ego and every mover with its boxes and poses
    (``calm``: exactly the entries calm scenes have always had; else :func:`_mover_metadata`)."""
    to_world = world.road_to_world
    ego = world.ego
    objects: list[dict] = [{
        "id": "ego", "kind": "ego", "speed": ego.speed,
        "trajectory": {"model": "x = speed t, y = lane_y + amplitude sin(wavenumber x + phase) (road frame)",
                       "lane_y": ego.lane_y, "amplitude": ego.amplitude, "wavenumber": ego.wavenumber,
                       "phase": ego.phase}}]
    if ego.swing:
        objects[0]["trajectory"].update(model="dx/dt = speed + swing sin(2 pi t / swing_period), y as above",
                                        swing=ego.swing, swing_period=ego.swing_period)
    if not calm:
        return objects + [_mover_metadata(mover, to_world, times) for mover in world.movers]
    for car in world.movers:
        objects.append({
            "id": car.index, "kind": "moving" if car.moving_at(0.0) else "parked", "role": car.role,
            "dims": [car.length, car.width, car.height], "color": np.round(car.color, 4).tolist(),
            "speed": car.speed(0.0), "velocity": (to_world[:3, :3] @ car.velocity(0.0)).tolist(),
            "boxes": [{"center": c.tolist(), "half_size": h.tolist(), "part": W.MATERIAL_NAMES[m]}
                      for c, h, m in zip(car.local_center, car.local_half, car.local_material, strict=True)],
            "poses": [(to_world @ car.pose(float(t))).tolist() for t in times]})
    return objects


def synthesize(config: SynthConfig, out: Path, overwrite: bool = False, progress: bool = True,
               preset: str | None = None) -> Path:
    """Generate a scene folder at ``out`` (see SCENE_FORMAT.md) and return its path.

    Writes images, radar, lidar, priors/ and gt/. gt/flow of the last frame is the displacement
    over one more frame interval (the motion is analytic, so it is extrapolated exactly).
    """
    validate(config)
    out = Path(out)
    dt = 1.0 / config.fps
    times = np.arange(config.num_frames) * dt
    world = build_world(config)
    if config.without_movers:
        world = background_world(world, times)
    K = C.intrinsics(config)
    cam_to_ego = C.cam_to_ego(config)
    rays = C.pixel_rays(K, config.width, config.height)
    mount = R.radar_to_ego(config.radar, np.random.default_rng([config.seed, _MOUNT]))
    prior_rng = np.random.default_rng([config.seed, _SCENE_PRIOR])
    a, b = (float(prior_rng.uniform(*r)) for r in (config.prior.scale_range, config.prior.shift_range))
    camera = Camera(config.width, config.height, K, cam_to_ego)
    radar_spec = RadarSpec(mount, R.FIELDS)
    to_world = world.road_to_world

    with SceneWriter(out, overwrite=overwrite) as writer:
        for i in tqdm(range(config.num_frames), desc=f"synth {out.name}", unit="frame", disable=not progress):
            time = float(times[i])
            view = C.render(world, config, K, cam_to_ego, rays, time, dt,
                            np.random.default_rng([config.seed, _CAMERA, i]))
            if config.supersample > 1:
                view = replace(view, image=C.supersampled_image(world, config, cam_to_ego, time, dt,
                                                                np.random.default_rng([config.seed, _CAMERA, i])))
            scan = R.simulate(world, config.radar, mount, time, np.random.default_rng([config.seed, _RADAR, i]))
            lidar = L.simulate(world, config.lidar, time, np.random.default_rng([config.seed, _LIDAR, i]))
            prior_rng = np.random.default_rng([config.seed, _PRIOR, i])
            field = P.distortion_field(world.noise, config.width, config.height, config.prior.distortion, time)
            pose = to_world @ world.ego.pose(time)
            # A skewed radar clock (radar_time_offset): the scan is of `time`, its stamp and pose are not.
            radar_time = time - config.radar_time_offset
            radar_pose = to_world @ world.ego.pose(radar_time) if config.radar_time_offset else pose
            frame = Frame(name=f"{i:06d}", timestamp=time, ego_to_world=pose, radar_timestamp=radar_time,
                          radar_ego_to_world=radar_pose,
                          ego_velocity=np.array([np.linalg.norm(world.ego.velocity(time)), 0.0, 0.0]),
                          extra={"ego_angular_velocity": [0.0, 0.0, world.ego.yaw_rate(time)]})
            writer.add_frame(frame, view.image, scan.points, lidar=lidar,
                             priors_mono_depth=P.mono_depth(view.depth.astype(np.float64), a, b, field,
                                                            config.prior, prior_rng),
                             priors_sky_mask=P.sky_mask(view.sky, config.prior, prior_rng),
                             gt_depth=view.depth, gt_dynamic_mask=view.dynamic, gt_sky_mask=view.sky,
                             gt_flow=view.flow, gt_radar_labels=scan.labels)
        yaw_mis = float(np.degrees(np.arctan2(mount[1, 0], mount[0, 0])))
        pitch_mis = float(np.degrees(-np.arcsin(mount[2, 0])))
        synthetic = {
            "road_to_world": to_world.tolist(),
            "dynamic_speed_threshold": W.DYNAMIC_SPEED,
            "flow_last_frame": "displacement over one more frame interval (exact: the motion is analytic)",
            "intersection_x_road": world.x_int,
            "radar_misalignment_deg": {"yaw": yaw_mis, "pitch": pitch_mis},
            "mono_depth_prior": {"a": a, "b": b, "model": "a / z * (1 + distortion + noise) + b, then blurred"},
            "objects": _object_metadata(world, times, calm=config.traffic == TrafficConfig()),
            "config": config_record(config),
        }
        source = {"dataset": "synthetic", "seed": config.seed, "preset": preset, "generator": GENERATOR}
        writer.finish(f"synthetic-s{config.seed}", camera, radar_spec, source=source,
                      extra={"synthetic": synthetic})
    return out

