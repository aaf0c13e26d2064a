"""relocation.icp: a known motion of the reference recovered, and how far ICP moved the reference and the tip.
Points are drawn analytically on the true surface (no renderer), so every figure is known exactly; each number
asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import GEOMETRY, true_centerline, wall_points

from ntcr_recon.core.robot.kinematics import TubeShape


def test_icp_recovers_a_known_motion_of_the_reference_and_relocates_onto_it():
    from ntcr_recon.core.base.transforms import quaternion_to_matrix
    from ntcr_recon.core.relocation.icp import icp, posed_reference, relocate_onto_reference

    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(45))
    centerline = true_centerline(shape)
    reference, normals, part = posed_reference(centerline, GEOMETRY, [], shape.length, 0.1e-3)
    # the observed cloud: the true outer wall, moved by a small rigid motion and made noisy
    sample = shape.sample_surface_parts(0.1e-3)
    wall = sample.points[sample.part == 0][::3]
    rotation = quaternion_to_matrix(np.array([0.0, np.sin(0.002), 0.0, np.cos(0.002)]))  # 0.23 deg about y
    translation = np.array([0.05e-3, -0.03e-3, 0.02e-3])
    rng = np.random.default_rng(4)
    cloud = wall @ rotation.T + translation + rng.normal(0.0, 0.01e-3, wall.shape)
    found_r, found_t, iterations = icp(reference, cloud, 0.8e-3, iterations=60)
    probe = centerline.points[::200]
    truth = probe @ rotation.T + translation
    before = np.linalg.norm(probe - truth, axis=1).max()
    error = np.linalg.norm(probe @ found_r.T + found_t - truth, axis=1).max()
    print(f"\nICP: centreline {before * 1e3:.3f} mm off before, {error * 1e3:.4f} mm after {iterations} iterations")
    # point-to-point ICP on a sampled reference slides along a tube only as far as its bend and ends hold it
    assert error < 0.5 * before
    moved = relocate_onto_reference(cloud, reference @ found_r.T + found_t, normals @ found_r.T, part, 0.8e-3)
    assert moved.accepted.mean() > 0.99
    assert np.median(moved.distance) < 0.05e-3


def test_the_reference_move_is_how_far_icp_moved_the_reference_and_the_tip_along_and_across_the_tube():
    """A straight reference along z turned 0.1 deg about x through its base and shifted 0.1 mm along z: at the 30 mm
    tip that is 0.1 mm along the tube and 0.052 mm across it; over the points, their RMS move."""
    from ntcr_recon.core.base.transforms import quaternion_to_matrix
    from ntcr_recon.core.relocation.icp import reference_move

    reference = wall_points(30e-3, spacing=0.5e-3)
    angle = math.radians(0.1)
    rotation = quaternion_to_matrix(np.array([math.sin(angle / 2), 0.0, 0.0, math.cos(angle / 2)]))
    translation = np.array([0.0, 0.0, 0.1e-3])
    move = reference_move(reference, rotation, translation, np.array([0.0, 0.0, 30e-3]), np.array([0.0, 0.0, 1.0]))
    moved = reference @ rotation.T + translation - reference
    print(f"\nreference moved {move.rms * 1e3:.4f} mm RMS; tip {move.tip_along * 1e3:.4f} mm along, "
          f"{move.tip_across * 1e3:.4f} mm across")
    assert move.tip_along == pytest.approx(0.1e-3, rel=1e-3)
    assert move.tip_across == pytest.approx(30e-3 * math.sin(angle), rel=1e-3)
    assert move.rms == pytest.approx(float(np.sqrt(np.mean(np.sum(moved**2, axis=1)))), rel=1e-9)
    assert reference_move(reference, np.eye(3), np.zeros(3), np.zeros(3), np.array([0.0, 0.0, 1.0])).rms == 0.0
