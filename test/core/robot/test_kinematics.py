"""Kinematics of the parametric NTCR against the asymmetric-notch formulas (York 2015, Swaney 2017)."""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from ntcr_recon.core.base.transforms import quaternion_to_matrix
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape


def neutral_axis_by_hand(r_o, r_i, g):
    d = g - r_o
    phi_o, phi_i = 2 * math.acos(d / r_o), 2 * math.acos(d / r_i)
    area_o = r_o**2 * (phi_o - math.sin(phi_o)) / 2
    area_i = r_i**2 * (phi_i - math.sin(phi_i)) / 2
    ybar_o = 4 * r_o * math.sin(phi_o / 2) ** 3 / (3 * (phi_o - math.sin(phi_o)))
    ybar_i = 4 * r_i * math.sin(phi_i / 2) ** 3 / (3 * (phi_i - math.sin(phi_i)))
    return (ybar_o * area_o - ybar_i * area_i) / (area_o - area_i)


def twist_transform(length, kappa):
    """Arc along local z bending towards local +x, as the exponential of a constant twist."""
    twist = np.zeros((4, 4))
    twist[0, 2], twist[2, 0] = kappa, -kappa  # angular velocity kappa about y
    twist[2, 3] = 1.0  # unit speed along z
    return expm(twist * length)


def chained_tip(geometry, bends):
    """Tip pose by chaining straight and arc transforms, independently of the robot module."""
    h, r_o, r_i = geometry.notch_width, geometry.outer_radius, geometry.inner_radius
    ybar = neutral_axis_by_hand(r_o, r_i, geometry.cut_depth)
    base = np.eye(4)
    base[:3, :3] = quaternion_to_matrix(geometry.base_orientation)
    base[:3, 3] = geometry.base_position
    side = np.eye(4)
    side[:3, :3] = [[math.cos(geometry.notch_side), -math.sin(geometry.notch_side), 0],
                    [math.sin(geometry.notch_side), math.cos(geometry.notch_side), 0], [0, 0, 1]]
    pose = base @ side @ twist_transform(geometry.proximal_length, 0.0)
    for i, theta in enumerate(bends):
        kappa = theta / (h - ybar * theta)  # theta = kappa s, s = h / (1 + ybar kappa)
        pose = pose @ twist_transform(h / (1 + ybar * kappa), kappa)
        spine = geometry.notch_pitch - h if i < len(bends) - 1 else geometry.distal_length
        pose = pose @ twist_transform(spine, 0.0)
    return pose


def test_neutral_axis_and_closing_angle_follow_the_formulas():
    geometry = TubeGeometry()
    ybar = neutral_axis_by_hand(1.75e-3, 1.25e-3, 2.45e-3)
    assert geometry.neutral_axis_offset == pytest.approx(ybar, rel=1e-12)
    assert 1.2e-3 < ybar < 1.27e-3  # the backbone's neutral axis, well away from the notch side
    assert geometry.max_notch_bend == pytest.approx(1.5e-3 / (1.75e-3 + ybar), rel=1e-12)
    assert geometry.gap_half_angle == pytest.approx(math.acos(-0.7 / 1.75))
    assert geometry.length == pytest.approx(5e-3 + 15 * 3e-3 + 1.5e-3 + 1.5e-3)


def test_shallow_cut_that_misses_the_bore_keeps_the_whole_bore_in_the_backbone():
    geometry = TubeGeometry(notch_depth=0.3e-3)  # d = -1.45 mm < -r_i: phi_i = 2 pi
    d = 0.3e-3 - 1.75e-3
    phi_o = 2 * math.acos(d / 1.75e-3)
    area_o = 1.75e-3**2 * (phi_o - math.sin(phi_o)) / 2
    ybar_o = 4 * 1.75e-3 * math.sin(phi_o / 2) ** 3 / (3 * (phi_o - math.sin(phi_o)))
    expected = ybar_o * area_o / (area_o - math.pi * 1.25e-3**2)
    assert geometry.neutral_axis_offset == pytest.approx(expected, rel=1e-12)


def test_tendon_pull_gives_the_curvature_and_arc_length_of_the_formulas():
    geometry = TubeGeometry()
    h, r_i, ybar = 1.5e-3, 1.25e-3, geometry.neutral_axis_offset
    dl = 0.1e-3
    shape = TubeShape.from_tendon_pull(geometry, dl)
    kappa = dl / (h * (r_i + ybar) - dl * ybar)
    s = h / (1 + ybar * kappa)
    np.testing.assert_allclose(shape.notch_curvature, kappa, rtol=1e-12)
    np.testing.assert_allclose(shape.notch_arc_length, s, rtol=1e-12)
    np.testing.assert_allclose(shape.notch_bend, kappa * s, rtol=1e-12)
    np.testing.assert_allclose(shape.tendon_pull, dl, rtol=1e-12)
    assert shape.length == pytest.approx(geometry.length - 16 * (h - s))


@pytest.mark.parametrize("total_deg", [0.0, 45.0, 90.0, 200.0])
def test_tip_of_uniform_bend_matches_chained_arc_transforms(total_deg):
    geometry = TubeGeometry(notch_side=0.7, base_position=(0.01, -0.02, 0.003),
                            base_orientation=(0.0, math.sin(0.2), 0.0, math.cos(0.2)))
    shape = TubeShape.from_bend_angle(geometry, math.radians(total_deg))
    expected = chained_tip(geometry, shape.notch_bend)
    position, frame = shape.tip_pose()
    np.testing.assert_allclose(position, expected[:3, 3], atol=1e-12)
    np.testing.assert_allclose(frame, expected[:3, :3], atol=1e-12)
    # the tip turned by the total bend, about the axis perpendicular to the notch side
    base_axis = geometry.base_rotation[:, 2]
    assert math.degrees(math.acos(np.clip(frame[:, 2] @ base_axis, -1, 1))) == pytest.approx(
        min(total_deg, 360 - total_deg), abs=1e-9)


def test_uniform_planar_bend_tip_lies_in_the_notch_plane_on_the_expected_side():
    geometry = TubeGeometry(notch_side=math.pi / 2)  # notches open towards +y
    position, _ = TubeShape.from_bend_angle(geometry, math.radians(90)).tip_pose()
    assert abs(position[0]) < 1e-12
    assert position[1] > 0.02 and 0.02 < position[2] < geometry.length


def test_non_uniform_profile_matches_chained_arc_transforms():
    geometry = TubeGeometry()
    bends = np.linspace(0.0, geometry.max_notch_bend, geometry.notch_count)
    shape = TubeShape.from_notch_bends(geometry, bends)
    position, frame = shape.tip_pose()
    expected = chained_tip(geometry, bends)
    np.testing.assert_allclose(position, expected[:3, 3], atol=1e-12)
    np.testing.assert_allclose(frame, expected[:3, :3], atol=1e-12)


def test_centerline_is_arc_length_parametrised_and_frames_orthonormal():
    shape = TubeShape.from_bend_angle(TubeGeometry(), math.radians(120))
    s = np.linspace(0.0, shape.length, 20001)
    points, frames = shape.centerline(s)
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert steps.sum() == pytest.approx(shape.length, rel=1e-6)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", frames, frames), np.broadcast_to(np.eye(3), frames.shape),
                               atol=1e-12)
    tangents = np.diff(points, axis=0) / steps[:, None]
    np.testing.assert_allclose(tangents, frames[:-1, :, 2], atol=2e-3)
    with pytest.raises(ValueError, match="arc length outside"):
        shape.centerline([shape.length + 1e-4])


def test_notch_table_widths_close_with_bending():
    geometry = TubeGeometry()
    straight = TubeShape.straight(geometry).notch_table()
    assert [n["width"] for n in straight] == pytest.approx([1.5e-3] * 16)
    np.testing.assert_allclose([n["center_s"] for n in straight], geometry.notch_centers_s, atol=1e-15)
    shape = TubeShape.from_bend_angle(geometry, math.radians(90))
    theta = math.radians(90) / 16
    for notch in shape.notch_table():
        assert notch["width"] == pytest.approx(1.5e-3 - theta * (1.75e-3 + geometry.neutral_axis_offset), rel=1e-9)
    closed = TubeShape.from_notch_bends(geometry, np.full(16, geometry.max_notch_bend)).notch_table()
    assert max(n["width"] for n in closed) == pytest.approx(0.0, abs=1e-15)


def test_a_bend_beyond_the_closing_angle_is_refused():
    geometry = TubeGeometry()
    limit = geometry.max_notch_bend * 16
    with pytest.raises(ValueError, match="theta_max"):
        TubeShape.from_bend_angle(geometry, limit * 1.01)
    with pytest.raises(ValueError, match="negative"):
        TubeShape.from_bend_angle(geometry, -0.1)
    with pytest.raises(ValueError, match="16 values"):
        TubeShape.from_notch_bends(geometry, [0.1, 0.2])


@pytest.mark.parametrize(("fields", "message"), [
    ({"notch_depth": 3.6e-3}, "notch_depth .* less than robot.outer_diameter"),
    ({"notch_pitch": 1.0e-3}, "notch_pitch .* overlap"),
    ({"inner_diameter": 4e-3}, "inner_diameter"),
    ({"notch_count": 0}, "notch_count"),
    ({"base_orientation": (0, 0, 0, 2)}, "base_orientation"),
    ({"outer_diameter": float("nan")}, "outer_diameter"),
])
def test_invalid_geometry_is_refused_naming_the_field(fields, message):
    with pytest.raises(ValueError, match=message):
        TubeGeometry(**fields).validate()


def test_from_mapping_round_trips_and_names_bad_keys():
    geometry = TubeGeometry(notch_side=1.0, base_position=(0.0, 0.001, 0.0))
    assert TubeGeometry.from_mapping(geometry.to_dict()) == geometry
    with pytest.raises(ValueError, match="robot.notch_cout"):
        TubeGeometry.from_mapping({"notch_cout": 16})
    with pytest.raises(ValueError, match="robot.notch_width"):
        TubeGeometry.from_mapping({"notch_width": "wide"})
    with pytest.raises(ValueError, match="robot.base_position"):
        TubeGeometry.from_mapping({"base_position": [0.0, 1.0]})


@pytest.mark.parametrize("bends_deg", [np.linspace(0.0, 9.0, 16), np.zeros(16), np.full(16, 3.0)])
def test_centerline_jacobian_is_the_derivative_of_the_centreline_by_each_bend(bends_deg):
    geometry = TubeGeometry(notch_side=0.7)
    shape = TubeShape(geometry, np.radians(bends_deg))
    s = np.linspace(0.0, shape.length - 1e-5, 1200)  # (the tip itself moves off the shortened robot)
    jacobian = shape.centerline_jacobian(s)
    step = 1e-6
    for notch in (0, 7, 15):
        bends = shape.notch_bend.copy()
        bends[notch] += step
        moved = TubeShape(geometry, bends)
        numeric = (moved.centerline_points(s) - shape.centerline_points(s)) / step
        # (forward differences: O(step))
        np.testing.assert_allclose(jacobian[:, notch], numeric, atol=1e-4 * np.abs(numeric).max())
    # nothing proximal of a notch moves with its bend
    assert not np.any(jacobian[s < shape.notch_table()[7]["start_s"], 7])
