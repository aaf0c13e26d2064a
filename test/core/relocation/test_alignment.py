"""relocation.alignment: the reference moved onto the wall a camera faces (trusted points, gated and smoothed
shifts), kept between cameras, clear of silhouette bulges and of the wall read into the slots. Points are drawn
analytically on the true surface (no renderer), so every figure is known exactly; each number asserted is printed."""

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
from ntcr_recon.core.relocation.alignment import WallTrust, align_to_trusted_wall
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.robot.comb import cut_intervals, inside_intervals
from ntcr_recon.core.robot.geometry import TubeGeometry


def test_alignment_moves_the_reference_onto_the_facing_wall_and_reports_the_shift():
    """A straight tube whose true axis lies 0.1 mm towards the notch side of the given centreline. Beyond the last
    window's trusted points (which keep a margin from the end) the end of the axis moves by the shift the wall
    before it measured, not back towards the given axis (a taper to none at the end turned the last spine's
    chord by 0.1 mm over a few millimetres: 2-4 degrees of the last notch's bend)."""
    length, shift = 30e-3, 0.1e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, rng=np.random.default_rng(2))
    points[:, 0] += shift
    centerline = straight_centerline(length)
    coords, frames = centerline.project_with_frames(points)
    viewpoints = np.where(points[:, 1:2] < 0, [[0.0, -0.09, 0.015]], [[0.0, 0.09, 0.015]])
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints,
                                   WallTrust(geometry, 0.8e-3, FOOTPRINT, length))
    moved = result.centerline.points[(result.centerline.s > 5e-3) & (result.centerline.s < 25e-3)]
    print(f"\nalignment: bias {result.bias_notch_side * 1e3:+.3f} mm measured (true {-shift * 1e3:+.1f}: the given "
          f"axis lies away from the notch side), axis now at x = {moved[:, 0].mean() * 1e3:.3f} mm, on "
          f"{result.trusted} trusted points")
    assert abs(result.bias_notch_side + shift) < 0.01e-3
    assert np.abs(moved[:, 0] - shift).max() < 0.02e-3
    assert abs(result.bias_binormal) < 0.01e-3
    end = result.centerline.points[result.centerline.s > length - 2e-3]
    print(f"last 2 mm of the axis at x = {end[:, 0].min() * 1e3:.3f} .. {end[:, 0].max() * 1e3:.3f} mm; the shift "
          f"held from s = {result.held_from * 1e3:.1f} mm moved the end {result.end_shift * 1e3:.3f} mm")
    assert np.abs(end[:, 0] - shift).max() < 0.02e-3
    # what the quality states of the tip: the shift held over the stretch no trusted wall checked, and where from
    assert result.end_shift == pytest.approx(shift, abs=0.02e-3)
    assert length - geometry.notch_pitch < result.held_from < length - FOOTPRINT


@pytest.mark.parametrize("shift", [0.3e-3, 1.5e-3])
def test_a_window_whose_few_points_solve_a_shift_past_the_gate_does_not_move_the_axis(shift):
    """The only window with trusted points (s = 12-15 mm) is seen on narrow arcs about each camera's line of sight,
    its points' offsets those of an axis `shift` towards the notch side (a linear model, as the solve's). Within
    the gate (0.8 mm) the axis is moved by it; 1.5 mm would put the points that placed it off the moved wall - no
    stereo bias, but a solve its few points did not determine (flying pixels against a backdrop moved a whole
    second-renderer tube 11.7 mm so): the axis stays where it was."""
    length, gate = 30e-3, 0.8e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    rng = np.random.default_rng(6)
    s = rng.uniform(12e-3, 15e-3, 400)
    phi = np.where(rng.random(400) < 0.5, np.pi / 2, -np.pi / 2) + rng.uniform(-0.17, 0.17, 400)
    radius = R_O + shift * np.cos(phi)
    points = np.stack([radius * np.cos(phi), radius * np.sin(phi), s], axis=1)
    centerline = straight_centerline(length)
    coords, frames = centerline.project_with_frames(points)
    viewpoints = np.where(points[:, 1:2] < 0, [[0.0, -0.09, 0.015]], [[0.0, 0.09, 0.015]])
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints, WallTrust(geometry, gate, FOOTPRINT, length))
    print(f"\nshift {shift * 1e3:.1f} mm on {result.trusted} trusted points: bias "
          f"{result.bias_notch_side * 1e3:+.3f} mm")
    if shift < gate:
        assert result.bias_notch_side == pytest.approx(-shift, abs=0.01e-3)
    else:
        assert result.centerline is centerline and result.bias_notch_side == 0.0


def test_alignment_keeps_the_axis_between_cameras_at_different_distances():
    """Cameras 80 and 105 mm across from a tube on its true axis, each seeing its wall flattened by the matcher
    in proportion to its pixel footprint squared, i.e. to its squared distance (0.1 mm for the near one, 0.17 mm
    for the far one). One level common to both reads the difference as a shift of the axis towards the nearer
    camera (36 um); the level scaled by each camera's squared distance leaves the axis where it is."""
    length = 30e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, rng=np.random.default_rng(5))
    near, far = 0.080, 0.105
    viewpoints = np.where(points[:, 1:2] < 0, [[0.0, -near, 0.015]], [[0.0, far, 0.015]])
    flattening = 0.1e-3 * np.einsum("ij,ij->i", viewpoints, viewpoints) / near**2  # the base is at the origin
    points[:, :2] *= (1 - flattening / R_O)[:, None]
    centerline = straight_centerline(length)
    coords, frames = centerline.project_with_frames(points)
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints,
                                   WallTrust(geometry, 0.8e-3, FOOTPRINT, length))
    moved = result.centerline.points[(result.centerline.s > 3e-3) & (result.centerline.s < 27e-3)]
    common = (flattening.max() - flattening.min()) / 2  # what one common level would read as a shift
    print(f"\ncameras at 80 and 105 mm: axis moved by at most {np.abs(moved[:, :2]).max() * 1e6:.1f} um (one level "
          f"for both: {common * 1e6:.0f} um towards the nearer camera); binormal lean "
          f"{result.bias_binormal * 1e6:+.1f} um")
    assert np.abs(moved[:, :2]).max() < 0.01e-3
    assert abs(result.bias_binormal) < 0.005e-3


def test_the_alignments_shift_varying_along_the_tube_is_its_scatter_about_the_median_shift():
    """A lean the same all along (the fit shifted 0.1 mm towards the notch side everywhere) scatters by nothing;
    one that changes over the distal 40 % of the tube (0.1 mm there, none before) by sqrt(0.4) x 0.1 mm about the
    median, none; measured up to the end seen only."""
    from ntcr_recon.core.relocation.alignment import shift_scatter

    fit = straight_centerline(30e-3)

    def shifted(offset):  # the fit moved by offset(s) (m) towards the notch side (+x)
        points = fit.points + offset(fit.s)[:, None] * fit.normals
        return Centerline.from_points(points, fit.binormals[0], float(fit.s[1] - fit.s[0]))

    everywhere = shifted(lambda s: np.full_like(s, 0.1e-3))
    distal = shifted(lambda s: np.where(s > 18e-3, 0.1e-3, 0.0))
    even, varying, proximal = (shift_scatter(fit, everywhere, 30e-3), shift_scatter(fit, distal, 30e-3),
                               shift_scatter(fit, distal, 18e-3))
    print(f"\nscatter: even lean {even * 1e3:.4f} mm, distal 40 % {varying * 1e3:.4f} mm, up to 18 mm "
          f"{proximal * 1e3:.4f}")
    assert even == pytest.approx(0.0, abs=1e-9)
    assert varying == pytest.approx(math.sqrt(0.4) * 0.1e-3, rel=0.03)
    assert proximal == pytest.approx(0.0, abs=1e-9)


def test_trusted_points_lie_pixels_inside_the_silhouette():
    """The facing zone is set in pixels: 4 footprints inside the silhouette of a 1.75 mm tube is 32.9 deg of view
    angle at 0.2 mm a pixel, 24.2 deg at 0.258 mm, never wider than the cap, and empty for a tube 4 px wide."""
    from ntcr_recon.core.relocation.alignment import facing_cosine

    cap = math.radians(45.0)
    for footprint, expected in ((0.2e-3, 32.9), (0.258e-3, 24.2)):
        angle = math.degrees(math.acos(facing_cosine(R_O, footprint, 4.0, cap)))
        print(f"\nfacing zone at {footprint * 1e3:.3f} mm a pixel: view angle below {angle:.1f} deg")
        # a point at that view angle lies 4 footprints inside the silhouette: r (1 - sin a) = 4 footprints
        assert R_O * (1 - math.sin(math.radians(angle))) == pytest.approx(4 * footprint, rel=1e-9)
        assert angle == pytest.approx(expected, abs=0.1)
    assert math.degrees(math.acos(facing_cosine(R_O, 0.05e-3, 4.0, cap))) == pytest.approx(45.0)
    assert facing_cosine(R_O, 1e-3, 4.0, cap) == pytest.approx(1.0)  # nothing faces: no point is trusted


def test_smoothed_shifts_share_noise_between_windows_and_keep_a_common_shift():
    """Windows each see a noisy copy of one shift: solved alone they scatter, solved jointly they agree, and a
    shift every window sees is kept whole (the smoothness prior only penalises differences)."""
    from ntcr_recon.core.relocation.alignment import smoothed_shifts

    rng = np.random.default_rng(11)
    windows, true_shift = 12, np.array([0.08e-3, -0.03e-3])
    matrices, rhs = [], []
    for _ in range(windows):
        phi = np.concatenate([rng.uniform(-2.1, -1.0, 30), rng.uniform(1.0, 2.1, 30)])  # two facing arcs
        terms = np.stack([np.cos(phi), np.sin(phi), np.ones_like(phi)], axis=1)
        offset = terms[:, :2] @ true_shift - 0.1e-3 + rng.normal(0.0, 0.05e-3, len(phi))
        matrices.append(terms.T @ terms)
        rhs.append(terms.T @ offset)
    matrices, rhs = np.array(matrices), np.array(rhs)
    alone = smoothed_shifts(matrices, rhs, 0.0)
    jointly = smoothed_shifts(matrices, rhs, 1.0)
    independent = np.array([np.linalg.solve(m, r)[:2] for m, r in zip(matrices, rhs, strict=True)])
    assert np.allclose(alone, independent, atol=1e-9)
    scatter_alone, scatter_jointly = np.std(alone[:, 0]), np.std(jointly[:, 0])
    print(f"\nshift towards the notches, scatter over windows: {scatter_alone * 1e3:.3f} mm alone, "
          f"{scatter_jointly * 1e3:.3f} mm jointly; mean {jointly[:, 0].mean() * 1e3:.3f} mm (true 0.080)")
    assert scatter_jointly < 0.6 * scatter_alone
    assert abs(jointly[:, 0].mean() - true_shift[0]) < 0.02e-3
    exact = np.array([m @ np.array([*true_shift, -0.1e-3]) for m in matrices])
    assert np.allclose(smoothed_shifts(matrices, exact, 5.0), true_shift, atol=1e-9)


def test_alignment_ignores_a_silhouette_bulge_on_the_notch_side():
    """A straight tube on its true axis whose wall points within 50 deg of each camera's silhouette on the notch
    side bulge 0.2 mm outward (a matcher's window pulling edge pixels towards the nearer rows, on the side where
    no flying pixels replace them). Trusting every point within 45 deg of the view would read that as a shift
    towards the notches; 4 pixels inside the silhouette the alignment leaves the axis where it is."""
    length = 30e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, rng=np.random.default_rng(7))
    angle = np.arctan2(points[:, 1], points[:, 0])
    view = np.abs(np.abs(angle) - math.pi / 2)     # view angle of a camera on the +-y axis
    bulged = (points[:, 0] > 0) & (view > math.radians(40.0))
    points[bulged, :2] *= (1 + 0.2e-3 / R_O)
    centerline = straight_centerline(length)
    coords, frames = centerline.project_with_frames(points)
    viewpoints = np.where(points[:, 1:2] < 0, [[0.0, -0.09, 0.015]], [[0.0, 0.09, 0.015]])
    wide = align_to_trusted_wall(centerline, coords, frames, viewpoints,
                                 WallTrust(geometry, 0.8e-3, FOOTPRINT, length, silhouette_margin_px=0.0))
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints,
                                   WallTrust(geometry, 0.8e-3, FOOTPRINT, length))
    print(f"\nbulge on the notch side: fit lean read {wide.bias_notch_side * 1e3:+.3f} mm within 45 deg, "
          f"{result.bias_notch_side * 1e3:+.3f} mm 4 px inside the silhouette")
    assert wide.bias_notch_side < -0.02e-3  # the axis would move towards the bulge: the fit read as leaning away
    assert abs(result.bias_notch_side) < 0.005e-3
    moved = result.centerline.points[(result.centerline.s > 3e-3) & (result.centerline.s < 27e-3)]
    assert np.abs(moved[:, :2]).max() < 0.01e-3


def test_alignment_ignores_the_wall_a_matcher_reads_into_the_slots_beside_a_cut():
    """Two cameras 100 deg round the tube from the notch side, either side of it: beside a cut each sees the backbone
    from the slot's edge (113.6 deg) on one side of its view, and the wall within 2 px of that edge reads 0.1 mm deep
    (the matcher's window reaches into the slot). The axis is where it truly is. Trusting that wall reads a lean
    away from the notch side and moves the axis towards it; 2 px clear of the edge the alignment leaves it."""
    length = GEOMETRY.length
    points = wall_points(length, rng=np.random.default_rng(12))
    axis = straight_centerline(length)
    angle = np.arctan2(points[:, 1], points[:, 0])
    beside_cut = inside_intervals(points[:, 2], cut_intervals(GEOMETRY, axis, FOOTPRINT))
    points = points[~(beside_cut & (np.abs(angle) < GEOMETRY.gap_half_angle))]  # the slots
    angles, origins, camera = cameras_round_the_tube([100.0, -100.0], points)
    beside_cut = inside_intervals(points[:, 2], cut_intervals(GEOMETRY, axis, 0.0))
    deep = beside_cut & (beyond_slot_edge(points, angles[camera]) < 2 * FOOTPRINT)
    points[deep, :2] *= 1 - 0.1e-3 / R_O
    coords, frames = axis.project_with_frames(points)

    def aligned_middle(slot_margin_px):
        result = align_to_trusted_wall(axis, coords, frames, origins[camera],
                                       WallTrust(GEOMETRY, 0.8e-3, FOOTPRINT, length, slot_margin_px=slot_margin_px))
        return result, result.centerline.points[(result.centerline.s > 10e-3) & (result.centerline.s < 40e-3)]

    (trusting, moved_by_slots), (clear, middle) = aligned_middle(0.0), aligned_middle(alignment.SLOT_MARGIN_PX)
    print(f"\n{deep.sum()} points beside the cuts read deep; axis towards the notch side at most "
          f"{moved_by_slots[:, 0].max() * 1e3:.3f} mm trusting them, {np.abs(middle[:, 0]).max() * 1e3:.3f} mm 2 px "
          f"clear of the slots' edges ({trusting.trusted} and {clear.trusted} trusted points)")
    assert moved_by_slots[:, 0].max() > 0.02e-3
    assert np.abs(middle[:, :2]).max() < 0.01e-3


def test_alignment_passes_add_up_to_the_whole_lean():
    """The bulging tube, its centreline given 0.15 mm towards the notch side of the true axis. Passes that
    project the points onto the moved axis and select again keep it on the axis, and the lean they report is
    the sum of their shifts (not the last pass's, which is near zero)."""
    length, lean = 30e-3, 0.15e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, rng=np.random.default_rng(8))
    angle = np.arctan2(points[:, 1], points[:, 0])
    bulged = (points[:, 0] > 0) & (np.abs(np.abs(angle) - math.pi / 2) > math.radians(40.0))
    points[bulged, :2] *= (1 + 0.2e-3 / R_O)
    given = straight_centerline(length)
    given = Centerline.from_points(given.points + [lean, 0.0, 0.0], np.array([0.0, 1.0, 0.0]), 0.1e-3)
    coords, frames = given.project_with_frames(points)
    viewpoints = np.where(points[:, 1:2] < 0, [[0.0, -0.09, 0.015]], [[0.0, 0.09, 0.015]])
    result = align_to_trusted_wall(given, coords, frames, viewpoints,
                                   WallTrust(geometry, 0.8e-3, FOOTPRINT, length), xyz=points, passes=3)
    middle = (result.centerline.s > 3e-3) & (result.centerline.s < 27e-3)
    error = np.abs(result.centerline.points[middle, 0]).max()
    print(f"\ncentreline given {lean * 1e3:.2f} mm off: {error * 1e3:.3f} mm off after three passes; lean reported "
          f"{result.bias_notch_side * 1e3:+.3f} mm")
    assert error < 0.03e-3
    assert result.bias_notch_side == pytest.approx(lean, abs=0.01e-3)


def test_alignment_leaves_a_tube_seen_from_one_side_alone():
    """One camera sees one face: a shift towards it cannot be told from the wall's level, so nothing moves."""
    length = 30e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, angles=(-math.pi, 0.0), rng=np.random.default_rng(5))  # the -y half
    points[:, 1] -= 0.1e-3
    centerline = straight_centerline(length)
    coords, frames = centerline.project_with_frames(points)
    viewpoints = np.tile([[0.0, -0.09, 0.015]], (len(points), 1))
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints,
                                   WallTrust(geometry, 0.8e-3, FOOTPRINT, length))
    assert np.allclose(result.centerline.points, centerline.points, atol=1e-9)
    assert result.bias_notch_side == 0.0 and result.bias_binormal == 0.0
