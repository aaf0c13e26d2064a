"""robot.comb: the notches' comb laid on a centreline, and the wall clear of the cuts. Points are drawn analytically
on the true surface (no renderer), so every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from support.analytic_tube import GEOMETRY, R_O, straight_centerline, true_centerline

from ntcr_recon.core.robot.comb import clear_of_cuts, cut_intervals, expected_centres, inside_intervals
from ntcr_recon.core.robot.kinematics import TubeShape


def test_the_comb_laid_on_a_centreline_is_its_own_per_robot_and_cannot_be_changed_by_a_caller():
    """expected_centres remembers the comb on the centreline it was laid on: asked again, the same read-only
    array; another robot (a longer notch pitch) on the same centreline, or the same robot on a bent one, its own."""
    straight = straight_centerline(GEOMETRY.length)
    centres = expected_centres(GEOMETRY, straight)
    assert expected_centres(GEOMETRY, straight) is centres
    with pytest.raises(ValueError, match="read-only"):
        centres[0] = 0.0
    wider = dataclasses.replace(GEOMETRY, notch_pitch=GEOMETRY.notch_pitch + 0.5e-3, notch_count=10)
    assert np.allclose(expected_centres(wider, straight), wider.notch_centers_s)
    bent = true_centerline(TubeShape.from_bend_angle(GEOMETRY, math.radians(60)))
    assert expected_centres(GEOMETRY, bent)[-1] < centres[-1] - 0.05e-3
    assert np.allclose(expected_centres(GEOMETRY, straight), GEOMETRY.notch_centers_s)


def test_comb_lies_on_the_configured_notches_of_a_straight_tube_and_shortens_with_bend():
    straight = straight_centerline(GEOMETRY.length)
    assert np.allclose(expected_centres(GEOMETRY, straight), GEOMETRY.notch_centers_s)
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(60))
    bent = true_centerline(shape)
    truth = np.array([n["center_s"] for n in shape.notch_table()])
    error = np.abs(expected_centres(GEOMETRY, bent) - truth).max()
    print(f"\ncomb on a 60 deg arc: worst notch centre {error * 1e3:.4f} mm off")
    assert error < 0.005e-3
    # curled past a full pitch of shortening: the turn up to each centre is taken at the centre, not at its
    # undeformed place (which lies past it, and counted the next notch's bend too: 0.73 mm off at 283 deg)
    curled = TubeShape.from_bend_angle(GEOMETRY, math.radians(283))
    truth = np.array([n["center_s"] for n in curled.notch_table()])
    error = np.abs(expected_centres(GEOMETRY, true_centerline(curled, 4000)) - truth).max()
    print(f"comb on a 283 deg arc: worst notch centre {error * 1e3:.4f} mm off")
    assert error < 0.005e-3
    intervals = cut_intervals(GEOMETRY, straight, 0.1e-3)
    centre = GEOMETRY.notch_centers_s[3]
    inside = inside_intervals(np.array([centre, centre + GEOMETRY.notch_width / 2 + 0.05e-3,
                                        centre + GEOMETRY.notch_pitch / 2]), intervals)
    assert inside.tolist() == [True, True, False]


def test_the_wall_is_clear_of_a_cut_on_the_spines_and_on_the_backbone_across_it():
    """A cut opens the outer wall within the gap's half-angle of the notch side; opposite it the backbone is whole
    wall, which the alignment may trust; beside it (within the margin, either way) it is not."""
    straight = straight_centerline(GEOMETRY.length)
    centre, margin, half = GEOMETRY.notch_centers_s[3], 0.1e-3, GEOMETRY.gap_half_angle
    beside = half + 0.5 * margin / R_O  # round the tube past the cut's edge, within the margin
    places = [(centre, 0.0), (centre, half - 0.01), (centre, beside), (centre, half + 2 * margin / R_O),
              (centre, math.pi), (centre + GEOMETRY.notch_width / 2 + 0.05e-3, 0.0),
              (centre + GEOMETRY.notch_pitch / 2, 0.0)]
    xyz = np.array([[R_O * math.cos(angle), R_O * math.sin(angle), s] for s, angle in places])
    clear = clear_of_cuts(straight.project(xyz), GEOMETRY, straight, margin)
    assert clear.tolist() == [False, False, False, True, True, False, True]
