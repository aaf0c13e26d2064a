"""The calibration's distance of points to the robot's tube, and its bends' Jacobian against finite differences."""

import numpy as np

from ntcr_recon.core.calibration.tube_distance import bend_jacobian, tube_distance
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

GEOMETRY = TubeGeometry()
RADIUS = GEOMETRY.outer_radius


def test_a_point_off_the_straight_wall_is_as_far_as_it_lies_off_the_radius():
    shape = TubeShape.straight(GEOMETRY)
    angles = np.linspace(0.0, 2 * np.pi, 7, endpoint=False)
    offsets = np.array([0.2e-3, -0.3e-3, 0.05e-3, 0.0, 0.1e-3, -0.1e-3, 0.4e-3])
    radial = np.stack([np.cos(angles), np.sin(angles), np.zeros(7)], axis=1)
    points = radial * (RADIUS + offsets)[:, None] + [0.0, 0.0, 0.02]
    measured = tube_distance(shape, points)
    np.testing.assert_allclose(measured.distance, offsets, atol=1e-9)
    np.testing.assert_allclose(measured.direction, radial, atol=1e-9)
    np.testing.assert_allclose(measured.foot_s, 0.02, atol=1e-9)
    assert not measured.below_base.any()


def test_the_far_half_seen_from_a_camera_is_further_off_than_its_wall_distance():
    shape = TubeShape.straight(GEOMETRY)
    camera = np.array([0.0, -0.09, 0.02])
    near = np.array([[0.0, -RADIUS - 0.1e-3, 0.02]])
    far = np.array([[0.0, RADIUS + 0.1e-3, 0.02]])
    assert tube_distance(shape, near, camera).distance[0] == np.float64(tube_distance(shape, near).distance[0])
    behind = tube_distance(shape, far, camera)
    assert behind.distance[0] > RADIUS  # the mirrored half lies a radius behind the limbs' plane
    assert tube_distance(shape, far).distance[0] < 0.2e-3


def test_past_the_tip_the_end_cap_and_past_the_base_the_clamp():
    shape = TubeShape.straight(GEOMETRY)
    length = shape.length
    points = np.array([[0.0, 0.0, length + 0.3e-3],           # on the axis beyond the cap
                       [0.5e-3, 0.0, length - 0.1e-3],         # inside, nearer the cap than the wall
                       [RADIUS + 0.3e-3, 0.0, length + 0.4e-3],  # beyond the cap's rim
                       [0.0, RADIUS, -1e-3]])                   # below the base: the clamp's post
    measured = tube_distance(shape, points)
    np.testing.assert_allclose(measured.distance[:3], [0.3e-3, -0.1e-3, 0.5e-3], atol=1e-9)
    assert measured.below_base.tolist() == [False, False, False, True]


def test_the_bends_jacobian_is_the_distance_change_under_a_bend_profile():
    shape = TubeShape(GEOMETRY, np.linspace(0.06, 0.03, GEOMETRY.notch_count))
    rng = np.random.default_rng(3)
    s = rng.uniform(0.0, shape.length * 0.95, 300)
    centres, frames = shape.centerline(s)
    angle = rng.uniform(0, 2 * np.pi, 300)
    points = centres + (RADIUS + rng.normal(0, 0.1e-3, 300))[:, None] * (
        np.cos(angle)[:, None] * frames[:, :, 0] + np.sin(angle)[:, None] * frames[:, :, 1])
    measured = tube_distance(shape, points)
    place = np.linspace(0.0, 1.0, GEOMETRY.notch_count)
    changes = np.stack([1.0 - place, place])
    columns = bend_jacobian(shape, measured.foot_s, measured.direction, changes)
    for column, change in enumerate(changes):
        step = 1e-5
        ahead = tube_distance(TubeShape(GEOMETRY, shape.notch_bend + step * change), points).distance
        behind = tube_distance(TubeShape(GEOMETRY, shape.notch_bend - step * change), points).distance
        numeric = (ahead - behind) / (2 * step)
        assert np.linalg.norm(columns[:, column] - numeric) < 0.02 * np.linalg.norm(numeric)
