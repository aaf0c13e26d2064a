"""relocation.bends: the bend read off a centreline (whole past half a turn, from the clamp's axis, the robot's
where the free end leans) and a curve carried on bending over the notches it stops short of. Points are drawn
analytically on the true surface (no renderer), so every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import GEOMETRY, displaced_centerline, straight_centerline, true_centerline

from ntcr_recon.core.relocation.bends import continued_bend, held_bend, turn_from_base
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.robot.kinematics import TubeShape


@pytest.mark.parametrize("bend_deg", [100, 179, 181, 250, 280])
def test_a_bend_past_half_a_turn_is_read_whole(bend_deg):
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(bend_deg))
    curve = true_centerline(shape)
    turn = np.degrees(curve.bend_angle(0.0, curve.s))
    assert turn[-1] == pytest.approx(bend_deg, abs=1e-6)  # the end tangents alone read 360 - bend past 180
    assert np.all(np.diff(turn) > -1e-9)  # it grows along the robot, never folding back
    assert np.degrees(curve.rolled(np.pi).bend_angle(0.0, shape.length)) == pytest.approx(-bend_deg, abs=1e-6)
    # the turn between two places past the base, and from a later place back to an earlier one
    assert np.degrees(curve.bend_angle(curve.s[200], curve.s[-1])) == pytest.approx(turn[-1] - turn[200], abs=1e-6)
    assert np.degrees(curve.bend_angle(curve.s[-1], curve.s[200])) == pytest.approx(turn[200] - turn[-1], abs=1e-6)


def test_the_bend_is_counted_from_the_clamps_axis_not_from_the_curves_leaning_start():
    """A smoothed curve's start leans with the first notches' bend spread back over the straight proximal part;
    the robot's bend (and with it its length, which places the tip) is counted from the configured base axis."""
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(250))
    # the start bent 3 deg back from the notch side (+x here), rejoining the true curve tangentially at 4 mm
    rejoin, lean = 4e-3, math.radians(3.0)
    leaning = displaced_centerline(shape, lambda s: lean / (2 * rejoin) * np.clip(rejoin - s, 0.0, None) ** 2)
    curve_turn = math.degrees(leaning.bend_angle(0.0, leaning.length))
    from_base = math.degrees(turn_from_base(leaning, GEOMETRY, leaning.length))
    print(f"\n250 deg bend, start leaning 3 deg: the curve turns {curve_turn:.2f} deg, from the base axis "
          f"{from_base:.2f}")
    assert curve_turn == pytest.approx(253.0, abs=0.3)
    assert from_base == pytest.approx(250.0, abs=0.3)


def test_the_bend_read_short_of_a_leaning_free_end_is_the_robots():
    """A fitted curve's free end follows only the data before it: its last 3 mm leaning 8 deg further towards the
    notches turn the curve's bend at its end by as much, and the robot's length at that bend by ybar x 8 deg (0.17 mm
    here). Read two pitches short of the end and carried on at the steady bend (held_bend), the bend is the
    robot's; on the true curve the two agree."""
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(60))
    centres = np.array([n["center_s"] for n in shape.notch_table()])
    exact = true_centerline(shape)
    leant, lean = 3e-3, math.tan(math.radians(8.0))
    leaning = displaced_centerline(
        shape, lambda s: lean / (2 * leant) * np.clip(s - (shape.length - leant), 0.0, None) ** 2)
    at_end = math.degrees(turn_from_base(leaning, GEOMETRY, leaning.length))
    held = math.degrees(held_bend(leaning, GEOMETRY, leaning.length, centres))
    exact_end = math.degrees(turn_from_base(exact, GEOMETRY, exact.length))
    exact_held = math.degrees(held_bend(exact, GEOMETRY, exact.length, centres))
    print(f"\n60 deg bend, the last 3 mm leaning 8 deg: read at the end {at_end:.2f} deg, held {held:.2f}; "
          f"on the true curve {exact_end:.2f} and {exact_held:.2f}")
    assert at_end == pytest.approx(68.0, abs=0.5)
    assert held == pytest.approx(60.0, abs=0.5)
    assert exact_held == pytest.approx(exact_end, abs=0.2) and exact_end == pytest.approx(60.0, abs=0.2)


@pytest.mark.parametrize("bend_deg", [60, 200])
def test_a_curve_that_stops_short_of_the_last_notch_carries_on_bending_over_it_to_the_tip(bend_deg):
    """The fit reaches only as far as the wall is seen whole; over a last notch seen thinly the curve is carried on
    to the tip. Along its end tangent it misses that notch's bend; at the steady bend per notch, over each notch past
    its end, it lands on the tip. Past the last notch (the distal ring) it goes on straight."""
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(bend_deg))
    table = shape.notch_table()
    centres = np.array([n["center_s"] for n in table])
    true_tip = shape.centerline(np.array([shape.length]))[0][0]

    def tip_error(stop_s: float) -> tuple[float, float]:
        s = np.arange(0.0, stop_s, 0.1e-3)
        points, frames = shape.centerline(s)
        cut = Centerline.from_frames(s, points, frames)
        carried = continued_bend(cut, shape.length, centres, GEOMETRY)
        along_tangent = cut.frames_at(np.array([shape.length]))[0][0]
        landed = carried.frames_at(np.array([shape.length]))[0][0]
        assert np.allclose(carried.points[: len(s)], cut.points)  # the curve itself is unchanged
        return float(np.linalg.norm(along_tangent - true_tip)), float(np.linalg.norm(landed - true_tip))

    before_last = tip_error(table[-1]["start_s"] - 0.3e-3)
    on_the_ring = tip_error(table[-1]["end_s"] + 0.2e-3)
    print(f"\n{bend_deg} deg, the curve stopped before the last notch: the tip along its end tangent "
          f"{before_last[0] * 1e3:.3f} mm off, carried on bending {before_last[1] * 1e3:.3f} mm; stopped on the distal "
          f"ring: {on_the_ring[0] * 1e3:.4f} and {on_the_ring[1] * 1e3:.4f} mm")
    assert before_last[0] > 0.08e-3
    assert before_last[1] < 0.005e-3
    assert on_the_ring[1] == pytest.approx(on_the_ring[0], abs=1e-9) and on_the_ring[1] < 0.005e-3


def test_a_tube_seen_part_way_is_carried_on_bending_at_its_notches():
    """Where a tube seen only so far would go on: bending at each notch past the end seen as the notches before
    it did, straight along the spines and the distal ring (not along its end tangent, nor on one arc)."""
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(90.0))
    truth = true_centerline(shape)
    centres = np.array([n["center_s"] for n in shape.notch_table()])
    beyond = np.linspace(0.0, shape.length - 38e-3, 50)
    carried = continued_bend(truth.up_to(38e-3), shape.length, centres, GEOMETRY)
    positions, tangents = carried.frames_at(38e-3 + beyond)[:2]
    true_positions, true_frames = shape.centerline(38e-3 + beyond)
    straight_on = truth.frames_at(np.array([38e-3]))[0][0] + beyond[-1] * truth.frames_at(np.array([38e-3]))[1][0]
    error = np.linalg.norm(positions - true_positions, axis=1).max()
    print(f"\n{beyond[-1] * 1e3:.1f} mm carried on: {error * 1e3:.3f} mm off the true robot "
          f"(straight on: {np.linalg.norm(straight_on - true_positions[-1]) * 1e3:.1f} mm)")
    assert error < 0.005e-3 and np.linalg.norm(straight_on - true_positions[-1]) > 2e-3
    assert np.einsum("ij,ij->i", tangents, true_frames[:, :, 2]).min() > math.cos(math.radians(0.5))
    straight = straight_centerline(30e-3)
    on = continued_bend(straight, 35e-3, centres, GEOMETRY)
    assert on.frames_at(np.array([35e-3]))[0][0] == pytest.approx([0.0, 0.0, 35e-3], abs=1e-9)
