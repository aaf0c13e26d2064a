"""The axis held to the plane the robot's notches bend it in (core.relocation.bend_plane)."""

import dataclasses
import math

import numpy as np
import pytest

from ntcr_recon.core.relocation.bend_plane import base_offset, held_to_bend_plane
from ntcr_recon.core.relocation.centerline import Centerline, base_pose
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

pytestmark = pytest.mark.unit

GEOMETRY = TubeGeometry()
STEP = 1.0e-4


def bent_axis(geometry: TubeGeometry, bend_deg: float) -> tuple[Centerline, TubeShape]:
    """The true axis of the robot bent by bend_deg in all, sampled STEP apart."""
    shape = TubeShape.from_bend_angle(geometry, math.radians(bend_deg))
    s = np.arange(0.0, shape.length, STEP)
    points, frames = shape.centerline(s)
    return Centerline.from_frames(s, points, frames), shape


def off_plane(axis: Centerline, wiggle: float, seed: int = 0) -> Centerline:
    """The axis moved off its bend plane (along the configured binormal) by a depth-like error: smooth along the
    tube, `wiggle` metres RMS."""
    rng = np.random.default_rng(seed)
    binormal = np.asarray(base_pose(GEOMETRY)[2], float)
    knots = rng.normal(0.0, wiggle, 8)
    error = np.interp(axis.s, np.linspace(0.0, axis.length, 8), knots)
    return Centerline.from_points(axis.points + error[:, None] * binormal, binormal, STEP)


def rms_apart(a: Centerline, b: Centerline) -> float:
    s = np.linspace(0.0, min(a.length, b.length), 400)
    return float(np.sqrt(np.mean(np.sum((a.frames_at(s)[0] - b.frames_at(s)[0]) ** 2, axis=1))))


def test_an_axis_off_the_bend_plane_is_held_to_it_at_the_configured_roll():
    truth, _ = bent_axis(GEOMETRY, 45.0)
    seen = off_plane(truth, 0.1e-3)
    plane = held_to_bend_plane(seen, GEOMETRY, truth.length)
    assert rms_apart(seen, truth) > 0.04e-3
    assert rms_apart(plane.centerline, truth) < 0.015e-3
    assert not plane.roll_measured
    assert abs(plane.roll) < math.radians(0.3)
    assert 0.03e-3 < plane.off_plane < 0.1e-3


def test_a_robot_turned_in_its_clamp_is_held_to_the_plane_its_samples_show():
    rolled = dataclasses.replace(GEOMETRY, notch_side=math.radians(10.0))
    truth, _ = bent_axis(rolled, 45.0)
    plane = held_to_bend_plane(off_plane(truth, 0.02e-3), GEOMETRY, truth.length)
    assert plane.roll_measured
    assert math.degrees(plane.roll) == pytest.approx(10.0, abs=0.3)
    assert rms_apart(plane.centerline, truth) < 0.03e-3


def test_a_straight_robot_keeps_the_configured_plane():
    """Even where its axis's error is a tilt that a plane turned 45 deg fits exactly: a robot bent less than its
    radius away from its base's axis shows no plane."""
    truth, _ = bent_axis(GEOMETRY, 0.0)
    plane = held_to_bend_plane(off_plane(truth, 0.05e-3), GEOMETRY, truth.length)
    assert not plane.roll_measured
    assert abs(plane.roll) < math.radians(0.5)
    assert rms_apart(plane.centerline, truth) < 0.01e-3
    tilt = np.outer(truth.s / truth.length * 0.05e-3, [1.0, 1.0, 0.0])  # 0.07 mm off at the tip, diagonally
    tilted = Centerline.from_points(truth.points + tilt, np.asarray(base_pose(GEOMETRY)[2], float), STEP)
    plane = held_to_bend_plane(tilted, GEOMETRY, truth.length)
    assert not plane.roll_measured and plane.roll == 0.0


def test_no_plane_without_a_roll_tolerance_or_before_the_third_notch():
    truth, _ = bent_axis(GEOMETRY, 45.0)
    assert held_to_bend_plane(truth, dataclasses.replace(GEOMETRY, roll_tolerance=None), truth.length) is None
    assert held_to_bend_plane(truth, GEOMETRY, 2.0 * GEOMETRY.notch_pitch) is None


@pytest.mark.parametrize("cameras_along, kept", [("y", (0.0, 0.05)), ("x", (0.95, 1.0))])
def test_the_hold_leaves_of_an_error_along_the_views_what_lies_in_the_plane(cameras_along, kept):
    """Cameras looking along the plane's normal (the robot bends across their views: y for notches opening to +x)
    see every depth error off the plane, and the hold takes it; cameras looking along the notch side see it in the
    plane, where it stays. The plane's own uncertainty: the roll's SD times the samples' distance from the axis."""
    truth, _ = bent_axis(GEOMETRY, 30.0)
    middle = truth.points[len(truth.points) // 2]
    direction = np.array([0.0, 1.0, 0.0]) if cameras_along == "y" else np.array([1.0, 0.0, 0.0])
    origins = np.array([middle - 0.09 * direction, middle + 0.09 * direction])
    plane = held_to_bend_plane(truth, GEOMETRY, truth.length, origins)
    assert kept[0] <= plane.along_views_kept <= kept[1]
    s = np.arange(0.5 * GEOMETRY.notch_pitch, truth.length, GEOMETRY.notch_pitch)
    lateral = truth.frames_at(s)[0][:, 0]
    assert plane.plane_uncertainty == pytest.approx(math.tan(GEOMETRY.roll_tolerance) * np.sqrt(np.mean(lateral**2)))


def test_the_roll_the_plane_shows_weighs_a_side_measured_otherwise_or_rules_it_out():
    axis, _ = bent_axis(GEOMETRY, 45.0)
    plane = held_to_bend_plane(off_plane(axis, 0.02e-3), GEOMETRY, axis.length)
    shown, shown_sd = plane.shown
    assert abs(shown) < 3 * shown_sd < math.radians(1.0)
    # the notches' edges, a few degrees off and known to ten: the plane's, nearly
    roll, sd = plane.weighed_with(math.radians(6.0), math.radians(10.0))
    assert roll == pytest.approx(shown, abs=0.01 * math.radians(6.0))
    assert sd == pytest.approx(shown_sd, rel=0.01)
    assert not plane.rules_out(math.radians(6.0), math.radians(10.0))
    # known to two, twenty degrees off: no roll the plane allows; half a turn round, the same plane
    assert plane.rules_out(math.radians(20.0), math.radians(2.0))
    assert not plane.rules_out(math.pi + shown, math.radians(2.0))
    # a robot bent less than its radius shows no plane: nothing weighed, nothing ruled out
    straight, _ = bent_axis(GEOMETRY, 0.0)
    unbent = held_to_bend_plane(straight, GEOMETRY, straight.length)
    assert unbent.shown is None
    assert unbent.weighed_with(0.3, 0.1) == (0.3, 0.1) and not unbent.rules_out(0.3, 0.01)


def test_the_axis_off_the_base_over_the_proximal_segment_is_measured_as_such():
    """A rigid shift of the whole axis (a camera's pose off along its view) shows in full over the proximal segment,
    whatever the bend; a smooth depth wiggle about the true axis shows as little; no points seen there: None."""
    truth, _ = bent_axis(GEOMETRY, 45.0)
    seen_s = np.linspace(0.3e-3, truth.length, 4000)
    binormal = np.asarray(base_pose(GEOMETRY)[2], float)
    assert base_offset(truth, seen_s, GEOMETRY) == pytest.approx(0.0, abs=1e-9)
    shift = 0.1e-3 * (binormal + np.array([1.0, 0.0, 0.0])) / math.sqrt(2.0)  # along and across the bend plane
    shifted = Centerline.from_points(truth.points + shift, binormal, STEP)
    assert base_offset(shifted, seen_s, GEOMETRY) == pytest.approx(0.1e-3, rel=0.02)
    tilted = Centerline.from_points(truth.points + np.outer(truth.s / truth.length, binormal) * 0.1e-3, binormal,
                                    STEP)  # 0.1 mm off at the tip, nothing at the base
    assert base_offset(tilted, seen_s, GEOMETRY) < 0.015e-3
    assert base_offset(shifted, seen_s[seen_s > GEOMETRY.proximal_length], GEOMETRY) is None
