"""relocation.backbone: the axis levelled between the notches by the camera facing the backbone, by the wall its
matcher keeps clear of the slots or, seeing none, by all it faces. Points are drawn analytically on the true surface
(no renderer), so every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import (
    FOOTPRINT,
    GEOMETRY,
    R_O,
    beyond_slot_edge,
    cameras_round_the_tube,
    straight_centerline,
    wall_points,
)

from ntcr_recon.core.relocation import alignment
from ntcr_recon.core.relocation.alignment import WallTrust
from ntcr_recon.core.relocation.backbone import level_by_backbone
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.robot.comb import cut_intervals, inside_intervals, near_cuts


def test_the_camera_facing_the_backbone_levels_the_axis_between_the_notches():
    """Notches open to +x; cam_a looks at them from +x and reads the wall between them 0.3 mm deep (its matcher
    reaches into the slots), cam_b faces the backbone from -x and reads it as on the plain tube. An axis put
    0.15 mm towards cam_b there (the two cameras' difference split between them, as a common level does) is moved
    back by cam_b's level on the plain stretches; seen side-on by both cameras, nothing is moved."""
    length = GEOMETRY.length
    points = wall_points(length, rng=np.random.default_rng(7))
    first, last = GEOMETRY.proximal_length, length - GEOMETRY.distal_length
    between = (points[:, 2] > first) & (points[:, 2] < last)
    s = np.linspace(0.0, length, int(length / 0.1e-3) + 1)
    lean = -0.15e-3 * np.clip(np.minimum(s - first, last - s) / 1e-3, 0.0, 1.0)
    given = Centerline.from_points(np.stack([lean, np.zeros_like(s), s], axis=1), np.array([0.0, 1.0, 0.0]), 0.1e-3)

    def levelled(origins):
        camera = (np.einsum("ij,cj->ic", points[:, :2], origins[:, :2]).argmax(axis=1)).astype(np.intp)
        seen = points.copy()
        deep = between & (camera == 0)  # cam_a: the notch side's
        seen[deep, :2] *= (1 - 0.3e-3 / R_O)
        coords, frames = given.project_with_frames(seen)
        return level_by_backbone(given, coords, frames, origins[camera], camera, origins,
                                 WallTrust(GEOMETRY, 0.8e-3, FOOTPRINT, length))

    moved, rms = levelled(np.array([[0.09, 0.0, 0.025], [-0.09, 0.0, 0.025]]))
    middle = moved.points[(moved.s > 15e-3) & (moved.s < 40e-3)]
    print(f"\naxis between the notches now at x = {middle[:, 0].min() * 1e3:+.3f} .. {middle[:, 0].max() * 1e3:+.3f} "
          f"mm (given -0.150), moved by {rms * 1e3:.3f} mm RMS")
    assert np.abs(middle[:, 0]).max() < 0.02e-3 and np.abs(middle[:, 1]).max() < 0.01e-3
    assert rms == pytest.approx(0.15e-3, abs=0.02e-3)
    side_on, none = levelled(np.array([[0.0, 0.09, 0.025], [0.0, -0.09, 0.025]]))
    assert side_on is given and none == 0.0


def leaning_between_the_notches(toward: np.ndarray, lean: float) -> tuple[np.ndarray, Centerline]:
    """A straight axis along z put `lean` (m) towards the direction `toward` (x, y) between the first and the last
    cut, ramped over 1 mm at each: (its samples' s, the axis)."""
    length, first = GEOMETRY.length, GEOMETRY.proximal_length
    last = length - GEOMETRY.distal_length
    s = np.linspace(0.0, length, int(length / 0.1e-3) + 1)
    off = lean * np.clip(np.minimum(s - first, last - s) / 1e-3, 0.0, 1.0)
    return s, Centerline.from_points(np.stack([off * toward[0], off * toward[1], s], axis=1),
                                     np.array([0.0, 1.0, 0.0]), 0.1e-3)


def test_a_camera_just_past_the_gaps_edge_levels_the_axis_by_the_wall_its_matcher_keeps_clear_of_the_slots():
    """One camera faces the backbone from 137 deg round the tube from the notch side, 23 deg past the gap's edge (113.6
    deg): in its image that edge lies 0.7 mm (3.5 px) from the tube's middle, and between the notches its matcher's
    window reaches into the slots from the wall within 3 px of it, which reads 0.2 mm deep. The axis is where it
    truly is: levelled by the wall clear of the slots in that camera's image, it stays there (by all the wall facing
    it, it was moved 0.04 mm). The other camera looks into the slots."""
    length = GEOMETRY.length
    points = wall_points(length, rng=np.random.default_rng(8))
    coords = straight_centerline(length).project(points)
    cuts = cut_intervals(GEOMETRY, straight_centerline(length), 0.0)
    in_cut = inside_intervals(points[:, 2], cuts) & (np.abs(coords.angle) < GEOMETRY.gap_half_angle)
    points = points[~in_cut]  # the slots
    angles, origins, camera = cameras_round_the_tube([137.0, -43.0], points)
    beyond_edge = beyond_slot_edge(points, angles[0])  # across the backbone camera's view
    reach = 3 * FOOTPRINT
    near_slot = inside_intervals(points[:, 2], cut_intervals(GEOMETRY, straight_centerline(length), reach))
    deep = (camera == 0) & near_slot & (beyond_edge < reach)
    deep |= (camera == 1) & (points[:, 2] > GEOMETRY.proximal_length)  # the notch side's camera sees every slot
    seen = points.copy()
    seen[deep, :2] *= 1 - 0.2e-3 / R_O
    given = straight_centerline(length)
    coords, frames = given.project_with_frames(seen)
    moved, rms = level_by_backbone(given, coords, frames, origins[camera], camera, origins,
                                   WallTrust(GEOMETRY, 0.8e-3, FOOTPRINT, length))
    shift = moved.frames_at(given.s)[0] - given.points
    print(f"\naxis moved by {rms * 1e3:.3f} mm RMS, at most {np.abs(shift).max() * 1e3:.3f} mm")
    assert np.abs(shift).max() < 0.02e-3


def test_a_camera_that_sees_no_wall_clear_of_the_slots_levels_by_all_the_wall_facing_it():
    """At 0.3 mm a pixel a camera 6 deg past the gap's edge (120 deg from the notch side) sees its edge within a
    matcher's reach (4 px) of all the wall facing it: none is clear of the slots. It reads that wall as on the plain
    tube (a matcher that keeps the slot out of the wall's window), the other camera looks into the slots and reads
    it 0.3 mm deep: an axis put 0.15 mm towards the first camera is moved back by the first camera's level."""
    footprint, length = 0.3e-3, GEOMETRY.length
    points = wall_points(length, spacing=footprint, rng=np.random.default_rng(9))
    first, last = GEOMETRY.proximal_length, length - GEOMETRY.distal_length
    angles, origins, camera = cameras_round_the_tube([120.0, -60.0], points)
    toward = np.array([np.cos(angles[0]), np.sin(angles[0])])
    s, given = leaning_between_the_notches(toward, 0.15e-3)
    seen = points.copy()
    deep = (points[:, 2] > first) & (points[:, 2] < last) & (camera == 1)
    seen[deep, :2] *= 1 - 0.3e-3 / R_O
    coords, frames = given.project_with_frames(seen)
    reach = alignment.SILHOUETTE_MARGIN_PX * footprint  # across the view and along s, as level_by_backbone's
    near_cut = near_cuts(coords.s, GEOMETRY, given, reach)
    assert not np.any(alignment.clear_of_slots_in_view(coords, frames, origins[camera], GEOMETRY, near_cut, reach)
                      & (camera == 0) & (points[:, 2] > first) & (points[:, 2] < last)
                      & (np.abs(coords.angle - angles[0]) < math.radians(20.0)))
    moved, rms = level_by_backbone(given, coords, frames, origins[camera], camera, origins,
                                   WallTrust(GEOMETRY, 0.8e-3, footprint, length))
    middle = moved.frames_at(s[(s > 15e-3) & (s < 40e-3)])[0]
    print(f"\naxis between the notches now {np.abs(middle[:, :2] @ toward).max() * 1e3:.3f} mm towards the "
          f"first camera at most (given 0.150), moved by {rms * 1e3:.3f} mm RMS")
    assert np.abs(middle[:, :2]).max() < 0.03e-3


def test_a_camera_that_sees_wall_clear_of_the_slots_in_one_window_only_levels_by_all_the_wall_facing_it():
    """A camera facing the backbone from 137 deg sees wall clear of the slots in its image in one window between the
    notches only (the rest of that wall lost, as to a matcher's dropouts); all the wall facing it reads as on the
    plain tube. An axis put 0.15 mm towards it is moved back over the whole notched stretch: one window's few points
    do not decide for the others, which level by all the camera's facing wall."""
    length = GEOMETRY.length
    points = wall_points(length, rng=np.random.default_rng(10))
    first, last = GEOMETRY.proximal_length, length - GEOMETRY.distal_length
    angles, origins, camera = cameras_round_the_tube([137.0, -43.0], points)
    toward = np.array([np.cos(angles[0]), np.sin(angles[0])])
    s, given = leaning_between_the_notches(toward, 0.15e-3)
    coords, frames = given.project_with_frames(points)
    reach = alignment.SILHOUETTE_MARGIN_PX * FOOTPRINT  # across the view and along s, as level_by_backbone's
    clear = alignment.clear_of_slots_in_view(coords, frames, origins[camera], GEOMETRY,
                                             near_cuts(coords.s, GEOMETRY, given, reach), reach)
    notched = (points[:, 2] > first) & (points[:, 2] < last)
    one_window = (points[:, 2] > 19.2e-3) & (points[:, 2] < 22.4e-3)
    kept = ~(clear & notched & ~one_window & (camera == 0))
    seen = points[kept]
    deep = notched[kept] & (camera[kept] == 1)  # the other camera looks into the slots
    seen[deep, :2] *= 1 - 0.3e-3 / R_O
    coords, frames = given.project_with_frames(seen)
    moved, rms = level_by_backbone(given, coords, frames, origins[camera[kept]], camera[kept], origins,
                                   WallTrust(GEOMETRY, 0.8e-3, FOOTPRINT, length))
    middle = moved.frames_at(s[(s > 10e-3) & (s < 40e-3)])[0]
    print(f"\naxis between the notches now {np.abs(middle[:, :2] @ toward).max() * 1e3:.3f} mm towards the camera "
          f"facing the backbone at most (given 0.150)")
    assert np.abs(middle[:, :2]).max() < 0.03e-3
