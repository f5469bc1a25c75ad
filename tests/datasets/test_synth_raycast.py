"""The ray caster against brute force, and its culling windows against no culling."""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from radar4dgs.config import preset
from radar4dgs.datasets.synth import SynthConfig
from radar4dgs.datasets.synth import camera as C
from radar4dgs.datasets.synth import radar as R
from radar4dgs.datasets.synth.raycast import (
    azimuth_windows,
    cast,
    pinhole_windows,
    ray_box,
    ray_sphere,
    rot_x,
    rot_y,
    rot_z,
)
from radar4dgs.datasets.synth.street import build_world

finite = st.floats(-5.0, 5.0, allow_nan=False)


def _inside_box(points, center, rot, half, slack=0.0):
    local = (points - center) @ rot
    return (np.abs(local) <= half + slack).all(axis=-1)


@settings(max_examples=150, deadline=None)
@given(center=st.tuples(finite, finite, finite), half=st.tuples(*[st.floats(0.1, 3.0)] * 3),
       angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3), origin=st.tuples(finite, finite, finite),
       direction=st.tuples(*[st.floats(-1.0, 1.0)] * 3))
@example(center=(0.0, 0.0, 1.0), half=(1.0, 1.0, 1.0), angles=(0.0, 0.0, 0.0), origin=(0.0, 2.0, 0.0),
         direction=(0.0, -1.0, 0.0))  # along the bottom face's plane, z = 0
def test_ray_box_matches_brute_force_marching(center, half, angles, origin, direction):
    center, half, origin, d = map(np.asarray, (center, half, origin, direction))
    if np.linalg.norm(d) < 1e-3:
        return
    d = d / np.linalg.norm(d)
    rot = rot_z(angles[0]) @ rot_y(angles[1]) @ rot_x(angles[2])
    if _inside_box(origin, center, rot, half, 1e-6):
        return  # the caster reports exits of a box it starts in as misses; sensors are outside
    t, _ = ray_box(origin, d[None], center, rot, half)
    steps = np.linspace(0.0, 30.0, 30001)
    inside = _inside_box(origin + steps[:, None] * d, center, rot, half)
    if np.isinf(t[0]):
        # A ray in the plane of a face only touches the surface: a hit or a miss is as good.
        assert not _inside_box(origin + steps[:, None] * d, center, rot, half, -1e-9).any()
    else:
        if inside.any():  # a grazing hit may fall between samples
            assert abs(t[0] - steps[np.argmax(inside)]) <= 2e-3
        # The hit lies on the surface: inside with slack, and on one face.
        local = (origin + t[0] * d - center) @ rot
        assert (np.abs(local) <= half + 1e-7).all()
        assert np.isclose(np.abs(local) / half, 1.0, atol=1e-7).any()


@settings(max_examples=100, deadline=None)
@given(center=st.tuples(finite, finite, finite), radius=st.floats(0.1, 3.0),
       origin=st.tuples(finite, finite, finite), direction=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
       length=st.floats(0.2, 3.0))
def test_ray_sphere_hits_the_surface_first(center, radius, origin, direction, length):
    center, origin, d = map(np.asarray, (center, origin, direction))
    if np.linalg.norm(d) < 1e-3 or np.linalg.norm(origin - center) <= radius + 1e-6:
        return
    d = d / np.linalg.norm(d) * length  # non-unit directions: t scales accordingly
    t = ray_sphere(origin, d[None], center, radius)[0]
    steps = np.linspace(0.0, 30.0 / length, 30001)
    inside = np.linalg.norm(origin + steps[:, None] * d - center, axis=1) <= radius
    if np.isinf(t):
        assert not inside.any()
    else:
        assert np.isclose(np.linalg.norm(origin + t * d - center), radius, atol=1e-7)
        if inside.any():
            assert abs(t - steps[np.argmax(inside)]) <= 2e-3 / length


def test_culling_windows_change_nothing():
    """Casting with the pinhole and azimuth windows equals casting every primitive on every ray."""
    config = preset(SynthConfig, "tiny", seed=4)
    world = build_world(config)
    prims = world.primitives_at(0.7)
    full = lambda n, shape: np.tile([0, shape[0], 0, shape[1]], (n, 1))  # noqa: E731
    K = C.intrinsics(config)
    cam_to_road = world.ego.pose(0.7) @ C.cam_to_ego(config)
    rays = C.pixel_rays(K, config.width, config.height) @ cam_to_road[:3, :3].T
    road_to_cam = np.linalg.inv(cam_to_road)
    culled = cast(cam_to_road[:3, 3], rays, prims,
                  pinhole_windows(prims.box_corners(), road_to_cam, K, config.width, config.height),
                  pinhole_windows(prims.sphere_corners(), road_to_cam, K, config.width, config.height))
    everything = cast(cam_to_road[:3, 3], rays, prims, full(prims.num_boxes, rays.shape),
                      full(len(prims.sphere_radius), rays.shape))
    assert np.array_equal(culled.prim, everything.prim)
    assert np.array_equal(culled.t, everything.t)

    # A full circle of azimuths, as the lidar uses, from the radar's position.
    azimuths = np.radians(np.arange(-179.75, 180.0, 0.5))
    elevations = np.radians(np.linspace(-20, 15, 12))
    dirs_sensor = R.spherical_to_xyz(np.ones((12, len(azimuths))), azimuths[None], elevations[:, None])
    sensor_to_road = world.ego.pose(0.7) @ np.array([[1, 0, 0, 3.6], [0, 1, 0, 0], [0, 0, 1, 0.5], [0, 0, 0, 1.0]])
    dirs = dirs_sensor @ sensor_to_road[:3, :3].T
    road_to_sensor = np.linalg.inv(sensor_to_road)
    margin = np.radians(0.5)
    culled = cast(sensor_to_road[:3, 3], dirs, prims,
                  azimuth_windows(prims.box_corners(), road_to_sensor, azimuths, margin, 12, 150.0),
                  azimuth_windows(prims.sphere_corners(), road_to_sensor, azimuths, margin, 12, 150.0), t_max=150.0)
    everything = cast(sensor_to_road[:3, 3], dirs, prims, full(prims.num_boxes, dirs.shape),
                      full(len(prims.sphere_radius), dirs.shape), t_max=150.0)
    assert np.array_equal(culled.prim, everything.prim)
    assert (culled.prim >= 1).sum() > 100  # the test saw boxes, not only ground and sky
