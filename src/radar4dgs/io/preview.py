"""Scene previews: what a scene folder holds, radar points drawn over frames, and a contact sheet
to look at (used by ``radar4dgs inspect``, the evaluation report and the segmentation data)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from radar4dgs.io.atomic import atomic_write_bytes
from radar4dgs.io.image_motion import scene_dynamic_pixel_motion
from radar4dgs.io.scene import Scene, SceneWarning


def pose_speeds(scene: Scene) -> np.ndarray:
    """(F-1,) ego speed (m/s) between consecutive frames from the pose translations."""
    positions = np.stack([f.ego_to_world[:3, 3] for f in scene.frames])
    times = np.array([f.timestamp for f in scene.frames])
    if len(times) < 2:
        return np.zeros(0)
    return np.linalg.norm(np.diff(positions, axis=0), axis=1) / np.diff(times)


def radar_points_in_camera(scene: Scene, index: int, xyz_radar: np.ndarray) -> np.ndarray:
    """(N, 3) radar-frame points of frame ``index`` in that frame's camera axes (OpenCV), through
    :meth:`Scene.radar_to_camera`."""
    transform = scene.radar_to_camera(index)
    return np.asarray(xyz_radar, dtype=np.float64) @ transform[:3, :3].T + transform[:3, 3]


def summarize_scene(scene: Scene) -> dict[str, Any]:
    """A JSON-ready summary: frames, duration, size, radar counts, speeds, split, optional folders."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SceneWarning)
        counts = np.array([len(scene.load_radar(i)) for i in range(len(scene))]) if scene.has_radar else None
    speeds = pose_speeds(scene)
    velocities = [f.ego_velocity for f in scene.frames if f.ego_velocity is not None]
    summary: dict[str, Any] = {
        "name": scene.name,
        "root": str(scene.root),
        "source": dict(scene.source),
        "frames": len(scene),
        "duration_s": round(scene.duration, 4),
        "frame_rate_hz": round((len(scene) - 1) / scene.duration, 3) if scene.duration > 0 else None,
        "image_size": [scene.camera.width, scene.camera.height],
        # None for a camera-only scene (convert nerfstudio / colmap).
        "radar_fields": list(scene.radar.fields) if counts is not None else None,
        "radar_points_per_frame": None if counts is None else {
            "min": int(counts.min()), "median": float(np.median(counts)), "max": int(counts.max()),
            "total": int(counts.sum())},
        "ego_speed_from_poses_mps": ({"mean": round(float(speeds.mean()), 3), "min": round(float(speeds.min()), 3),
                                      "max": round(float(speeds.max()), 3)} if len(speeds) else None),
        "ego_speed_from_ego_velocity_mps": (round(float(np.mean([np.linalg.norm(v) for v in velocities])), 3)
                                            if velocities else None),
        "split": {"test_every": scene.test_every, "train": len(scene.train_indices), "test": len(scene.test_indices),
                  "test_frames": [scene.frames[i].name for i in scene.test_indices]},
        "optional_folders": scene.optional_folders(),
        "dynamic_pixel_motion_px": dynamic_motion_statistics(scene),
        "warnings": [str(w.message) for w in caught],
    }
    return summary


MOTION_FOLDERS = ("gt/dynamic_mask", "gt/depth", "gt/flow")


def dynamic_motion_statistics(scene: Scene) -> dict[str, Any] | None:
    """p50 / p90 / p99 / max of how far the dynamic pixels move per frame (px), pooled over the
    scene, from its ground truth (:func:`~radar4dgs.io.image_motion.dynamic_pixel_motion`); None
    when the scene has no ``gt/dynamic_mask``, ``gt/depth`` and ``gt/flow``. Every motion figure
    of the project is reported beside these, since flow error grows with the motion itself."""
    if not all(folder in scene.optional_folders() for folder in MOTION_FOLDERS):
        return None
    motion = scene_dynamic_pixel_motion(scene)
    if not len(motion):
        return {"pixels": 0, "p50": None, "p90": None, "p99": None, "max": None}
    p50, p90, p99 = np.percentile(motion, [50, 90, 99])
    return {"pixels": int(len(motion)), "p50": round(float(p50), 2), "p90": round(float(p90), 2),
            "p99": round(float(p99), 2), "max": round(float(motion.max()), 2)}


def format_summary(summary: dict[str, Any]) -> str:
    radar = summary["radar_points_per_frame"]
    speed = summary["ego_speed_from_poses_mps"]
    lines = [
        f"scene      {summary['name']}  ({summary['root']})",
        f"source     {json.dumps(summary['source'])}",
        f"frames     {summary['frames']} over {summary['duration_s']:.2f} s"
        + (f" ({summary['frame_rate_hz']:.2f} Hz)" if summary["frame_rate_hz"] else ""),
        f"image      {summary['image_size'][0]}x{summary['image_size'][1]}",
        (f"radar      {', '.join(summary['radar_fields'])}; points per frame min {radar['min']} / "
         f"median {radar['median']:.0f} / max {radar['max']}" if radar else "radar      none (a camera-only scene)"),
        "ego speed  " + (f"{speed['mean']:.2f} m/s mean from poses (min {speed['min']:.2f}, max {speed['max']:.2f})"
                         if speed else "n/a (one frame)")
        + (f"; {summary['ego_speed_from_ego_velocity_mps']:.2f} m/s from ego_velocity"
           if summary["ego_speed_from_ego_velocity_mps"] is not None else ""),
        f"split      {summary['split']['train']} train / {summary['split']['test']} test "
        f"(every {summary['split']['test_every']}th frame)",
        f"optional   {', '.join(summary['optional_folders']) or 'none'}",
        "motion     " + _format_motion(summary.get("dynamic_pixel_motion_px")),
    ]
    lines += [f"warning    {w}" for w in summary["warnings"]]
    return "\n".join(lines)


def _format_motion(motion: dict[str, Any] | None) -> str:
    if motion is None:
        return "n/a (needs gt/dynamic_mask, gt/depth and gt/flow)"
    if not motion["pixels"]:
        return "no dynamic pixels"
    return (f"dynamic pixels move p50 {motion['p50']:.1f} / p90 {motion['p90']:.1f} / p99 {motion['p99']:.1f} px "
            f"per frame (max {motion['max']:.1f}; {motion['pixels']} pixels)")


def doppler_colors(v_r: np.ndarray, limit: float) -> np.ndarray:
    """(N, 3) uint8 RGB: blue for approaching (v_r < 0), white at 0, red for receding, saturating
    at ``limit`` m/s."""
    t = np.clip(v_r / max(limit, 1e-6), -1.0, 1.0)[:, None]
    white = np.array([255.0, 255.0, 255.0])
    red, blue = np.array([220.0, 30.0, 30.0]), np.array([30.0, 80.0, 230.0])
    colors = np.where(t >= 0, white + t * (red - white), white - t * (blue - white))
    return colors.astype(np.uint8)


def draw_radar_overlay(image: np.ndarray, uv: np.ndarray, colors: np.ndarray, radius: int) -> np.ndarray:
    """Copy of (H, W, 3) RGB ``image`` with (N, 2) pixel positions drawn as outlined dots."""
    canvas = image.copy()
    for (u, v), color in zip(np.round(uv).astype(int), colors, strict=True):
        cv2.circle(canvas, (int(u), int(v)), radius + 1, (0, 0, 0), -1, cv2.LINE_AA)
        cv2.circle(canvas, (int(u), int(v)), radius, tuple(int(c) for c in color), -1, cv2.LINE_AA)
    return canvas


def contact_sheet(scene: Scene, num_frames: int = 4, tile_width: int = 480,
                  v_r_limit: float | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB grid of ``num_frames`` evenly spaced frames with the radar points
    projected and coloured by raw ``v_r`` (blue approaching, red receding), and a legend row."""
    indices = np.unique(np.linspace(0, len(scene) - 1, min(num_frames, len(scene))).round().astype(int))
    scale = tile_width / scene.camera.width
    tile_height = int(round(scene.camera.height * scale))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        # A camera-only scene's sheet is its frames without points.
        scans = [scene.load_radar(int(i)) if scene.has_radar else None for i in indices]
    if v_r_limit is None:
        all_v = np.concatenate([s.v_r for s in scans if s is not None] or [np.zeros(0)])
        v_r_limit = float(np.percentile(np.abs(all_v), 95)) if len(all_v) else 1.0
    tiles = []
    for index, scan in zip(indices, scans, strict=True):
        tile = cv2.resize(scene.load_image(int(index)), (tile_width, tile_height), interpolation=cv2.INTER_AREA)
        if scan is not None:
            tile, visible = _overlay_scan(scene, int(index), scan, tile, scale, v_r_limit)
        label = (f"{scene.frames[int(index)].name}"
                 f"  t={scene.frames[int(index)].timestamp - scene.frames[0].timestamp:.2f}s"
                 + (f"  {visible}/{len(scan)} radar pts" if scan is not None else ""))
        cv2.rectangle(tile, (0, 0), (tile_width, 22), (0, 0, 0), -1)
        cv2.putText(tile, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    return _grid_with_legend(tiles, tile_width, tile_height, v_r_limit)


def _overlay_scan(scene: Scene, index: int, scan, tile: np.ndarray, scale: float,
                  v_r_limit: float) -> tuple[np.ndarray, int]:
    """``tile`` (H, W, 3) with frame ``index``'s radar points drawn, and how many were in view."""
    tile_height, tile_width = tile.shape[:2]
    uv, z = scene.camera.project(radar_points_in_camera(scene, index, scan.xyz.astype(np.float64)))
    uv = uv * scale
    visible = (z > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] < tile_width) & (uv[:, 1] >= 0) & (uv[:, 1] < tile_height)
    # Far points first, so near ones are drawn on top.
    order = np.argsort(-z[visible])
    tile = draw_radar_overlay(tile, uv[visible][order], doppler_colors(scan.v_r[visible][order], v_r_limit),
                              radius=max(2, tile_width // 160))
    return tile, int(visible.sum())


def _grid_with_legend(tiles: list[np.ndarray], tile_width: int, tile_height: int, v_r_limit: float) -> np.ndarray:
    """The (H, W, 3) tiles in two columns above the Doppler colour legend."""
    columns = 2 if len(tiles) > 1 else 1
    rows = -(-len(tiles) // columns)
    blank = np.zeros((tile_height, tile_width, 3), np.uint8)
    tiles += [blank] * (rows * columns - len(tiles))
    grid = np.concatenate([np.concatenate(tiles[r * columns:(r + 1) * columns], axis=1) for r in range(rows)], axis=0)
    width = grid.shape[1]
    legend = np.full((28, width, 3), 255, np.uint8)
    ramp_start, ramp_end = int(0.25 * width), int(0.45 * width)
    ramp = doppler_colors(np.linspace(-v_r_limit, v_r_limit, max(ramp_end - ramp_start, 1)), v_r_limit)
    legend[6:22, ramp_start:ramp_end] = ramp[None, : ramp_end - ramp_start, :]
    if width >= 400:  # text does not fit on a thumbnail-sized sheet
        font = cv2.FONT_HERSHEY_SIMPLEX
        cv2.putText(legend, f"v_r -{v_r_limit:.1f}", (8, 19), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
        cv2.putText(legend, f"+{v_r_limit:.1f} m/s (raw Doppler; blue approaching, red receding)",
                    (ramp_end + 6, 19), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([grid, legend], axis=0)


def save_png(path: Path, rgb: np.ndarray) -> Path:
    """Atomically write an (H, W, 3) uint8 RGB image as PNG."""
    ok, encoded = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"{path}: PNG encoding failed")
    return atomic_write_bytes(path, encoded.tobytes())
