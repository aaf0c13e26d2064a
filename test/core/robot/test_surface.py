"""The sampled true surface of the NTCR: notches where the parameters put them, rings of the right radii."""

import math

import numpy as np
import pytest

from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.core.robot.surface import PART_CUT_FACE, PART_OUTER_WALL

SPACING = 0.05e-3


@pytest.fixture(scope="module")
def straight():
    shape = TubeShape.straight(TubeGeometry())
    return shape, shape.sample_surface(SPACING)


@pytest.fixture(scope="module")
def bent():
    shape = TubeShape.from_bend_angle(TubeGeometry(notch_side=math.pi / 2), math.radians(90))
    return shape, shape.sample_surface_parts(SPACING)


def test_straight_notches_counted_and_measured_on_the_surface_line_facing_them(straight):
    shape, (points, _) = straight
    # outer-surface points on the line facing the notches (+x, angle 0), found from coordinates alone
    radius = np.hypot(points[:, 0], points[:, 1])
    angle = np.arctan2(points[:, 1], points[:, 0])
    line = points[(np.abs(radius - 1.75e-3) < 1e-6) & (np.abs(angle) < 0.02), 2]
    z = np.unique(np.round(line, 9))
    gaps = np.diff(z)
    open_gaps = gaps > 5 * SPACING
    assert open_gaps.sum() == 16
    np.testing.assert_allclose(gaps[open_gaps], 1.5e-3, atol=1e-9)
    np.testing.assert_allclose((z[:-1][open_gaps] + z[1:][open_gaps]) / 2, shape.geometry.notch_centers_s, atol=1e-9)


def test_no_notch_on_the_backbone_side(straight):
    _, (points, _) = straight
    radius = np.hypot(points[:, 0], points[:, 1])
    angle = np.arctan2(points[:, 1], points[:, 0])
    line = np.sort(points[(np.abs(radius - 1.75e-3) < 1e-6) & (np.abs(np.abs(angle) - math.pi) < 0.02), 2])
    assert np.diff(line).max() <= SPACING + 1e-12
    assert line[0] == pytest.approx(0.0, abs=1e-12) and line[-1] == pytest.approx(0.053, abs=1e-12)


def test_spine_cross_section_is_a_ring_of_the_tube_radii(bent):
    shape, sample = bent
    notches = shape.notch_table()
    mid = (notches[7]["end_s"] + notches[8]["start_s"]) / 2  # middle of a spine in the bent section
    centre, frame = shape.centerline([mid])
    offset = sample.points - centre[0]
    axial = offset @ frame[0][:, 2]
    in_plane = offset[np.abs(axial) < SPACING / 2] @ frame[0][:, :2]
    assert len(in_plane) > 200

    def fit_circle(xy):  # algebraic (Kasa) circle fit
        design = np.column_stack([2 * xy, np.ones(len(xy))])
        (a, b, c), *_ = np.linalg.lstsq(design, (xy**2).sum(axis=1), rcond=None)
        return np.array([a, b]), math.sqrt(c + a * a + b * b)

    distance = np.linalg.norm(in_plane - in_plane.mean(axis=0), axis=1)
    outer_centre, outer_r = fit_circle(in_plane[distance > 1.5e-3])
    inner_centre, inner_r = fit_circle(in_plane[distance < 1.5e-3])
    assert outer_r == pytest.approx(1.75e-3, abs=1e-7)
    assert inner_r == pytest.approx(1.25e-3, abs=1e-7)
    assert np.linalg.norm(outer_centre) < 1e-7 and np.linalg.norm(inner_centre) < 1e-7


def test_bent_notch_widths_on_the_surface_equal_the_truth_table(bent):
    shape, sample = bent
    r_o = shape.geometry.outer_radius
    # the cut faces' outer edges on the line facing the notches
    edge = (sample.part == PART_CUT_FACE) & (np.abs(sample.radius - r_o) < 1e-9) & (np.abs(sample.angle) < 1e-9)
    s_edges = sample.s[edge]
    points = sample.points[edge]
    table = shape.notch_table()
    assert len(table) == 16
    for notch in table:
        proximal = points[np.isclose(s_edges, notch["start_s"], atol=1e-12)]
        distal = points[np.isclose(s_edges, notch["end_s"], atol=1e-12)]
        assert len(proximal) == 1 and len(distal) == 1
        chord = np.linalg.norm(distal[0] - proximal[0])
        theta = notch["bend"]
        arc = chord * (theta / 2) / math.sin(theta / 2)  # the outer line is an arc of angle theta
        assert arc == pytest.approx(notch["width"], abs=1e-9)
        assert notch["width"] < 1.5e-3 - 1e-4  # visibly closed by the bend


def test_outer_wall_points_sit_at_the_outer_radius_from_the_bent_centerline(bent):
    shape, sample = bent
    wall = sample.part == PART_OUTER_WALL
    centre, _ = shape.centerline(sample.s[wall])
    np.testing.assert_allclose(np.linalg.norm(sample.points[wall] - centre, axis=1), 1.75e-3, atol=1e-12)
    steps = np.abs(np.diff(np.sort(sample.s[wall])))
    assert steps.max() <= SPACING * (1 + 1e-9)


def test_surface_distance_of_offset_points(bent):
    shape, sample = bent
    rng = np.random.default_rng(0)
    pick = rng.choice(np.flatnonzero(sample.part == PART_OUTER_WALL), 2000, replace=False)
    for offset in (0.0, 0.1e-3, 0.3e-3):
        points = sample.points[pick] + offset * sample.normals[pick]
        np.testing.assert_allclose(shape.surface_distance(points), offset, atol=2e-6)
