"""A moving object's position at its end facing the radar (radar/anchor.py): exact along the heading whatever part
of the body the returns cover, and a crossing car tracked at its speed where the centroid's slide slows it."""

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from radar4dgs.radar.anchor import anchored_position, extent_along, track_lengths
from radar4dgs.radar.config import RadarObjectConfig
from radar4dgs.radar.objects import detect_objects, track_objects


def side_returns(centre, heading, length, width, radar, fraction, n, rng):
    """(n + 2, 2) returns on the near long side of a box, from the end facing ``radar`` inward over ``fraction``
    of its length, and on that end's face (the extreme point along the heading among them)."""
    across = np.array([-heading[1], heading[0]])
    near = 0.5 * width * (1.0 if across @ (radar - centre) > 0 else -1.0)
    facing = 1.0 if heading @ (radar - centre) > 0 else -1.0
    end = facing * length / 2
    along = end - facing * rng.uniform(0.0, fraction * length, n)
    side = centre + along[:, None] * heading + near * across
    face = centre + end * heading + np.array([[0.0], [near]]) * across
    return np.concatenate([side, face])


@settings(max_examples=60, deadline=None)
@given(angle=st.floats(0.0, 2 * math.pi), length=st.floats(3.0, 12.0), fraction=st.floats(0.05, 1.0),
       bearing=st.floats(0.0, 2 * math.pi), distance=st.floats(10.0, 120.0), seed=st.integers(0, 1000))
def test_the_facing_end_gives_the_centre_along_the_heading_whatever_part_is_seen(angle, length, fraction, bearing,
                                                                                   distance, seed):
    rng = np.random.default_rng(seed)
    heading = np.array([math.cos(angle), math.sin(angle)])
    centre = np.array([5.0, -3.0])
    radar = centre + distance * np.array([math.cos(bearing), math.sin(bearing)])
    # Seen nearly side-on, the centroid may lie on the other side of the radar's line than the centre, and the end
    # taken is then the far one (harmless when the whole side is seen, which is when that happens on a road).
    assume(abs(heading @ (radar - centre)) > length)
    returns = side_returns(centre, heading, length, 1.8, radar, fraction, 6, rng)
    centroid = returns.mean(axis=0)
    found = anchored_position(returns, centroid, heading, radar, length)
    assert abs((found - centre) @ heading) < 1e-9
    across = np.array([-heading[1], heading[0]])
    assert abs((found - centroid) @ across) < 1e-9


def test_track_lengths_take_the_quantile_of_the_moving_scans_extents():
    heading = np.array([0.0, 1.0])
    points = [[np.array([[0.0, 0.0], [0.0, extent], [0.5, 0.2]])] for extent in (1.0, 2.0, 3.0, 4.0)]
    ids = [np.array([7])] * 4
    velocities = [np.array([[0.0, 10.0]])] * 3 + [np.array([[0.0, 0.5]])]   # the last scan is too slow
    assert extent_along(points[3][0], heading) == 4.0
    assert track_lengths(ids, velocities, points, 2.0, 3, 1.0) == {7: 3.0}
    assert track_lengths(ids, velocities, points, 2.0, 3, 0.5) == {7: 2.0}
    assert track_lengths(ids, velocities, points, 2.0, 4, 0.5) == {}


def test_a_crossing_car_whose_returns_slide_along_it_is_tracked_at_its_speed():
    """A car crossing 40 m ahead at 17 m/s, 10 Hz: while it approaches the radar's axis its front and the front
    part of its near side face the radar, then its rear and the rear part; the part seen shrinks towards the axis
    and grows after it, so the returns' centroid slides 1.5 m back along the body within the crossing."""
    rng = np.random.default_rng(3)
    speed, length, dt = 17.0, 4.5, 0.1
    heading = np.array([0.0, 1.0])
    frames, names = [], []
    for t in range(30):
        centre = np.array([40.0, -25.0 + speed * dt * t])
        fraction = float(np.clip(0.2 + abs(centre[1]) / 30.0, 0.2, 1.0))
        planar = side_returns(centre, heading, length, 1.8, np.zeros(2), fraction, 10, rng)
        xyz = np.column_stack([planar, rng.uniform(0.3, 1.4, len(planar))])
        d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        doppler = d[:, :2] @ (speed * heading) + rng.normal(0.0, 0.1, len(xyz))
        frames.append(detect_objects(xyz, doppler, np.ones(len(xyz), bool), np.eye(4), seed=t))
        names.append(f"{t:06d}")
    errors = {}
    for anchored in (False, True):
        document = track_objects(names, np.arange(30) * dt, frames, RadarObjectConfig(anchor_visible_end=anchored))
        tracked = np.array([frame["objects"][0]["velocity"][:2] for frame in document["frames"]])
        errors[anchored] = float(np.mean(tracked[5:-5] @ heading) - speed)
    assert errors[False] < -0.5          # the centroid's slide read as a slower car
    # Near the radar's axis (|cos| of the aspect below 0.3) the scans keep the centroid, loosely: what is left.
    assert abs(errors[True]) < 0.3 and abs(errors[True]) < 0.5 * abs(errors[False]), errors


def test_scans_with_few_returns_or_seen_side_on_keep_the_centroid_loosely_along_the_heading():
    """Three scans of one track heading +y at 10 m/s: 6 returns with the rear facing the radar at |cos| 0.6 are
    anchored; 3 returns, or 6 seen side-on (|cos| 0.1), keep the centroid with std max(1, L / 2) along the heading."""
    from radar4dgs.radar.objects import anchored_measurements, measurement
    from radar4dgs.radar.tracking import TrackedFrame

    config = RadarObjectConfig(anchor_visible_end=True, anchor_min_scans=1)
    heading, length = np.array([0.0, 1.0]), 4.5
    scans = [(np.array([30.0, 22.5]), 6), (np.array([30.0, 22.5]), 3), (np.array([30.0, 3.0]), 6)]
    detections, z, R, tracked = [], [], [], []
    for centre, n in scans:
        # The rear face's two corners' middle and the near side from the rear end forward, 0.9 m apart.
        planar = np.array([[0.0, -length / 2]] + [[-0.9, -length / 2 + 0.9 * k] for k in range(n - 1)]) + centre
        xyz = np.column_stack([planar, np.full(len(planar), 0.8)])
        d = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        found = detect_objects(xyz, d[:, :2] @ (10.0 * heading), np.ones(n, bool), np.eye(4))
        detections.append(found)
        pairs = [measurement(det, config) for det in found]
        z.append(np.array([p[0] for p in pairs]))
        R.append(np.array([p[1] for p in pairs]))
        tracked.append(TrackedFrame(np.array([0]), np.array([[*centre, *(10.0 * heading), 0.0]]),
                                    np.eye(5)[None], np.zeros(1)))
    length_seen = track_lengths([f.ids for f in tracked], [f.states[:, 2:4] for f in tracked],
                                [[det.planar for det in frame] for frame in detections], 2.0, 1, 0.9)[0]
    z2, R2 = anchored_measurements(detections, tracked, z, R, config)
    np.testing.assert_allclose(z2[0][0, :2] @ heading, 22.5 - length / 2 + length_seen / 2, atol=1e-9)
    for k in (1, 2):
        np.testing.assert_array_equal(z2[k], z[k])
        along = max(config.centroid_std, length_seen / 2) ** 2
        np.testing.assert_allclose(R2[k][0, :2, :2], np.diag([config.centroid_std ** 2, along]), atol=1e-12)
    np.testing.assert_array_equal(R2[0], R[0])
