"""Exact ray casting of analytic primitives: the ground plane z = 0, oriented boxes and spheres.

Every sensor here has one optical centre and a 2D grid of rays (camera pixels, radar azimuth x
elevation cells, lidar beams x azimuth steps), so rays are held as an (A, B, 3) grid and each
primitive is tested only on a rectangular window of that grid that its bounds can reach.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Hit index conventions of :class:`Hits`.prim: -1 = no surface (sky), 0 = ground plane,
# 1..M = box i - 1, M+1..M+S = sphere j - M - 1.
NO_HIT = -1
GROUND = 0
_EPS = 1e-9


def rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rigid(rotation: np.ndarray, translation) -> np.ndarray:
    """(4, 4) transform from a (3, 3) rotation and a (3,) translation."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    matrix[:3, 3] = translation
    return matrix


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (..., 3) points."""
    return points @ transform[:3, :3].T + transform[:3, 3]


@dataclass(frozen=True)
class Primitives:
    """A set of boxes and spheres with per-primitive attributes (road frame).

    Attributes:
        box_center, box_half: (M, 3) centre and half extents along the box axes (m).
        box_rot: (M, 3, 3) box-to-road rotation; its columns are the box axes.
        sphere_center: (S, 3); sphere_radius: (S,).
        material, obj: (1 + M + S,) int, indexed like ``Hits.prim`` (entry 0 is the ground):
            material id and owning object (-1 = static world, k = mover k).
        color: (1 + M + S, 3) base colour in 0..1.
    """

    box_center: np.ndarray
    box_rot: np.ndarray
    box_half: np.ndarray
    sphere_center: np.ndarray
    sphere_radius: np.ndarray
    material: np.ndarray
    obj: np.ndarray
    color: np.ndarray

    @property
    def num_boxes(self) -> int:
        return int(self.box_center.shape[0])

    def box_corners(self) -> np.ndarray:
        """(M, 8, 3) corners of every box."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        local = signs[None] * self.box_half[:, None, :]
        return np.einsum("mij,mkj->mki", self.box_rot, local) + self.box_center[:, None, :]

    def sphere_corners(self) -> np.ndarray:
        """(S, 8, 3) corners of every sphere's axis-aligned bounding box."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return self.sphere_center[:, None, :] + signs[None] * self.sphere_radius[:, None, None]


@dataclass(frozen=True)
class Hits:
    """First hits of a ray grid.

    Attributes:
        t: (A, B) ray parameter of the hit (inf = none); equals the distance for unit directions
            and the z-depth for camera rays with unit z.
        prim: (A, B) int32 primitive index (see module constants).
        normal: (A, B, 3) unit surface normal in the road frame, facing the ray's origin side
            for boxes and the ground; outward for spheres.
    """

    t: np.ndarray
    prim: np.ndarray
    normal: np.ndarray


def ray_box(origin: np.ndarray, dirs: np.ndarray, center: np.ndarray, rot: np.ndarray,
            half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slab test of (..., 3) rays from one origin against one oriented box.

    Returns the entry parameter (..., ) (inf where missed or where the origin is inside) and the
    (...,) index of the box axis whose slab was entered last (the face that was hit).
    """
    o = rot.T @ (origin - center)
    d = dirs @ rot
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / d
        t1 = (-half - o) * inv
        t2 = (half - o) * inv
    tmin = np.minimum(t1, t2)
    t_near = tmin.max(axis=-1)
    t_far = np.maximum(t1, t2).min(axis=-1)
    # NaN (a ray lying in a slab's boundary plane) compares False, so it counts as a miss.
    hit = (t_near <= t_far) & (t_near > _EPS)
    return np.where(hit, t_near, np.inf), tmin.argmax(axis=-1)


def ray_sphere(origin: np.ndarray, dirs: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """Entry parameter (...,) of (..., 3) rays from one origin into a sphere (inf where missed)."""
    oc = origin - center
    a = np.einsum("...i,...i->...", dirs, dirs)
    b = dirs @ oc
    c = oc @ oc - radius * radius
    disc = b * b - a * c
    with np.errstate(invalid="ignore"):
        t = (-b - np.sqrt(disc)) / a
    return np.where((disc >= 0) & (t > _EPS), t, np.inf)


def cast(origin: np.ndarray, dirs: np.ndarray, prims: Primitives, box_windows: np.ndarray,
         sphere_windows: np.ndarray, t_max: float = np.inf) -> Hits:
    """First hits of a grid of rays from ``origin`` (3,) along ``dirs`` (A, B, 3) (road frame).

    ``box_windows`` (M, 4) and ``sphere_windows`` (S, 4) hold (row0, row1, col0, col1): each
    primitive is tested only on ``dirs[row0:row1, col0:col1]``; an empty window culls it. The
    windows must be conservative (contain every ray that can hit the primitive).
    """
    shape = dirs.shape[:2]
    t = np.full(shape, float(t_max))
    prim = np.full(shape, NO_HIT, dtype=np.int32)
    normal = np.zeros(shape + (3,))
    if origin[2] > 0:  # the ground plane z = 0, seen from above
        with np.errstate(divide="ignore", invalid="ignore"):
            t_ground = -origin[2] / dirs[..., 2]
        hit = (dirs[..., 2] < 0) & (t_ground < t)
        t[hit] = t_ground[hit]
        prim[hit] = GROUND
        normal[hit] = (0.0, 0.0, 1.0)
    for i in range(prims.num_boxes):
        r0, r1, c0, c1 = box_windows[i]
        if r1 <= r0 or c1 <= c0:
            continue
        window = (slice(r0, r1), slice(c0, c1))
        t_box, axis = ray_box(origin, dirs[window], prims.box_center[i], prims.box_rot[i], prims.box_half[i])
        closer = t_box < t[window]
        if not closer.any():
            continue
        axis = axis[closer]
        local_d = dirs[window][closer] @ prims.box_rot[i]
        sign = -np.sign(local_d[np.arange(len(axis)), axis])
        t[window][closer] = t_box[closer]
        prim[window][closer] = 1 + i
        normal[window][closer] = prims.box_rot[i][:, axis].T * sign[:, None]
    for j in range(len(prims.sphere_radius)):
        r0, r1, c0, c1 = sphere_windows[j]
        if r1 <= r0 or c1 <= c0:
            continue
        window = (slice(r0, r1), slice(c0, c1))
        t_sph = ray_sphere(origin, dirs[window], prims.sphere_center[j], prims.sphere_radius[j])
        closer = t_sph < t[window]
        if not closer.any():
            continue
        points = origin + dirs[window][closer] * t_sph[closer][:, None]
        t[window][closer] = t_sph[closer]
        prim[window][closer] = 1 + prims.num_boxes + j
        normal[window][closer] = (points - prims.sphere_center[j]) / prims.sphere_radius[j]
    t[prim == NO_HIT] = np.inf
    return Hits(t, prim, normal)


def pinhole_windows(corners: np.ndarray, road_to_cam: np.ndarray, K: np.ndarray, width: int,
                    height: int, near: float = 0.05) -> np.ndarray:
    """(P, 4) pixel windows (row0, row1, col0, col1) of (P, 8, 3) convex hulls' corners.

    A pinhole maps a convex hull in front of the camera inside the hull of its projected corners;
    a hull that crosses the near plane gets the whole image, one behind it an empty window.
    Pixel centres are at integer coordinates.
    """
    pc = apply(road_to_cam, corners)
    z = pc[..., 2]
    behind = (z <= near).all(axis=1)
    straddles = (z <= near).any(axis=1) & ~behind
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K[0, 0] * pc[..., 0] / z + K[0, 2]
        v = K[1, 1] * pc[..., 1] / z + K[1, 2]
    windows = np.stack([np.floor(v.min(1)) - 1, np.ceil(v.max(1)) + 2,
                        np.floor(u.min(1)) - 1, np.ceil(u.max(1)) + 2], axis=1)
    windows = np.nan_to_num(windows, nan=0.0, posinf=1e9, neginf=-1e9)
    windows[straddles] = (0, height, 0, width)
    windows[behind] = 0
    windows[:, :2] = windows[:, :2].clip(0, height)
    windows[:, 2:] = windows[:, 2:].clip(0, width)
    return windows.astype(np.int64)


def azimuth_windows(corners: np.ndarray, road_to_sensor: np.ndarray, azimuths: np.ndarray,
                    margin: float, rows: int, max_range: float) -> np.ndarray:
    """(P, 4) windows of (P, 8, 3) hulls on a grid whose columns are sorted ``azimuths`` (rad).

    Culls in azimuth only (all ``rows`` are kept) since a box's elevation extremes need not lie at
    its corners. ``margin`` (rad) widens each window for rays jittered inside their cells. A hull
    whose bounding circle contains the sensor, or that wraps across +-pi, gets every column.
    """
    pc = apply(road_to_sensor, corners)
    center = pc.mean(axis=1)
    radius = np.linalg.norm(pc - center[:, None], axis=2).max(axis=1)
    dist_xy = np.linalg.norm(center[:, :2], axis=1)
    dist = np.linalg.norm(center, axis=1)
    az_center = np.arctan2(center[:, 1], center[:, 0])
    rel = np.arctan2(pc[..., 1], pc[..., 0]) - az_center[:, None]
    rel = (rel + np.pi) % (2 * np.pi) - np.pi
    lo = az_center + rel.min(axis=1) - margin
    hi = az_center + rel.max(axis=1) + margin
    full = (dist_xy <= radius) | (hi - lo >= np.pi)
    lo = (lo + np.pi) % (2 * np.pi) - np.pi
    hi = (hi + np.pi) % (2 * np.pi) - np.pi
    full |= lo > hi
    c0 = np.searchsorted(azimuths, lo, side="left")
    c1 = np.searchsorted(azimuths, hi, side="right")
    c0[full], c1[full] = 0, len(azimuths)
    windows = np.stack([np.zeros_like(c0), np.full_like(c0, rows), c0, c1], axis=1)
    windows[dist - radius > max_range] = 0
    return windows.astype(np.int64)


def cast_sensor_grid(prims: Primitives, sensor_to_road: np.ndarray, dirs_sensor: np.ndarray,
                     azimuths: np.ndarray, margin: float, max_range: float):
    """Cast a rotating sensor's ray grid (lidar, radar) from its pose into the world.

    ``dirs_sensor`` (rows, columns, 3) are unit rays in the sensor frame on a grid whose columns are
    the sorted ``azimuths``; primitives are culled per azimuth column (``margin`` rad wider, for
    jittered rays). Returns (origin (3,), road-frame dirs (rows, columns, 3), road_to_sensor (4, 4),
    the :func:`cast` hits).
    """
    road_to_sensor = np.linalg.inv(sensor_to_road)
    origin = sensor_to_road[:3, 3]
    dirs = dirs_sensor @ sensor_to_road[:3, :3].T
    rows = dirs_sensor.shape[0]
    hits = cast(origin, dirs, prims,
                azimuth_windows(prims.box_corners(), road_to_sensor, azimuths, margin, rows, max_range),
                azimuth_windows(prims.sphere_corners(), road_to_sensor, azimuths, margin, rows, max_range),
                t_max=max_range)
    return origin, dirs, road_to_sensor, hits
