"""Radar association: nearest dynamic return within a gate, ego-compensated Doppler."""

from __future__ import annotations

import numpy as np
import pytest

from radar4dgs.motion.association import (
    RadarDynamics,
    associate_nearest,
    associate_velocities,
    compensated_radial_velocity,
    load_radar_dynamics,
    oracle_radar_velocity,
)


def test_association_nearest_within_gate():
    radar = RadarDynamics(np.array([[10.0, 0, 0], [20.0, 0, 0]]), np.array([1.0, -2.0]), np.zeros(3))
    points = np.array([[10.5, 0, 0], [19.0, 0.5, 0], [15.0, 0, 0], [30.0, 0, 0]])
    index, distance = associate_nearest(points, radar.points, gate=2.0)
    assert index.tolist() == [0, 1, -1, -1]
    assert distance[0] == pytest.approx(0.5)
    velocity = associate_velocities(points, radar, gate=2.0)
    assert velocity[:2].tolist() == [1.0, -2.0] and np.isnan(velocity[2:]).all()
    empty = RadarDynamics(np.zeros((0, 3)), np.zeros(0), np.zeros(3))
    assert np.isnan(associate_velocities(points, empty)).all()


def test_compensated_radial_velocity_of_static_and_moving_points():
    xyz = np.array([[10.0, 0, 0], [0, 10.0, 0], [6.0, 8.0, 0]])
    radar_velocity = np.array([5.0, 0, 0])
    static_doppler = -(xyz / np.linalg.norm(xyz, axis=1, keepdims=True)) @ radar_velocity  # v_r = -d . v_s
    assert compensated_radial_velocity(xyz, static_doppler, radar_velocity) == pytest.approx([0, 0, 0])
    # a point ahead receding at 3 m/s in the world while the radar drives at 5: raw v_r = 3 - 5
    assert compensated_radial_velocity(xyz[:1], np.array([-2.0]), radar_velocity)[0] == pytest.approx(3.0)


def test_oracle_radar_dynamics_compensate_static_points(motion_scene):
    i = 3
    scan = motion_scene.load_radar(i)
    labels = motion_scene.load_optional("gt/radar_labels", i)
    comp = compensated_radial_velocity(scan.xyz, scan.v_r, oracle_radar_velocity(motion_scene, i))
    assert np.median(np.abs(comp[labels == 0])) < 0.3
    dynamics = load_radar_dynamics(motion_scene, i, "oracle")
    assert len(dynamics) == int((labels == 1).sum())
    assert dynamics.centre == pytest.approx(motion_scene.radar_to_world(i)[:3, 3])
