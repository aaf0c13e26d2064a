"""relocation.tip: the tube's end from its wall (what a camera can see of it), carried on to the robot's length
where it is hidden, and the end cap of a tube pointing at a camera. Points are drawn analytically on the true
surface (no renderer), so every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import FOOTPRINT, GEOMETRY, R_O, straight_centerline, true_centerline, wall_points

from ntcr_recon.core.relocation.bends import continued_bend
from ntcr_recon.core.relocation.tip import TipAlongTube, carried_to_length, tube_end, visible_sectors
from ntcr_recon.core.robot.kinematics import TubeShape


def test_tip_of_a_straight_tube_is_its_end_and_never_past_the_robot():
    length = 30e-3
    centerline = straight_centerline(length + 5e-3)
    coords = centerline.project(wall_points(length, rng=np.random.default_rng(1)))
    end = tube_end(coords, R_O, 0.8e-3, FOOTPRINT)
    print(f"\nstraight tube end {end * 1e3:.3f} mm (true {length * 1e3:.1f})")
    assert abs(end - length) < FOOTPRINT
    # a backdrop-like blob of wall-radius points beyond the robot's length is not searched
    far = centerline.project(wall_points(length + 4e-3, start=length + 1e-3))
    both = type(coords)(np.concatenate([coords.s, far.s]), np.concatenate([coords.x, far.x]),
                        np.concatenate([coords.y, far.y]))
    assert tube_end(both, R_O, 0.8e-3, FOOTPRINT, max_s=length + 0.5e-3) <= length + 0.5e-3


def test_tip_of_a_tube_seen_from_one_side_only_counts_what_the_camera_can_see():
    """The distal part pointing away from one camera: only the other sees it, one half of the ring."""
    length, seen_alone_from = 30e-3, 20e-3
    centerline = straight_centerline(length + 5e-3)
    both_sides = wall_points(seen_alone_from)
    one_side = wall_points(length, angles=(-math.pi, 0.0), start=seen_alone_from)  # the -y half
    coords = centerline.project(np.concatenate([both_sides, one_side]))
    cameras = np.array([[0.0, -0.09, 0.02], [0.0, 0.09, 0.02]])
    blind = tube_end(coords, R_O, 0.8e-3, FOOTPRINT)
    # cam_b (at +y) is switched off past 20 mm: it is not among the viewpoints judging the end
    aware = tube_end(coords, R_O, 0.8e-3, FOOTPRINT, centerline=centerline, viewpoints=cameras[:1])
    print(f"\none side seen past 20 mm: end {blind * 1e3:.2f} mm counting every sector, "
          f"{aware * 1e3:.2f} mm counting the visible ones (true {length * 1e3:.0f})")
    assert abs(aware - length) < FOOTPRINT
    sectors = visible_sectors(centerline, np.array([10e-3]), cameras[:1], 24)[0]
    assert 8 <= np.count_nonzero(sectors) <= 12  # about half the ring faces one camera


def test_tip_of_a_tube_pointing_at_a_camera_uses_any_wall_point():
    """No sector faces a camera on the tube's axis: every wall point counts, the end is still found."""
    length = 25e-3
    centerline = straight_centerline(length + 5e-3)
    coords = centerline.project(wall_points(length, angles=(-0.5, 0.5)))  # a sliver of the wall only
    on_axis = np.array([[0.0, 0.0, 0.12]])
    assert not visible_sectors(centerline, np.array([20e-3]), on_axis, 24).any()
    end = tube_end(coords, R_O, 0.8e-3, FOOTPRINT, centerline=centerline, viewpoints=on_axis)
    print(f"\ntube pointing at the camera: end {end * 1e3:.2f} mm (true {length * 1e3:.0f})")
    assert abs(end - length) < 2 * FOOTPRINT


def test_a_tip_hidden_from_every_camera_is_carried_on_to_the_robots_length():
    """A 90 deg robot seen to 40 mm of its 51: the tip carried on bending to the robot's length lands on the true
    tip (the seen end is 11 mm short of it); how far a straight hidden part would leave it across the tube is its
    uncertainty there, and along it the length's, with what the straight part would leave it ahead or short."""
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(90.0))
    truth = true_centerline(shape)
    centres = np.array([n["center_s"] for n in shape.notch_table()])
    carried = continued_bend(truth.up_to(40e-3), GEOMETRY.reach, centres, GEOMETRY)
    seen = TipAlongTube(40e-3, 0.1e-3, 40e-3, 0.1e-3, shape.length, 0.1e-3)
    tip = carried_to_length(seen, carried)
    true_tip = shape.centerline(np.array([shape.length]))[0][0]
    landed = np.linalg.norm(carried.frames_at(np.array([tip.s]))[0][0] - true_tip)
    seen_off = np.linalg.norm(carried.frames_at(np.array([seen.s]))[0][0] - true_tip)
    print(f"\ncarried {(tip.s - seen.s) * 1e3:.1f} mm: {landed * 1e3:.3f} mm off the true tip (the end seen "
          f"{seen_off * 1e3:.1f}); stated {tip.uncertainty * 1e3:.2f} mm along, {tip.hidden_across * 1e3:.2f} across")
    assert tip.s == shape.length and tip.beyond_seen and not tip.length_weighed
    assert landed < 0.005e-3 and seen_off > 10e-3
    # were the hidden 11 mm straight on along the end seen's tangent, the tip would lie this far off
    position, tangent = (a[0] for a in truth.frames_at(np.array([40e-3]))[:2])
    straight_off = position + (shape.length - 40e-3) * tangent - true_tip
    true_tangent = shape.centerline(np.array([shape.length]))[1][0][:, 2]
    ahead = straight_off @ true_tangent
    assert tip.hidden_across == pytest.approx(np.linalg.norm(straight_off - ahead * true_tangent), rel=1e-3)
    assert tip.uncertainty == pytest.approx(math.hypot(0.1e-3, ahead), rel=1e-3)
    assert 1e-3 < tip.hidden_across < 11e-3


def test_a_pile_up_on_the_wall_or_at_a_notch_face_is_no_end_cap():
    """A tube pointing at a camera whose last 5 mm lie nearer it than its depth range: the wall stops at 25 mm
    with its points piled up there (a ring at the wall's radius), and a notch's cut face turned to the camera piles
    its points up on a half annulus at 23.5 mm. Neither is the cap: a cap fills the annulus, past the last notch."""
    from ntcr_recon.core.relocation.tip import end_cap_plane

    centerline = straight_centerline(35e-3)
    rng = np.random.default_rng(7)
    wall = wall_points(25e-3, spacing=0.4e-3)
    angle = rng.uniform(-math.pi, math.pi, 400)
    ring = np.stack([R_O * np.cos(angle), R_O * np.sin(angle), np.full(400, 25e-3)], axis=1)
    coords = centerline.project(np.concatenate([wall, ring]))
    assert end_cap_plane(coords, GEOMETRY.inner_radius, R_O, 25.3e-3, GEOMETRY.outer_diameter, FOOTPRINT) is None
    radius = rng.uniform(GEOMETRY.inner_radius, R_O, 400)
    half = rng.uniform(-math.pi / 2, math.pi / 2, 400)  # the notch side's half of the annulus
    face = np.stack([radius * np.cos(half), radius * np.sin(half), np.full(400, 23.5e-3)], axis=1)
    coords = centerline.project(np.concatenate([wall, face]))
    found = end_cap_plane(coords, GEOMETRY.inner_radius, R_O, 25.3e-3, GEOMETRY.outer_diameter, FOOTPRINT)
    assert found is not None and abs(found[0] - 23.5e-3) < FOOTPRINT  # the face, taken for the cap
    last_cut = 23.5e-3  # the face is the last notch's far edge: the cap lies the distal ring past it
    assert end_cap_plane(coords, GEOMETRY.inner_radius, R_O, 25.3e-3, GEOMETRY.outer_diameter, FOOTPRINT,
                         after=last_cut + GEOMETRY.distal_length / 2) is None


def test_end_cap_of_a_tube_pointing_at_a_camera_places_the_tip():
    """Thin wall, a dense cap at 25 mm and a few flying pixels trailing behind it along the axis."""
    from ntcr_recon.core.relocation.tip import cap_faces_a_camera, end_cap_plane

    length = 25e-3
    centerline = straight_centerline(length + 5e-3)
    rng = np.random.default_rng(6)
    wall = wall_points(length, spacing=0.4e-3)
    radius = rng.uniform(GEOMETRY.inner_radius, R_O, 400)
    angle = rng.uniform(-math.pi, math.pi, 400)
    cap = np.stack([radius * np.cos(angle), radius * np.sin(angle), np.full(400, length)], axis=1)
    trail = np.stack([np.full(12, R_O), np.zeros(12), length + rng.uniform(0.2e-3, 1.5e-3, 12)], axis=1)
    coords = centerline.project(np.concatenate([wall, cap, trail]))
    on_axis = np.array([[0.0, 0.0, 0.12]])
    assert cap_faces_a_camera(centerline, length, on_axis, math.sin(math.radians(45)))
    assert not cap_faces_a_camera(centerline, length, np.array([[0.0, -0.09, 0.02]]), math.sin(math.radians(45)))
    plane, smear = end_cap_plane(coords, GEOMETRY.inner_radius, R_O, length + 0.6e-3, GEOMETRY.outer_diameter,
                                 FOOTPRINT)
    print(f"\ncap plane at {plane * 1e3:.3f} mm (true {length * 1e3:.0f}), smear {smear * 1e3:.3f} mm")
    assert abs(plane - length) < FOOTPRINT / 4 and smear < FOOTPRINT / 4
    # a ring narrower than the matcher's window: every cap pixel mixed with the bore behind, pulled up to
    # 1 mm away from the camera (less s), more often a little than much
    pulled = cap - np.stack([np.zeros(400), np.zeros(400), 1e-3 * rng.uniform(0.0, 1.0, 400) ** 2], axis=1)
    coords = centerline.project(np.concatenate([wall, pulled, trail]))
    plane, smear = end_cap_plane(coords, GEOMETRY.inner_radius, R_O, length + 0.6e-3, GEOMETRY.outer_diameter,
                                 FOOTPRINT)
    print(f"mixed with the bore: cap plane at {plane * 1e3:.3f} mm, smear {smear * 1e3:.3f} mm")
    assert abs(plane - length) < FOOTPRINT / 2 and smear > FOOTPRINT / 2   # (the median alone: 0.2 mm short)
