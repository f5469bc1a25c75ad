"""Independent geometry for the synthetic-scene tests: every helper reads only a written scene
folder (poses, calibration, metadata, arrays) and recomputes from first principles."""

from __future__ import annotations

import numpy as np


def radar_velocity_in_radar_frame(scene, i):
    """v_s: the radar's own velocity in its frame, from ego_velocity, the yaw rate and the mount."""
    frame = scene.frames[i]
    omega = np.asarray(frame.extra["ego_angular_velocity"])
    mount = scene.radar.radar_to_ego
    v_ego = frame.ego_velocity + np.cross(omega, mount[:3, 3])
    return mount[:3, :3].T @ v_ego


def doppler_residual(scene, i):
    """(N,) v_r + d . v_s for every point of frame i, and the labels."""
    scan = scene.load_radar(i)
    xyz = scan.xyz.astype(np.float64)
    d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    return scan.v_r + d @ radar_velocity_in_radar_frame(scene, i), scene.load_optional("gt/radar_labels", i)


def bilinear(image, u, v):
    """Bilinear sample of (H, W) ``image`` at float pixel coordinates (pixel centres at integers)."""
    h, w = image.shape
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * image[v0, u0] + a * (1 - b) * image[v0, u0 + 1]
            + (1 - a) * b * image[v0 + 1, u0] + a * b * image[v0 + 1, u0 + 1])


def project(scene, i, points_world):
    """(N, 2) pixels and (N,) z-depth of world points in frame i's camera."""
    cam = scene.world_to_camera(i)
    pc = points_world @ cam[:3, :3].T + cam[:3, 3]
    return scene.camera.project(pc)


def depth_agrees(scene, i, uv, z, rel_tol):
    """(N,) bool: the camera's gt depth at (u, v) equals z within ``rel_tol``, interpolated in
    inverse depth (exact on a plane) or, at a depth edge, at one of the 4 surrounding pixels; and
    (N,) bool: (u, v) lies in the image in front of the camera."""
    depth = scene.load_optional("gt/depth", i).astype(np.float64)
    w, h = scene.camera.width, scene.camera.height
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1) & (z > 0.5)
    u, v, zi = uv[inside, 0], uv[inside, 1], z[inside]
    match = np.abs(bilinear(1.0 / depth, u, v) * zi - 1.0) < rel_tol  # sky: 1/inf = 0
    u0, v0 = np.clip(np.floor(u).astype(int), 0, w - 2), np.clip(np.floor(v).astype(int), 0, h - 2)
    for du in (0, 1):
        for dv in (0, 1):
            match |= np.abs(depth[v0 + dv, u0 + du] / zi - 1.0) < rel_tol
    ok = np.zeros(len(z), bool)
    ok[inside] = match
    return ok, inside


def backproject(scene, i):
    """(H*W, 3) world points of every pixel from gt depth (NaN/inf for sky) and (H*W,) sky flags."""
    depth = scene.load_optional("gt/depth", i).astype(np.float64)
    K = scene.camera.K
    v, u = np.mgrid[0:scene.camera.height, 0:scene.camera.width]
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
    pc = (rays * depth[..., None]).reshape(-1, 3)
    cam_to_world = np.linalg.inv(scene.world_to_camera(i))
    sky = ~np.isfinite(depth.reshape(-1))
    pc[sky] = 0.0
    return pc @ cam_to_world[:3, :3].T + cam_to_world[:3, 3], sky


def inside_cars(scene, i, points_world, moving, slack=0.01):
    """(N,) bool: points inside any box of the (moving or parked) cars at frame i, from metadata."""
    hit = np.zeros(len(points_world), bool)
    for obj in scene.extra["synthetic"]["objects"]:
        if obj["kind"] != ("moving" if moving else "parked"):
            continue
        pose = np.asarray(obj["poses"][i])
        local = (points_world - pose[:3, 3]) @ pose[:3, :3]
        for box in obj["boxes"]:
            hit |= (np.abs(local - box["center"]) <= np.asarray(box["half_size"]) + slack).all(axis=1)
    return hit
