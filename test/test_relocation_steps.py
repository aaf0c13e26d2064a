"""Each step of the relocation (paper Sec. IV) on known inputs: a straight tube, one notch, a known arc, a tube
pointing at a camera. Points are drawn analytically on the true surface (no renderer), so every figure is
known exactly; each number asserted is printed."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from ntcr_recon.core.config.rig import RelocationConfig
from ntcr_recon.core.quality.checks import Trace, assess
from ntcr_recon.core.quality.measures import (
    camera_coverage,
    camera_reach,
    cameras_looking_into_slots,
    centerline_uncertainty,
    depth_step,
    notched_thinning,
    surface_depth,
    unmeasured_share,
    where_notches_went_unseen,
)
from ntcr_recon.core.relocation.alignment import align_to_trusted_wall, cross_view_spread, level_by_backbone
from ntcr_recon.core.relocation.centerline import (
    Centerline,
    continued_bend,
    estimate_centerline,
    held_bend,
    settings_for,
    turn_from_base,
)
from ntcr_recon.core.relocation.notches import Notch, detect_notches
from ntcr_recon.core.relocation.outline import OUTLINE_TOLERANCE_PX, across_views_from, outline_offset
from ntcr_recon.core.relocation import alignment
from ntcr_recon.core.relocation.tip import TipAlongTube, carried_to_length, tube_end, visible_sectors
from ntcr_recon.core.robot.comb import clear_of_cuts, cut_intervals, expected_centres, inside_intervals, near_cuts
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

GEOMETRY = TubeGeometry()   # 3.5 mm, 16 notches, straight along base +z, notches towards +x
FOOTPRINT = 0.2e-3          # a D405 pixel at 90 mm
# the findings (core.quality.findings) that state how well the tip is placed, along the tube and across it
TIP_CODES = {"TIP_ON_ERODED_RIM", "TIP_ON_END_CAP"}


def _by_code(warnings) -> dict:
    """The findings by code (core.quality.findings), each code's in the order raised."""
    found: dict = {}
    for warning in warnings:
        found.setdefault(warning.code, []).append(warning)
    return found


def _tip_findings(warnings) -> list:
    return [w for w in warnings if w.code in TIP_CODES]


def _text(by_code: dict) -> str:
    return "\n".join(f"[{code}] {w}" for code, found in by_code.items() for w in found)
R_O = GEOMETRY.outer_radius


def straight_centerline(length: float) -> Centerline:
    s = np.linspace(0.0, length, int(length / 0.1e-3) + 1)
    points = np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=1)
    return Centerline.from_points(points, np.array([0.0, 1.0, 0.0]), 0.1e-3)


def wall_points(length: float, spacing: float = FOOTPRINT, angles=(-math.pi, math.pi), radius: float = R_O,
                start: float = 0.0, rng=None) -> np.ndarray:
    """Points on a straight cylinder about base z, angle measured from +x (the notch side)."""
    s = np.arange(start, length, spacing)
    phi = np.arange(angles[0], angles[1], spacing / radius)
    ss, pp = (a.ravel() for a in np.meshgrid(s, phi, indexing="ij"))
    points = np.stack([radius * np.cos(pp), radius * np.sin(pp), ss], axis=1)
    if rng is not None:
        points += rng.normal(0.0, 0.01e-3, points.shape)
    return points


def true_centerline(shape: TubeShape, samples: int = 2000) -> Centerline:
    s = np.linspace(0.0, shape.length, samples)
    points, frames = shape.centerline(s)
    return Centerline(s, points, frames[:, :, 2], frames[:, :, 0], frames[:, :, 1])


def displaced_centerline(shape: TubeShape, towards_notches) -> Centerline:
    """The shape's centreline with each sample moved towards the notch side by towards_notches(s) (m): a fitted
    curve's local error, on a known robot."""
    s = np.linspace(0.0, shape.length, 4000)
    points, frames = shape.centerline(s)
    return Centerline.from_points(points + towards_notches(s)[:, None] * frames[:, :, 0], frames[0, :, 1], 0.1e-3)


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
        cut = Centerline(s, points, frames[:, :, 2], frames[:, :, 0], frames[:, :, 1])
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


def _tube_with_one_notch(depressed: bool, filled: float = 0.0):
    """A straight robot's outer wall with notch 5 open: a see-through slot, or (depressed) its window filled
    by points at the notch floor's depth, as an obliquely seen notch is, or (filled > 0) that share of its window
    left on the wall, as a matcher whose window is wider than the slot fills it."""
    geometry = TubeGeometry(notch_count=16)
    start = geometry.notch_centers_s[5] - geometry.notch_width / 2
    end = start + geometry.notch_width
    points = wall_points(geometry.length, spacing=FOOTPRINT / 2)
    phi = np.arctan2(points[:, 1], points[:, 0])
    open_window = (points[:, 2] > start) & (points[:, 2] < end) & (np.abs(phi) < geometry.gap_half_angle)
    if depressed:
        points[open_window, :2] *= (geometry.outer_radius - 0.4e-3) / geometry.outer_radius
    else:
        points = points[~(open_window & (np.random.default_rng(3).random(len(points)) >= filled))]
    centerline = straight_centerline(geometry.length + 2e-3)
    return geometry, centerline, centerline.project(points), start, end


@pytest.mark.parametrize("depressed", [False, True], ids=["seen_through", "seen_obliquely"])
def test_one_notch_is_found_where_the_comb_puts_it_by_the_signal_that_shows_it(depressed):
    geometry, centerline, coords, start, end = _tube_with_one_notch(depressed)
    notches = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3)
    print(f"\n{'depressed' if depressed else 'open'} notch: found {[(n.index, n.signal) for n in notches]}, "
          f"edges {[(round(n.start_s * 1e3, 3), round(n.end_s * 1e3, 3)) for n in notches]} "
          f"(true {start * 1e3:.3f}..{end * 1e3:.3f} mm)")
    assert [n.index for n in notches] == [5]
    assert notches[0].signal == ("depression" if depressed else "coverage")
    assert abs(notches[0].start_s - start) < FOOTPRINT / 2
    assert abs(notches[0].end_s - end) < FOOTPRINT / 2
    assert abs(notches[0].width - geometry.notch_width) < FOOTPRINT


def test_a_slot_the_matcher_filled_is_found_by_its_dip_and_given_its_bends_width():
    """A slot narrower than the matcher's window keeps part of its wall: 60% left, the coverage dips to 0.4 and
    never crosses the half-plateau edge level; the notch is still found where the comb puts it ("dip"), its arc
    and width those its bend implies (straight: the configured width). Left at 85%, the dip is under DIP_PEAK:
    no notch is made of it."""
    from ntcr_recon.core.relocation.notches import DIP_PEAK

    found = {}
    for filled in (0.6, 0.85):
        geometry, centerline, coords, start, end = _tube_with_one_notch(False, filled=filled)
        found[filled] = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25,
                                       geometry.length - 0.1e-3)
        listed = [(n.index, n.signal, round(n.width * 1e3, 3)) for n in found[filled]]
        print(f"\n{filled:.0%} of the slot's wall left: found {listed}")
    [dip] = found[0.6]
    assert (dip.index, dip.signal) == (5, "dip")
    assert abs(dip.center_s - (start + end) / 2) < FOOTPRINT / 2
    assert dip.width == pytest.approx(geometry.notch_width_at_bend(dip.bend)) and abs(dip.bend) < 1e-3
    assert dip.end_s - dip.start_s == pytest.approx(geometry.notch_arc_at_bend(dip.bend))
    assert found[0.85] == [] and DIP_PEAK > 1 - 0.85


def test_a_dips_width_is_its_bend_taken_with_its_neighbours_not_one_chords_wobble():
    """A robot bent 3.75 deg at each notch whose centreline wobbles 0.1 mm across the spine between notches 9 and
    10 (where its support changes from two cameras to one): that spine's chord turns 3.8 deg, notch 9 reads 7.6
    deg and notch 10 0 deg. Notch 9 is a dip (the matcher filled its slot: no edges), so its width is the one its
    bend implies: with its own chord's bend 0.2 mm narrow, with the median of its own and its neighbours' true."""
    from ntcr_recon.core.relocation.notches import _measure

    geometry = GEOMETRY
    shape = TubeShape.from_bend_angle(geometry, math.radians(60))
    table = shape.notch_table()
    spine_middle = (table[9]["end_s"] + table[10]["start_s"]) / 2
    # a ramp across the spine, none over the notches
    wobbly = displaced_centerline(shape, lambda s: 0.1e-3 / (1 + np.exp(-(s - spine_middle) / 0.15e-3)))
    gaps = [(n["start_s"], n["end_s"]) for n in table]
    signals = ["dip" if n["index"] == 9 else "coverage" for n in table]
    measured = _measure(gaps, list(range(geometry.notch_count)), signals, wobbly, geometry,
                        np.array([n["center_s"] for n in table]), shape.length)
    by_index = {n.index: n for n in measured}
    bends = {i: math.degrees(by_index[i].bend) for i in (8, 10)}
    print(f"\nwobbling chord: notch 9 (a dip) {by_index[9].width * 1e3:.3f} mm, true {table[9]['width'] * 1e3:.3f};"
          f" notches 10 and 8 read bends {bends[10]:.2f}, {bends[8]:.2f} deg")
    assert abs(math.degrees(by_index[10].bend) - 3.75) > 2.0  # the wobble turns the chords either side of it
    assert by_index[9].signal == "dip"
    assert by_index[9].width == pytest.approx(table[9]["width"], abs=0.03e-3)


def _comb_tube(shift_of_notch_5: float = 0.0, window_unseen_from: float = np.inf, rng=None,
               notch_5_filled: float = 0.0, spines_left: float | None = None, spines_pulled_in: float = 0.0):
    """A straight robot's outer wall with every notch open where the comb puts it (notch 5 moved along s by
    `shift_of_notch_5`, and that share of its window left on the wall, as a matcher whose window is wider than
    the slot fills it); past `window_unseen_from` the notch window holds only a stray point every 0.7 mm
    (the notched side turned away from both cameras), the backbone side is still seen. spines_left: of each spine
    between two notches only its middle that long is left in the window, `spines_pulled_in` inside the wall (a
    matcher mixing a backdrop seen through the slots into the rims' pixels)."""
    geometry = TubeGeometry(notch_count=16)
    points = wall_points(geometry.length, spacing=FOOTPRINT / 2)
    phi = np.arctan2(points[:, 1], points[:, 0])
    in_window = np.abs(phi) < geometry.gap_half_angle
    centres = geometry.notch_centers_s + np.where(np.arange(16) == 5, shift_of_notch_5, 0.0)
    cut = np.zeros(len(points), bool)
    left_on_wall = np.random.default_rng(3).random(len(points)) < notch_5_filled
    for k, centre in enumerate(centres):
        cut |= in_window & (np.abs(points[:, 2] - centre) < geometry.notch_width / 2) & ~(left_on_wall & (k == 5))
    if spines_left is not None:
        middles = (centres[:-1] + centres[1:]) / 2
        on_spine_middle = np.abs(points[:, 2, None] - middles[None, :]).min(axis=1) < spines_left / 2
        notched = (points[:, 2] > centres[0]) & (points[:, 2] < centres[-1])
        cut |= in_window & notched & ~on_spine_middle
        pulled = in_window & notched & on_spine_middle
        points[pulled, :2] *= (R_O - spines_pulled_in) / R_O
    keep = ~cut & ~(in_window & (points[:, 2] > window_unseen_from))
    points = points[keep]
    if rng is not None:
        stray_s = np.arange(window_unseen_from, geometry.length, 0.7e-3)
        stray_phi = rng.uniform(-geometry.gap_half_angle, geometry.gap_half_angle, len(stray_s))
        strays = np.stack([R_O * np.cos(stray_phi), R_O * np.sin(stray_phi), stray_s], axis=1)
        points = np.concatenate([points, strays])
    centerline = straight_centerline(geometry.length + 2e-3)
    return geometry, centerline, centerline.project(points)


def test_no_notch_is_found_where_no_camera_sees_the_notched_side():
    """Past 30 mm the window holds a few stray points: gaps between them are no slots seen through (once
    read as notches of any width there, which then spoiled the rim calibration of every notch)."""
    geometry, centerline, coords = _comb_tube(window_unseen_from=30e-3, rng=np.random.default_rng(4))
    notches = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3)
    seen = [k for k, centre in enumerate(geometry.notch_centers_s) if centre + geometry.notch_width / 2 < 30e-3]
    print(f"\nwindow unseen past 30 mm: found {[n.index for n in notches]}, seen {seen}")
    assert [n.index for n in notches] == seen
    for notch in notches:
        assert abs(notch.width - geometry.notch_width) < FOOTPRINT


@pytest.mark.parametrize("pulled_in", [0.0, 0.4e-3], ids=["on_the_wall", "pulled_inside_it"])
def test_notches_between_spines_a_backdrop_eroded_to_a_tenth_of_the_pitch_are_all_found(pulled_in):
    """A backdrop seen through the slots, mixed into the rims' pixels by the matcher, leaves of each spine only its
    middle 0.3 mm (a tenth of the 3 mm pitch), on the wall or 0.4 mm inside it: the upper quartile of the window's
    coverage lies in the gaps and once called the window unseen past the plain tube (the first and last notch found
    of 16 here, none with the spines inside the wall; 3 of 16 on a rendered width1.8 robot). The spines' tops make
    the plateau: every notch is found where the comb puts it, its gap the stretch between two eroded spines (the rim
    calibration gives the erosion back)."""
    spine_left = 0.3e-3
    geometry, centerline, coords = _comb_tube(spines_left=spine_left, spines_pulled_in=pulled_in)
    notches = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3)
    print(f"\nspines eroded to {spine_left * 1e3:.1f} mm, {pulled_in * 1e3:.1f} mm inside the wall: found "
          f"{[(n.index, n.signal, round(n.width * 1e3, 2)) for n in notches]}")
    assert [n.index for n in notches] == list(range(16))
    assert all(n.signal == "coverage" for n in notches)
    # each gap spans its cut; the inner ones lie between two eroded spines, centred where the comb puts them
    half = geometry.notch_width / 2
    for notch, centre in zip(notches, geometry.notch_centers_s, strict=True):
        assert notch.start_s < centre - half + FOOTPRINT and notch.end_s > centre + half - FOOTPRINT
    for notch, centre in zip(notches[1:-1], geometry.notch_centers_s[1:-1], strict=True):
        assert abs(notch.center_s - centre) < FOOTPRINT / 2
    # the first and last border the plain tube, whose edge is the cut's own
    assert abs(notches[0].start_s - (geometry.notch_centers_s[0] - half)) < FOOTPRINT
    assert abs(notches[-1].end_s - (geometry.notch_centers_s[-1] + half)) < FOOTPRINT


def test_a_run_centred_off_its_notch_is_not_that_notch():
    """Notch 5 cut 0.9 mm (0.6 widths) along from where the comb puts it: not taken as notch 5 (nor as 6)."""
    geometry, centerline, coords = _comb_tube(shift_of_notch_5=0.6 * TubeGeometry().notch_width)
    notches = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3)
    print(f"\nnotch 5 moved 0.6 widths: found {[n.index for n in notches]}")
    assert [n.index for n in notches] == [k for k in range(16) if k != 5]


@pytest.mark.parametrize("shift_widths, found", [(0.3, True), (0.6, False)])
def test_a_dip_seen_obliquely_off_its_comb_place_is_that_notch_within_half_a_width(shift_widths, found):
    """Notch 5's slot filled to 60% by the matcher (a dip, no edges) and its open part moved along s, as an oblique
    view moves it: 0.3 widths (0.45 mm, what a robot bent 90 degrees towards the camera its notches face shows)
    is still notch 5, found as a dip where the comb puts it; 0.6 widths, beyond half a notch width, is not
    (as a run centred that far off is not: test_a_run_centred_off_its_notch_is_not_that_notch)."""
    shift = shift_widths * TubeGeometry().notch_width
    geometry, centerline, coords = _comb_tube(shift_of_notch_5=shift, notch_5_filled=0.6)
    notches = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3)
    print(f"\nfilled notch 5 moved {shift_widths} widths: found {[(n.index, n.signal) for n in notches]}")
    others = [k for k in range(16) if k != 5]
    assert [n.index for n in notches if n.index != 5] == others
    fifth = [n for n in notches if n.index == 5]
    if found:
        [notch] = fifth
        assert notch.signal == "dip"
        assert abs(notch.center_s - geometry.notch_centers_s[5]) < FOOTPRINT / 2  # where the comb puts it
    else:
        assert fifth == []


def test_a_rim_the_matcher_mixed_with_the_floor_behind_it_is_measured_where_its_rays_put_it():
    """A see-through notch seen from a camera 16 mm further along the tube (looking down 10 degrees onto it): its
    end face is turned away, so the first 0.3 mm of wall past its end rim is a depth edge the matcher mixes with
    the floor behind (seen 0.4 mm deeper along the viewing rays), while its start face, turned towards the
    camera, is seen beside its rim down to 1 mm deep. Judged where they were seen, the mixed rim pixels widen
    the notch by 0.3 mm; moved along their rays they land on the wall past the end rim and give it back, and the
    face's points, which land inside the gap short of the end rim, leave the start where it is."""
    from ntcr_recon.core.relocation.centerline import TubeCoordinates

    geometry = TubeGeometry(notch_count=16)
    start = geometry.notch_centers_s[5] - geometry.notch_width / 2
    end = start + geometry.notch_width
    camera = np.array([90e-3, 0.0, start + 16e-3])
    points = wall_points(geometry.length, spacing=FOOTPRINT / 2)
    phi = np.arctan2(points[:, 1], points[:, 0])
    in_window = np.abs(phi) < geometry.gap_half_angle
    points = points[~(in_window & (points[:, 2] > start) & (points[:, 2] < end))]
    phi = np.arctan2(points[:, 1], points[:, 0])
    mixed = (np.abs(phi) < geometry.gap_half_angle) & (points[:, 2] > end) & (points[:, 2] < end + 0.3e-3)
    rays = points - camera
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    seen_points = points + np.where(mixed[:, None], 0.4e-3 * rays, 0.0)
    # the start face (the normal plane at `start`), seen down to 1 mm inside the wall
    depth, angle = (a.ravel() for a in np.meshgrid(np.arange(0.05e-3, 1.0e-3, FOOTPRINT / 2),
                                                   np.arange(-1.0, 1.0, FOOTPRINT / 2 / R_O), indexing="ij"))
    face = np.stack([(R_O - depth) * np.cos(angle), (R_O - depth) * np.sin(angle), np.full_like(depth, start)], 1)
    face_rays = face - camera
    face_rays /= np.linalg.norm(face_rays, axis=1, keepdims=True)
    # where the face's rays cross the wall's radius (towards the camera): inside the gap
    a = face_rays[:, 0] ** 2 + face_rays[:, 1] ** 2
    b = face[:, 0] * face_rays[:, 0] + face[:, 1] * face_rays[:, 1]
    c = face[:, 0] ** 2 + face[:, 1] ** 2 - R_O ** 2
    face_on_wall = face + (-(b + np.sqrt(b * b - a * c)) / a)[:, None] * face_rays
    centerline = straight_centerline(geometry.length + 2e-3)
    seen = centerline.project(np.concatenate([seen_points, face]))
    moved = centerline.project(np.concatenate([points, face_on_wall]))
    assert np.all(moved.s[len(points):] > start) and np.all(moved.s[len(points):] < start + 0.3e-3)
    arguments = (centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3)
    as_seen = detect_notches(seen, *arguments)
    on_rays = detect_notches(TubeCoordinates(moved.s, moved.x, moved.y), *arguments, observed=seen)
    print(f"\nmixed end rim: as seen {as_seen[0].start_s * 1e3:.3f}..{as_seen[0].end_s * 1e3:.3f}, on rays "
          f"{on_rays[0].start_s * 1e3:.3f}..{on_rays[0].end_s * 1e3:.3f} mm (true {start * 1e3:.3f}..{end * 1e3:.3f})")
    assert [n.index for n in as_seen] == [n.index for n in on_rays] == [5]
    assert as_seen[0].end_s - end > 0.2e-3  # the mixed rim pixels read as gap
    assert abs(on_rays[0].end_s - end) < FOOTPRINT / 2
    assert abs(on_rays[0].start_s - as_seen[0].start_s) < FOOTPRINT / 20  # the start rim: as before


@pytest.mark.parametrize("reach", [0.6e-3, -0.6e-3])
def test_rim_calibration_gives_back_the_cut_faces_the_cameras_see(reach):
    """A straight robot seen by two cameras 110 mm away across its middle: every edge eroded by 0.05 mm, and each
    cut face turned towards the cameras covers the gap beside its rim by 0.6 mm x tan(view angle from its plane)
    (0.14 mm at the end notches) - or, where a matcher averages the face's depth into the rim, uncovers as much
    (reach < 0). The spines' known length gives back both: the widths come out exact, where one erosion for every
    edge leaves the end notches 0.08 mm off (their seen face's cover is read as erosion spread over both edges)."""
    from ntcr_recon.core.relocation.notches import Notch, calibrate_rims, face_view_tangent

    geometry = TubeGeometry()
    centerline = straight_centerline(geometry.length + 1e-3)
    middle = geometry.length / 2
    cameras = np.array([[0.0, -0.11, middle], [0.0, 0.11, middle]])
    starts = geometry.notch_centers_s - geometry.notch_width / 2
    ends = starts + geometry.notch_width
    erosion = 0.05e-3
    start_v = face_view_tangent(centerline, starts, cameras, 1.0)
    end_v = face_view_tangent(centerline, ends, cameras, -1.0)
    assert start_v[0] > 0 and start_v[-1] == 0 and end_v[0] == 0 and end_v[-1] > 0  # each end sees one face
    observed = [Notch(i, (a + b) / 2, a - erosion + reach * va, b + erosion - reach * vb,
                      b - a + 2 * erosion - reach * (va + vb), 0.0)
                for i, (a, b, va, vb) in enumerate(zip(starts, ends, start_v, end_v, strict=True))]
    calibrated = calibrate_rims(observed, geometry, centerline, cameras)
    alone = calibrate_rims(observed, geometry)
    error = max(abs(n.width - geometry.notch_width) for n in calibrated)
    error_alone = max(abs(n.width - geometry.notch_width) for n in alone)
    print(f"\nrim calibration: widths within {error * 1e6:.1f} um (one erosion for all edges: "
          f"{error_alone * 1e6:.0f} um)")
    assert error < 1e-6
    assert max(abs(n.start_s - a) for n, a in zip(calibrated, starts, strict=True)) < 1e-6
    assert error_alone > 0.03e-3
    # faces a camera sees almost edge-on to the gap (the tube pointing at it): the tangent grows without bound,
    # but no face hides more than the whole gap, so no edge moves by more than a notch width
    pointing = np.array([[0.0, 0.0, geometry.length + 0.05], [0.0, -0.11, middle]])
    assert face_view_tangent(centerline, ends[-1:], pointing[:1], -1.0)[0] == 0.0  # the end face turns away
    assert face_view_tangent(centerline, starts[-1:], pointing[:1], 1.0)[0] > 1e3
    turned = calibrate_rims(observed, geometry, centerline, pointing)
    moved = max(max(abs(n.start_s - o.start_s), abs(n.end_s - o.end_s)) for n, o in zip(turned, observed,
                                                                                      strict=True))
    print(f"a camera on the robot's axis: no edge moved by more than {moved * 1e3:.3f} mm")
    assert moved <= geometry.notch_width


def test_each_spine_is_given_its_known_length_its_two_rims_sharing_what_it_reads_off():
    """Every rim of a straight robot read with its own error (0.04 mm sd, 200 robots): after calibration each
    spine between two measured notches is its nominal length, and the widths' error falls by about 1/sqrt(2) (the
    two rims of a spine are one unknown seen twice). A dip bounds no spine: its neighbours' far rims stay as they
    were measured, and one rim read 0.4 mm off is shared by the two notches it bounds."""
    from ntcr_recon.core.relocation.notches import Notch, calibrate_rims

    geometry = TubeGeometry()
    nominal = geometry.notch_pitch - geometry.notch_width
    starts = geometry.notch_centers_s - geometry.notch_width / 2
    ends = starts + geometry.notch_width

    def measured(start_error, end_error, signals=None):
        signals = signals or ["coverage"] * len(starts)
        return [Notch(i, (a + b) / 2, a + da, b + db, b - a + db - da, 0.0, signal)
                for i, (a, b, da, db, signal) in enumerate(zip(starts, ends, start_error, end_error, signals,
                                                               strict=True))]

    rng = np.random.default_rng(11)
    before, after = [], []
    for _ in range(200):
        error = rng.normal(0.0, 0.04e-3, (2, len(starts)))
        observed = measured(*error)
        calibrated = calibrate_rims(observed, geometry)
        spines = [b.start_s - a.end_s for a, b in zip(calibrated[:-1], calibrated[1:], strict=True)]
        assert np.allclose(spines, nominal, atol=1e-9)
        before += [n.width - geometry.notch_width for n in observed]
        after += [n.width - geometry.notch_width for n in calibrated]
    ratio = float(np.sqrt(np.mean(np.square(after)) / np.mean(np.square(before))))
    print(f"\nwidth error rms with each spine at its length / as measured: {ratio:.3f}")
    assert 0.65 < ratio < 0.8
    # one end rim read 0.4 mm early: half of it on each notch it bounds, not all on one
    end_error = np.zeros(len(starts))
    end_error[5] = -0.4e-3
    signals = ["coverage"] * len(starts)
    signals[8] = "dip"
    calibrated = calibrate_rims(measured(np.zeros(len(starts)), end_error, signals), geometry)
    widths = np.array([n.width for n in calibrated]) - geometry.notch_width
    assert np.allclose(widths[[5, 6]], [-0.2e-3, 0.2e-3], atol=1e-9)
    assert np.allclose(np.delete(widths, [5, 6]), 0.0, atol=1e-9)
    assert calibrated[7].end_s == pytest.approx(ends[7]) and calibrated[9].start_s == pytest.approx(starts[9])


def read_notch(geometry: TubeGeometry, index: int, start: float, end: float, bend: float,
              signal: str = "coverage") -> Notch:
    """A notch read between rims at start and end (m) on a robot bent `bend` there (its width the gap on the outer
    wall: the arc less bend x outer radius)."""
    return Notch(index, (start + end) / 2, start, end, end - start - bend * geometry.outer_radius, bend, signal)


def read_evenly_bent(geometry: TubeGeometry, bend: float) -> list[Notch]:
    """Every notch of a robot bent `bend` at each, read exactly where the bend puts it."""
    arc = geometry.notch_arc_at_bend(bend)
    centres = geometry.notch_centers_s - np.arange(geometry.notch_count) * geometry.neutral_axis_offset * bend
    return [read_notch(geometry, i, c - arc / 2, c + arc / 2, bend) for i, c in enumerate(centres)]


def test_a_notch_read_at_a_width_its_bend_rules_out_is_given_its_bends_and_its_neighbours_are_not_spoiled():
    """A robot bent 6 deg at each notch, its rims read exactly but notch 6's: only the middle 0.3 mm of its slot
    was seen through (a narrow run of coverage). Calibrated as measured, its error spreads to the spines it bounds
    (notches 5 and 7 read off); checked against the bends, notch 6 is given the arc and width its bend implies
    about its centre (signal "bend", the width read reported), and every other width is exact; where its next
    notch is missing near the tube's end, by the bend of the two notches before it, and with those missing too not
    at all (a warning names it unchecked). A notch read 0.1 mm wide - under a
    tenth of the cut width off its bend, a reading a robot could hold - is kept as measured."""
    from ntcr_recon.core.relocation.notches import MISREAD_WIDTH_FRACTION, calibrate_and_check, calibrate_rims

    geometry, bend = TubeGeometry(), math.radians(6.0)
    arc, width = geometry.notch_arc_at_bend(bend), geometry.notch_width_at_bend(bend)
    centres = geometry.notch_centers_s - np.arange(geometry.notch_count) * geometry.neutral_axis_offset * bend
    exact = read_evenly_bent(geometry, bend)
    narrow = [read_notch(geometry, 6, centres[6] - 0.15e-3, centres[6] + 0.15e-3, bend) if n.index == 6 else n
              for n in exact]
    spoiled = np.array([n.width for n in calibrate_rims(narrow, geometry)]) - width
    assert abs(spoiled[5]) > 0.1e-3 and abs(spoiled[7]) > 0.1e-3  # the misread rims shared with its neighbours

    checked, misread, _ = calibrate_and_check(narrow, geometry)
    assert set(misread) == {6} and misread[6] < width - MISREAD_WIDTH_FRACTION * geometry.notch_width
    by_index = {n.index: n for n in checked}
    assert by_index[6].signal == "bend" and not by_index[6].edges_measured
    assert by_index[6].width == pytest.approx(width, abs=1e-12)
    assert by_index[6].center_s == pytest.approx(centres[6], abs=1e-9)
    assert by_index[6].end_s - by_index[6].start_s == pytest.approx(arc, abs=1e-12)
    assert np.allclose([n.width for n in checked], width, atol=1e-9)
    # its next notch not found and the tube seen to just past it: the spine after it may run to a tube cut short,
    # its own bend is not trusted to check it, the bend of the two notches before it is; seen a pitch beyond, its own
    without_7 = [n for n in narrow if n.index != 7]
    assert 6 in calibrate_and_check(without_7, geometry, tip_s=centres[8]).misread
    by_earlier, flagged, not_checked = calibrate_and_check(without_7, geometry, tip_s=centres[7])
    assert set(flagged) == {6} and not_checked == []
    assert next(n for n in by_earlier if n.index == 6).width == pytest.approx(width, abs=1e-12)
    # ... and with neither (notches 4 and 5 not found either), it is left as read
    alone = [n for n in narrow if n.index not in (4, 5, 7)]
    unchecked, flagged, not_checked = calibrate_and_check(alone, geometry, tip_s=centres[7])
    assert 6 not in flagged and next(n for n in unchecked if n.index == 6).signal == "coverage"
    assert not_checked == [6]
    # ... and the result says its width was checked against nothing
    quality, said = assess(Trace(
        geometry=geometry, camera_names=("cam_a", "cam_b"), notches=unchecked,
        coords_s=np.linspace(0.0, centres[7], 500), camera=None, tip_s=centres[7],
        total_bend=bend * geometry.notch_count, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0,
        configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}, unchecked=not_checked))
    assert quality["notches_unchecked"] == [6]
    assert [w.figures["notches"] for w in said if w.code == "NOTCH_WIDTH_UNCHECKED"] == [[6]]

    wide = [read_notch(geometry, 6, n.start_s - 0.05e-3, n.end_s + 0.05e-3, bend) if n.index == 6 else n for n in exact]
    assert MISREAD_WIDTH_FRACTION * geometry.notch_width > 0.1e-3
    kept, none, _ = calibrate_and_check(wide, geometry)
    assert none == {} and {n.signal for n in kept} == {"coverage"}
    assert max(n.width for n in kept) - width > 0.04e-3  # still read wider: measured, not overwritten
    warnings = assess(Trace(
        geometry=geometry, camera_names=("cam_a", "cam_b"), notches=checked, coords_s=np.linspace(0.0, 50e-3, 500),
        camera=None, tip_s=50e-3, total_bend=bend * geometry.notch_count, footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
        misread_widths=misread))[1]
    print("\n" + " ".join(map(str, warnings)))
    (misread_finding,) = [w for w in warnings if w.code == "NOTCH_WIDTH_MISREAD"]
    assert misread_finding.figures["notches"] == [6]
    assert misread_finding.figures["read_width_mm"] == {"6": pytest.approx(misread[6] * 1e3)}
    assert misread_finding.figures["implied_width_mm"] == {"6": pytest.approx(width * 1e3)}


def test_the_last_notch_found_is_checked_against_the_bend_of_the_notches_before_it():
    """Where the tube seen thins out past the last notch found (its next one unseen, the end within a pitch), that
    notch's distal rim reads late (0.25-0.4 mm in the sweeps) and no whole spine beyond measures its own bend (its
    chord runs into a tube cut short: here it reads 4 deg for 2). Checked against the bend of the two notches before
    it, it is given the true width, not its own chord's bend's."""
    from ntcr_recon.core.relocation.notches import calibrate_and_check

    geometry, bend = TubeGeometry(), math.radians(2.0)
    width = geometry.notch_width_at_bend(bend)
    notches = read_evenly_bent(geometry, bend)[:9]  # notches 9-15 unseen
    last = notches[8]
    notches[8] = dataclasses.replace(last, end_s=last.end_s + 0.37e-3, width=last.width + 0.37e-3,
                                     bend=math.radians(4.0))
    tip_s = last.end_s + geometry.notch_pitch  # the tube seen ends within a pitch past the spine after it
    checked, misread, unchecked = calibrate_and_check(notches, geometry, tip_s=tip_s)
    given = next(n for n in checked if n.index == 8)
    own_chords = geometry.notch_width_at_bend(math.radians(4.0))
    print(f"\nthe last notch found, read {misread.get(8, given.width) * 1e3:.3f} mm: given {given.width * 1e3:.3f} "
          f"(true {width * 1e3:.3f}; its own chord's bend implies {own_chords * 1e3:.3f})")
    assert set(misread) == {8} and unchecked == [] and given.signal == "bend"
    assert given.width == pytest.approx(width, abs=1e-9)
    assert width - own_chords > 0.1e-3


def test_a_notch_bent_much_sharper_than_its_neighbours_keeps_the_width_it_reads():
    """A robot bent 2 deg at each notch but 12 at notch 7 (matrix row bend_kink), its rims read exactly. The smoothed
    centreline spreads the kink over three notches: their chords read 4.7, 6.3 and 4.7 deg. Notch 7's width, 0.52 mm
    narrower than its neighbours', is 0.30 mm off what its own chord's bend implies; with the bump's excess over the
    steady bend given back (notches.bump_at) its bend is 12 deg, and the width read is kept, also where the
    bump's own excess raises the scatter of all the chords (it is measured without the bump's span). The same width
    read where the chords show no bump is misread, and so is one where the chords scatter as much as the bump
    (noise, not a kink). A chord that wobbles turns two neighbours opposite ways: no bump."""
    from ntcr_recon.core.relocation.notches import bump_at, calibrate_and_check, chord_scatter

    geometry = TubeGeometry()
    true_bends = np.radians(np.where(np.arange(geometry.notch_count) == 7, 12.0, 2.0))
    notches, start = [], geometry.notch_centers_s[0] - geometry.notch_arc_at_bend(true_bends[0]) / 2
    for i, bend in enumerate(true_bends):  # each notch's arc as its bend shrinks it, the spines rigid between
        end = start + geometry.notch_arc_at_bend(bend)
        notches.append(read_notch(geometry, i, start, end, bend))
        start = end + geometry.notch_pitch - geometry.notch_width
    chords = np.radians(np.where(np.arange(geometry.notch_count) == 7, 6.3, 2.0))
    chords[[6, 8]] = np.radians([4.7, 4.7])
    kinked = [dataclasses.replace(n, bend=float(chords[n.index])) for n in notches]
    checked, misread, _ = calibrate_and_check(kinked, geometry)
    true_width = geometry.notch_width_at_bend(true_bends[7])
    kept = next(n for n in checked if n.index == 7)
    by_chord = geometry.notch_width_at_bend(chords[7])
    gathered = np.degrees(bump_at(dict(enumerate(chords)), 7).bend)
    print(f"\nnotch 7 read {kept.width * 1e3:.3f} mm (true {true_width * 1e3:.3f}; its chord's bend implies "
          f"{by_chord * 1e3:.3f}; its gathered bend {gathered:.1f} deg)")
    assert misread == {} and kept.signal != "bend" and kept.width == pytest.approx(true_width, abs=1e-6)
    assert by_chord - true_width > 0.25e-3
    flat = [dataclasses.replace(n, bend=float(np.radians(6.3 if n.index == 7 else 2.0))) for n in notches]
    assert set(calibrate_and_check(flat, geometry).misread) == {7}
    assert gathered == pytest.approx(11.7, abs=0.05)
    assert chord_scatter(dict(enumerate(chords))) == pytest.approx(0.0)
    rng = np.random.default_rng(3)  # chords scattered by 3 deg: the bump is noise's as much
    noisy = chords + np.radians(rng.normal(0.0, 3.0, len(chords)))
    assert np.degrees(chord_scatter(dict(enumerate(noisy)))) > 1.5
    scattered = [dataclasses.replace(n, bend=float(noisy[n.index])) for n in notches]
    assert 7 in calibrate_and_check(scattered, geometry).misread
    # the chords as bend_kink's centreline read them on one run: the bump's own excess scatters all sixteen by 0.93
    # deg, three times of which its neighbours' 2.3-2.9 deg do not exceed; without the bump's three, 0.41
    as_read = np.radians([1.88, 1.93, 2.05, 1.84, 2.18, 2.49, 4.51, 6.2, 5.07, 2.21, 1.96, 1.5, 1.74, 2.29, 2.44, 1.47])
    assert np.degrees(chord_scatter(dict(enumerate(as_read)))) > 0.9
    checked, misread, _ = calibrate_and_check([dataclasses.replace(n, bend=float(as_read[n.index])) for n in notches],
                                              geometry)
    assert 7 not in misread and next(n for n in checked if n.index == 7).width == pytest.approx(true_width, abs=1e-6)
    wobble = {i: np.radians(2.0) for i in range(16)} | {7: np.radians(3.0), 8: np.radians(1.0)}
    assert bump_at(wobble, 7) is None and bump_at(wobble, 8) is None
    assert bump_at(dict(enumerate(chords)), 0) is None and bump_at({7: 0.1, 8: 0.1}, 7) is None
    # chords as read on second-renderer scenes of robots bent evenly (4.8 deg at each of 20 notches, 4.5 at each of
    # 16): one alone off its neighbours, a curve that waves along the tube, chords falling towards its end
    lone = [4.57, 4.49, 4.52, 4.87, 4.96, 4.86, 4.76, 4.63, 4.51, 5.25, 5.52, 5.55, 4.81, 4.23, 0.27, 4.41, 4.73, 5.5,
            4.72, 4.62]
    waving = lone[:14] + [4.14] + lone[15:]
    falling = [4.27, 4.23, 4.24, 4.88, 4.36, 4.6, 4.18, 3.65, 4.1, 4.88, 5.92, 7.09, 5.26, 3.12, 2.59, 3.35]
    for even in (lone, waving, falling):
        assert bump_at(dict(enumerate(np.radians(even))), 14) is None


def test_a_kink_read_wide_is_given_the_bend_its_chords_gather_back_and_its_neighbours_the_steady_bend():
    """bend_kink (12 deg at notch 7, 2 at the others): notch 7's rims read it about 0.2 mm wide, a width its own
    chord (spread by the smoothed centreline) does not rule out. The bump's five chords, less the steady bend of four,
    give back its bend: that rules the width out, and notch 7 is given that bend's width; the notches beside it,
    judged by the steady bend, keep theirs. Those bends are the ones reported. So with the chords as read under the
    simulator's own matcher, and under one without its left-right check (the far neighbour's chord then only 2.9
    times the scatter beyond the steady bend: the bump of three chords each beyond three missed it)."""
    from ntcr_recon.core.relocation.notches import bend_implied, bump_at, calibrate_and_check

    geometry = TubeGeometry()
    true_bends = np.radians(np.where(np.arange(geometry.notch_count) == 7, 12.0, 2.0))
    notches, start = [], geometry.notch_centers_s[0] - geometry.notch_arc_at_bend(true_bends[0]) / 2
    for i, bend in enumerate(true_bends):
        end = start + geometry.notch_arc_at_bend(bend)
        widen = 0.18e-3 if i == 7 else 0.0  # notch 7's rims read too far apart (the spines beside share half)
        notches.append(read_notch(geometry, i, start - widen, end + widen, bend))
        start = end + geometry.notch_pitch - geometry.notch_width
    true_width = geometry.notch_width_at_bend(true_bends[7])
    own_matcher = [1.98, 1.77, 2.18, 1.86, 2.01, 2.42, 4.67, 6.16, 4.98, 2.29, 1.81, 1.5, 1.95, 2.11, 2.68, 1.4]
    no_left_right_check = [2.61, 1.91, 1.87, 1.63, 1.99, 3.0, 4.64, 5.83, 3.71, 2.62, 2.96, 1.91, 1.31, 2.02, 2.93,
                           1.03]
    for chords in (np.radians(own_matcher), np.radians(no_left_right_check)):
        assert np.degrees(bump_at(dict(enumerate(chords)), 7).bend) == pytest.approx(12.0, abs=1.3)
        checked, misread, _ = calibrate_and_check([dataclasses.replace(n, bend=float(chords[n.index]))
                                                   for n in notches], geometry)
        given = next(n for n in checked if n.index == 7)
        assert set(misread) == {7} and given.signal == "bend" and misread[7] - true_width > 0.1e-3
        assert abs(given.width - true_width) < 0.07e-3
        assert geometry.notch_width_at_bend(chords[7]) - true_width > 0.25e-3  # what its own chord would give
        assert max(abs(n.width - geometry.notch_width_at_bend(true_bends[n.index])) for n in checked) < 0.07e-3
        # the bends reported: the kink's and the steady one beside it, the span's total turn its chords'
        reported = np.array([n.bend for n in checked])
        assert np.degrees(np.abs(reported - true_bends)).max() < 1.3
        assert reported[5:10].sum() == pytest.approx(chords[5:10].sum(), abs=1e-12)
    # a notch two from the kink whose edges were not measured (a dip: its width its bend's, by the median of its own
    # and its neighbours' chords, one of them the kink's spread one) takes the width of the steady bend given back
    dip = bend_implied(dataclasses.replace(notches[9], bend=float(np.median(chords[8:11]))), geometry, "dip")
    with_dip = [dip if n.index == 9 else dataclasses.replace(n, bend=float(chords[n.index])) for n in notches]
    given = next(n for n in calibrate_and_check(with_dip, geometry).notches if n.index == 9)
    assert given.signal == "dip" and dip.width - geometry.notch_width_at_bend(true_bends[9]) < -0.05e-3
    assert given.width == pytest.approx(geometry.notch_width_at_bend(given.bend), abs=1e-12)
    assert abs(given.width - geometry.notch_width_at_bend(true_bends[9])) < 0.01e-3


def test_a_misread_notch_is_given_the_width_of_its_bend_taken_with_its_neighbours():
    """A robot bent 6 deg at each notch whose centreline wobbles at notch 6's far spine: notch 6 reads a bend of
    4 deg and notch 7 one of 8 (one chord turned, the two notches it joins off opposite ways). Notch 6's rims are
    misread (only the middle 0.3 mm of its slot seen through): the width it is given is the one the median of its
    own and its neighbours' bends implies, the true one, not its own bend's (0.1 mm wide)."""
    from ntcr_recon.core.relocation.notches import calibrate_and_check

    geometry, bend = TubeGeometry(), math.radians(6.0)
    width = geometry.notch_width_at_bend(bend)
    read_bends = np.full(geometry.notch_count, bend)
    read_bends[6:8] = np.radians([4.0, 8.0])
    notches = [dataclasses.replace(n, bend=float(read_bends[n.index])) for n in read_evenly_bent(geometry, bend)]
    centre = notches[6].center_s
    notches[6] = dataclasses.replace(notches[6], start_s=centre - 0.15e-3, end_s=centre + 0.15e-3, width=0.3e-3)
    checked, misread, _ = calibrate_and_check(notches, geometry)
    given = next(n for n in checked if n.index == 6)
    own = geometry.notch_width_at_bend(read_bends[6])
    print(f"\nnotch 6 misread: given {given.width * 1e3:.3f} mm (true {width * 1e3:.3f}, its own bend's "
          f"{own * 1e3:.3f})")
    assert set(misread) == {6} and given.signal == "bend"
    assert given.width == pytest.approx(width, abs=1e-9)
    assert own - width > 0.1e-3


def test_centreline_of_a_known_arc():
    """The fit reaches the tube's end and runs on a slab or so past it (the pipeline cuts it at the tip it
    finds), never past the robot's reach; up to the robot's length it lies on the arc."""
    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(60))
    sample = shape.sample_surface_parts(0.1e-3)
    outer = sample.part == 0
    settings = settings_for(GEOMETRY, FOOTPRINT, RelocationConfig())
    centerline, iterations, _ = estimate_centerline(sample.points[outer], GEOMETRY, settings)
    s = np.linspace(0.0, shape.length, 4000)
    truth, _ = shape.centerline(s)
    from ntcr_recon.core.quality.metrics import centerline_rmse

    rmse = centerline_rmse(centerline.points[centerline.s <= shape.length], truth)
    print(f"\n60 deg arc from its exact outer wall: centreline RMSE {rmse * 1e3:.4f} mm in {iterations} iterations, "
          f"{(centerline.length - shape.length) * 1e3:+.2f} mm past the tip")
    assert rmse < 0.02e-3
    assert shape.length - settings.bin_length < centerline.length < GEOMETRY.reach + settings.bin_length


def test_the_centreline_reaches_the_tube_end_the_cold_start_march_stopped_short_of():
    """An 18 deg arc's outer wall, and the end cap and last millimetre of bore a camera beside it sees through the
    open end. The march from the base stops short of the end (1.9 mm here) and its first refit moves the curve
    within the convergence tolerance everywhere but at the end: a fit settled on the interior alone returned the
    march's extent. Settled only once its extent holds to a slab, the curve reaches the tip."""
    from ntcr_recon.core.robot.surface import PART_END_CAP, PART_INNER_WALL, PART_OUTER_WALL

    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(18))
    sample = shape.sample_surface_parts(0.1e-3)
    camera = np.array([0.0, 0.09, 0.025])
    facing = np.einsum("ij,ij->i", sample.normals, camera - sample.points) > 0
    tip, tip_frame = shape.tip_pose()
    at_the_end = ((sample.points - tip) @ tip_frame[:, 2] > -1e-3) & facing
    seen = (sample.part == PART_OUTER_WALL) | (np.isin(sample.part, [PART_END_CAP, PART_INNER_WALL]) & at_the_end)
    settings = settings_for(GEOMETRY, FOOTPRINT, RelocationConfig())
    centerline, iterations, _ = estimate_centerline(sample.points[seen], GEOMETRY, settings)
    end = centerline.frames_at(np.array([min(shape.length, centerline.length)]))[0][0]
    print(f"\nfit in {iterations} iterations: {centerline.length * 1e3:.2f} mm long (the robot "
          f"{shape.length * 1e3:.2f}), its end {np.linalg.norm(end - tip) * 1e3:.3f} mm from the tip")
    assert abs(centerline.length - shape.length) < settings.bin_length
    assert np.linalg.norm(end - tip) < 0.15e-3


def test_a_warm_start_whose_free_end_is_off_is_refitted_there_not_returned_as_it_came():
    """A 30 deg arc's exact wall, warm-started from its own fit with the last 4 mm bowed 0.2 mm off the arc (a
    prior fitted on another frame's points can end so). The first refit puts the end back on the arc and moves the
    interior less than the convergence tolerance: a fit settled on the interior alone returned the prior as it
    came, bow and all, and the tip's direction with it (second renderer, scene 5018: tip 0.24 mm off, 0.08 mm
    once refitted). Judged at the free end too, the fit ends on the arc."""
    from ntcr_recon.core.quality.metrics import centerline_rmse

    shape = TubeShape.from_bend_angle(GEOMETRY, math.radians(30))
    sample = shape.sample_surface_parts(0.1e-3)
    wall = sample.points[sample.part == 0]
    settings = settings_for(GEOMETRY, FOOTPRINT, RelocationConfig())
    fit, _, _ = estimate_centerline(wall, GEOMETRY, settings)
    reach, bow = 4e-3, 0.2e-3
    assert reach < 2 * settings.smoothing_length + 3 * settings.bin_length  # within the stretch the interior leaves
    start = shape.length - reach
    offset = bow * np.sin(np.pi * np.clip((fit.s - start) / reach, 0.0, 1.0)) ** 2
    prior = Centerline.from_points(fit.points + offset[:, None] * fit.binormals, fit.binormals[0],
                                   float(fit.s[1] - fit.s[0]))
    centerline, iterations, _ = estimate_centerline(wall, GEOMETRY, settings, prior=prior)
    end_stretch = (centerline.s > start) & (centerline.s < shape.length)
    truth, _ = shape.centerline(np.linspace(0.0, shape.length, 4000))
    rmse = centerline_rmse(centerline.points[end_stretch], truth)
    print(f"\nprior bowed {bow * 1e3:.2f} mm off the arc over its last {reach * 1e3:.0f} mm; refitted in {iterations} "
          f"iterations: {rmse * 1e3:.4f} mm RMS there")
    assert rmse < 0.01e-3


def test_the_centreline_error_splits_into_along_and_across_the_cameras_views():
    """A straight axis along z, the estimate 0.05 mm off along y (towards the cameras) and 0.12 mm along x: for
    cameras facing each other along y the error is 0.05 along their views and 0.12 across; for cameras along x it
    is the other way round; the two parts add up to centerline_rmse."""
    from ntcr_recon.core.quality.metrics import centerline_error_by_view, centerline_rmse

    z = np.linspace(0.0, 30e-3, 301)
    truth = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    estimate = truth[5:-5] + [0.12e-3, 0.05e-3, 0.0]
    opposed_along_y = np.array([[0.0, -0.1, 0.015], [0.0, 0.1, 0.015]])
    along, across = centerline_error_by_view(estimate, truth, opposed_along_y)
    assert along == pytest.approx(0.05e-3, rel=1e-3) and across == pytest.approx(0.12e-3, rel=1e-3)
    along, across = centerline_error_by_view(estimate, truth, opposed_along_y[:, [1, 0, 2]])
    assert along == pytest.approx(0.12e-3, rel=1e-3) and across == pytest.approx(0.05e-3, rel=1e-3)
    assert math.hypot(along, across) == pytest.approx(centerline_rmse(estimate, truth), rel=1e-3)


def test_centreline_circles_leave_out_pixels_a_matcher_mixed_with_the_background():
    """A straight tube's wall (10 um noise) and, over its +x flank, as many pixels a stereo matcher mixed with the
    background behind: 0.25-0.5 mm outside the wall, well inside the fit's millimetre gate. Circles fitted over the
    whole gate leaned 70 um towards them; fitted over the wall's band (two footprints here) the axis stays within
    the fit's convergence tolerance (17.5 um) of the wall's."""
    length = 20e-3
    rng = np.random.default_rng(7)
    wall = wall_points(length, rng=rng)
    mixed = wall[wall[:, 0] > 0.9 * R_O].copy()
    mixed[:, :2] *= (1.0 + rng.uniform(0.25e-3, 0.5e-3, len(mixed)) / R_O)[:, None]
    settings = settings_for(GEOMETRY, FOOTPRINT, RelocationConfig())
    assert settings.gate > 0.5e-3  # the mixed pixels lie inside the fit's gate
    centerline, _, _ = estimate_centerline(np.vstack([wall, mixed]), GEOMETRY, settings)
    inside = centerline.points[(centerline.s > 2e-3) & (centerline.s < length - 2e-3)]
    print(f"\n{len(mixed)} mixed pixels on {len(wall)} wall points: axis at x = {inside[:, 0].mean() * 1e6:+.1f} um "
          f"(worst {np.abs(inside[:, :2]).max() * 1e6:.1f} um off)")
    assert np.abs(inside[:, :2]).max() < settings.tolerance


def test_the_smoothing_does_not_straighten_the_free_end_of_an_arc():
    """Nodes on a 20 mm arc, the data as strong as the prior: a penalty on the curvature itself makes a natural
    end (no curvature) and swings it out of the bend (155 um); penalising only the curvature's departure from
    the steady bend the curve holds leaves an exact arc where it is, to its end, while noise on it is smoothed
    (a third of what was added, at the end as within)."""
    from ntcr_recon.core.relocation.centerline import _smooth_update

    radius, step, count = 20e-3, 0.4e-3, 100
    phi = np.arange(count) * step / radius
    nodes = np.stack([radius * (1 - np.cos(phi)), np.zeros(count), radius * np.sin(phi)], axis=1)
    tangents = np.stack([np.sin(phi), np.zeros(count), np.cos(phi)], axis=1)
    normals = np.stack([np.cos(phi), np.zeros(count), -np.sin(phi)], axis=1)
    binormals = np.tile([0.0, 1.0, 0.0], (count, 1))
    axes = np.stack([normals, binormals], axis=1)
    information = 1e6 * (np.eye(3)[None] - tangents[:, :, None] * tangents[:, None, :])
    updated = _smooth_update(nodes, tangents, nodes, information, nodes[0], 4.0, axes, 15.0)
    deviation = np.linalg.norm(updated - nodes, axis=1)
    noise = np.random.default_rng(3).normal(0.0, 30e-6, (count, 1)) * normals
    smoothed = _smooth_update(nodes, tangents, nodes + noise, information, nodes[0], 4.0, axes, 15.0)
    left = np.linalg.norm(smoothed - nodes, axis=1)
    print(f"\nend of the arc {deviation[-1] * 1e6:.2f} um off it (interior at most {deviation[:-10].max() * 1e6:.2f}); "
          f"30 um noise smoothed to {np.sqrt(np.mean(left ** 2)) * 1e6:.1f} um RMS, the last 10 nodes "
          f"{np.sqrt(np.mean(left[-10:] ** 2)) * 1e6:.1f}")
    assert deviation.max() < 1e-6
    assert np.sqrt(np.mean(left**2)) < 10e-6 and np.sqrt(np.mean(left[-10:] ** 2)) < 15e-6


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
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints, geometry, 0.8e-3, FOOTPRINT, length)
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
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints, geometry, gate, FOOTPRINT, length)
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
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints, geometry, 0.8e-3, FOOTPRINT, length)
    moved = result.centerline.points[(result.centerline.s > 3e-3) & (result.centerline.s < 27e-3)]
    common = (flattening.max() - flattening.min()) / 2  # what one common level would read as a shift
    print(f"\ncameras at 80 and 105 mm: axis moved by at most {np.abs(moved[:, :2]).max() * 1e6:.1f} um (one level "
          f"for both: {common * 1e6:.0f} um towards the nearer camera); binormal lean "
          f"{result.bias_binormal * 1e6:+.1f} um")
    assert np.abs(moved[:, :2]).max() < 0.01e-3
    assert abs(result.bias_binormal) < 0.005e-3


def opposed_cameras_on_a_straight_tube(length: float = 30e-3):
    """A straight tube's wall (8 notches' geometry, none cut) seen by opposed cameras at -y and +y, each point by the
    one on its side: (geometry, points, camera index, viewpoints per point, centreline)."""
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, rng=np.random.default_rng(4))
    camera = (points[:, 1] > 0).astype(np.intp)
    viewpoints = np.array([[0.0, -0.09, 0.015], [0.0, 0.09, 0.015]])[camera]
    return geometry, points, camera, viewpoints, straight_centerline(length)


def test_cross_view_spread_is_how_far_each_camera_alone_puts_the_axis_across_its_view():
    """Opposed cameras at -y and +y see a straight tube on its axis: they agree (spread under 5 um). Then cam_a's
    wall is moved 0.1 mm across its view (+x), as a matcher's window reaching the slots on one side of its view
    moves it: cam_a alone puts the axis 0.1 mm off, cam_b on it, an RMS over the cameras of 0.1 / sqrt(2) mm;
    moved along its view (-y, a level) it places the axis no differently across."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)

    def spread(moved_by):
        moved = points + np.where(camera[:, None] == 0, moved_by, 0.0)
        coords, frames = centerline.project_with_frames(moved)
        return cross_view_spread(centerline, coords, frames, viewpoints, camera, 2, geometry, 0.8e-3, FOOTPRINT,
                                 length).spread

    agreed, across, along = spread([0.0, 0.0, 0.0]), spread([0.1e-3, 0.0, 0.0]), spread([0.0, -0.1e-3, 0.0])
    print(f"\ncameras agree: {agreed * 1e6:.1f} um; cam_a's wall 0.1 mm across its view: {across * 1e6:.1f} um "
          f"(expected {0.1e3 / math.sqrt(2):.1f}); along it: {along * 1e6:.1f} um")
    assert agreed < 10e-6 and along < 10e-6
    assert across == pytest.approx(0.1e-3 / math.sqrt(2), rel=0.1)
    # moved over the last window only (a matcher reaching the slots of the last notch), the spread over the length
    # stays small and the spread at the end (`distal`) is the camera's own 0.1 mm
    moved = points + np.where((camera[:, None] == 0) & (points[:, 2:] > length - 3e-3), [0.1e-3, 0.0, 0.0], 0.0)
    coords, frames = centerline.project_with_frames(moved)
    at_end = cross_view_spread(centerline, coords, frames, viewpoints, camera, 2, geometry, 0.8e-3, FOOTPRINT, length)
    print(f"cam_a's wall moved 0.1 mm over the last window: over the length {at_end.spread * 1e6:.1f} um, at the "
          f"end {at_end.distal * 1e6:.1f} um")
    assert at_end.distal == pytest.approx(0.1e-3 / math.sqrt(2), rel=0.1)
    assert at_end.spread < 0.5 * at_end.distal
    # too few trusted points in every window (the tube seen only edge-on): nothing to tell
    edge_on = np.abs(points[:, 0]) > 0.99 * R_O
    coords, frames = centerline.project_with_frames(points[edge_on])
    seen_edge_on = cross_view_spread(centerline, coords, frames, viewpoints[edge_on], camera[edge_on], 2, geometry,
                                     0.8e-3, FOOTPRINT, length)
    assert seen_edge_on.spread is None
    margin = alignment.SILHOUETTE_MARGIN_PX * FOOTPRINT
    assert len(seen_edge_on.unsupported) == 1
    assert seen_edge_on.unsupported[0] == pytest.approx((margin, length - margin))


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


def test_the_outline_check_finds_an_axis_moved_across_the_views_not_along_them():
    """Opposed cameras at -y and +y see a straight tube's wall, each its own half: the middle of each camera's outline
    (its points' extent along x, across its view) lies on the true axis; an axis 0.3 mm off along x lies 0.3 mm from
    both middles, one 0.3 mm off along y (along the views) on them. Seen end-on (the cameras on the tube's axis) no
    outline checks it; nor where the extent is not the tube's diameter (the wall's half cut away)."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)

    def offset(shift, kept=slice(None), at=viewpoints):
        moved = Centerline.from_points(centerline.points + shift, np.array([0.0, 1.0, 0.0]), 0.1e-3)
        coords, frames = moved.project_with_frames(points[kept])
        return outline_offset(coords, frames, points[kept], at[kept], camera[kept], geometry, 0.8e-3, length)

    on_axis, across, along = offset([0.0, 0.0, 0.0]), offset([0.3e-3, 0.0, 0.0]), offset([0.0, 0.3e-3, 0.0])
    print(f"\noutline offset: axis on the tube {on_axis * 1e6:.1f} um, 0.3 mm across the views {across * 1e6:.1f} um, "
          f"0.3 mm along them {along * 1e6:.1f} um")
    assert on_axis < 10e-6 and along < 10e-6
    assert across == pytest.approx(0.3e-3, abs=10e-6)
    end_on = np.tile([0.0, 0.0, 0.12], (len(points), 1))
    assert offset([0.3e-3, 0.0, 0.0], at=end_on) is None
    assert offset([0.3e-3, 0.0, 0.0], kept=points[:, 0] > 0) is None


def test_the_fit_places_the_axis_across_the_views_and_the_alignment_along_them():
    """A straight axis along z and a reference 0.2 mm off it along x, 0.1 mm along y. Opposed cameras at -y and +y
    (both views along y, across them x): the axis takes the reference's x and keeps its own y, and the alignment
    moved to it reports that move as its lean and its end's move. Cameras at -y and +x (views 90 deg apart): what
    is along one view is across the other, and the axis takes the reference's place whole."""
    z = np.linspace(0.0, 30e-3, 301)
    axis = Centerline.from_points(np.stack([0 * z, 0 * z, z], axis=1), np.array([0.0, 1.0, 0.0]), 0.1e-3)
    offset = np.array([0.2e-3, 0.1e-3, 0.0])
    reference = Centerline.from_points(axis.points + offset, np.array([0.0, 1.0, 0.0]), 0.1e-3)
    opposed = across_views_from(reference, axis, np.array([[0.0, -0.09, 15e-3], [0.0, 0.09, 15e-3]]))
    crossed = across_views_from(reference, axis, np.array([[0.0, -0.09, 15e-3], [0.09, 0.0, 15e-3]]))
    print(f"\nmoved by (um): opposed cameras {np.round(np.mean(opposed.points - axis.points, axis=0) * 1e6, 2)}, "
          f"cameras 90 deg apart {np.round(np.mean(crossed.points - axis.points, axis=0) * 1e6, 2)}")
    np.testing.assert_allclose(opposed.points - axis.points, np.tile([0.2e-3, 0.0, 0.0], (len(axis.s), 1)),
                               atol=1e-9)
    np.testing.assert_allclose(crossed.points - axis.points, np.tile(offset, (len(axis.s), 1)), atol=1e-9)
    moved = alignment.Alignment(axis, 0.0, 0.0, 0).moved_to(opposed, axis)
    assert moved.centerline is opposed and moved.end_shift == pytest.approx(0.2e-3)
    # the axis's normal (towards the notch side) is x here: the fit leaned 0.2 mm away from it
    assert moved.bias_notch_side == pytest.approx(-0.2e-3) and moved.bias_binormal == pytest.approx(0.0, abs=1e-12)


def test_a_stretch_where_no_camera_sees_its_wall_facing_it_is_reported_unsupported():
    """Past s = 21 mm of a 30 mm tube, both cameras see only its wall edge-on (as where a matcher spoils every pixel
    whose window meets the background): the windows there hold no trusted point, and the stretch from 21 mm to the
    end's margin is reported; a 3 mm window (one notch pitch) thinned alone is bridged, not reported."""
    length = 30e-3
    geometry, points, camera, viewpoints, centerline = opposed_cameras_on_a_straight_tube(length)
    margin = alignment.SILHOUETTE_MARGIN_PX * FOOTPRINT

    def unsupported(kept):
        coords, frames = centerline.project_with_frames(points[kept])
        return cross_view_spread(centerline, coords, frames, viewpoints[kept], camera[kept], 2, geometry, 0.8e-3,
                                 FOOTPRINT, length).unsupported

    edge_on = np.abs(points[:, 0]) > 0.99 * R_O
    distal = unsupported(edge_on | (points[:, 2] < 21e-3))
    one_window = unsupported(edge_on | (points[:, 2] < 12e-3) | (points[:, 2] >= 15e-3))
    print(f"\nunsupported: distal {np.round(np.array(distal) * 1e3, 2).tolist()} mm, one window "
          f"{np.round(np.array(one_window) * 1e3, 2).tolist()} mm")
    assert len(distal) == 1 and distal[0] == pytest.approx((21e-3, length - margin))
    assert one_window == ()


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
        return level_by_backbone(given, coords, frames, origins[camera], camera, origins, GEOMETRY, 0.8e-3,
                                 FOOTPRINT, length)

    moved, rms = levelled(np.array([[0.09, 0.0, 0.025], [-0.09, 0.0, 0.025]]))
    middle = moved.points[(moved.s > 15e-3) & (moved.s < 40e-3)]
    print(f"\naxis between the notches now at x = {middle[:, 0].min() * 1e3:+.3f} .. {middle[:, 0].max() * 1e3:+.3f} "
          f"mm (given -0.150), moved by {rms * 1e3:.3f} mm RMS")
    assert np.abs(middle[:, 0]).max() < 0.02e-3 and np.abs(middle[:, 1]).max() < 0.01e-3
    assert rms == pytest.approx(0.15e-3, abs=0.02e-3)
    side_on, none = levelled(np.array([[0.0, 0.09, 0.025], [0.0, -0.09, 0.025]]))
    assert side_on is given and none == 0.0


def cameras_round_the_tube(angles_deg, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cameras 90 mm from a straight tube along z, at these angles round it from the notch side (+x), each point
    seen by the one it faces most: (angles in rad, the cameras' origins (C, 3), each point's camera index)."""
    angles = np.radians(angles_deg)
    origins = np.stack([0.09 * np.cos(angles), 0.09 * np.sin(angles), np.full(len(angles), 0.025)], axis=1)
    camera = (np.einsum("ij,cj->ic", points[:, :2], origins[:, :2]).argmax(axis=1)).astype(np.intp)
    return angles, origins, camera


def leaning_between_the_notches(toward: np.ndarray, lean: float) -> tuple[np.ndarray, Centerline]:
    """A straight axis along z put `lean` (m) towards the direction `toward` (x, y) between the first and the last
    cut, ramped over 1 mm at each: (its samples' s, the axis)."""
    length, first = GEOMETRY.length, GEOMETRY.proximal_length
    last = length - GEOMETRY.distal_length
    s = np.linspace(0.0, length, int(length / 0.1e-3) + 1)
    off = lean * np.clip(np.minimum(s - first, last - s) / 1e-3, 0.0, 1.0)
    return s, Centerline.from_points(np.stack([off * toward[0], off * toward[1], s], axis=1),
                                     np.array([0.0, 1.0, 0.0]), 0.1e-3)


def beyond_slot_edge(points: np.ndarray, camera_angle) -> np.ndarray:
    """Across the view of a camera at `camera_angle` round the straight tube (rad from the notch side; one, or one per
    point), from the slots' edge on its side to each wall point (m; +: towards the backbone): what
    alignment.clear_of_slots_in_view measures, written out here on the known geometry."""
    phi = np.arctan2(points[:, 1], points[:, 0])
    side = np.sign(camera_angle)
    return side * R_O * (np.sin(phi - camera_angle) - np.sin(side * GEOMETRY.gap_half_angle - camera_angle))


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
    moved, rms = level_by_backbone(given, coords, frames, origins[camera], camera, origins, GEOMETRY, 0.8e-3,
                                   FOOTPRINT, length)
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
    moved, rms = level_by_backbone(given, coords, frames, origins[camera], camera, origins, GEOMETRY, 0.8e-3,
                                   footprint, length)
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
    moved, rms = level_by_backbone(given, coords, frames, origins[camera[kept]], camera[kept], origins, GEOMETRY,
                                   0.8e-3, FOOTPRINT, length)
    middle = moved.frames_at(s[(s > 10e-3) & (s < 40e-3)])[0]
    print(f"\naxis between the notches now {np.abs(middle[:, :2] @ toward).max() * 1e3:.3f} mm towards the camera "
          f"facing the backbone at most (given 0.150)")
    assert np.abs(middle[:, :2]).max() < 0.03e-3


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
    wide = align_to_trusted_wall(centerline, coords, frames, viewpoints, geometry, 0.8e-3, FOOTPRINT, length,
                                 silhouette_margin_px=0.0)
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints, geometry, 0.8e-3, FOOTPRINT, length)
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
        result = align_to_trusted_wall(axis, coords, frames, origins[camera], GEOMETRY, 0.8e-3, FOOTPRINT, length,
                                       slot_margin_px=slot_margin_px)
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
    result = align_to_trusted_wall(given, coords, frames, viewpoints, geometry, 0.8e-3, FOOTPRINT, length, xyz=points,
                                   passes=3)
    middle = (result.centerline.s > 3e-3) & (result.centerline.s < 27e-3)
    error = np.abs(result.centerline.points[middle, 0]).max()
    print(f"\ncentreline given {lean * 1e3:.2f} mm off: {error * 1e3:.3f} mm off after three passes; lean reported "
          f"{result.bias_notch_side * 1e3:+.3f} mm")
    assert error < 0.03e-3
    assert result.bias_notch_side == pytest.approx(lean, abs=0.01e-3)


def test_quality_says_what_is_doubtful():
    notches = []
    s = np.linspace(0.0, 50e-3, 5000)
    camera = np.where(s < 40e-3, np.arange(len(s)) % 2, 1).astype(np.int8)  # cam_b alone past 40 mm
    share, alone = camera_coverage(s, camera, ("cam_a", "cam_b"), 50e-3, 0.25e-3, pool=3.5e-3)
    assert alone["cam_b"] == pytest.approx(10e-3, abs=0.5e-3) and alone["cam_a"] == 0.0
    assert share["cam_a"] == pytest.approx(0.8, abs=0.02)
    # a stray cam_a point every 0.7 mm past 40 mm (a twentieth of its density before) is no view of the tube
    stray = (s >= 40e-3) & (np.arange(len(s)) % 70 == 0)
    share_stray, alone_stray = camera_coverage(s, np.where(stray, 0, camera).astype(np.int8), ("cam_a", "cam_b"),
                                               50e-3, 0.25e-3, pool=3.5e-3)
    assert alone_stray["cam_b"] == pytest.approx(10e-3, abs=1e-3)
    assert share_stray["cam_a"] == pytest.approx(0.8, abs=0.04)
    quality, warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=notches, coords_s=s,
        camera=camera, tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.05e-3,
        notch_side=math.radians(20), configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
        depth_steps={"cam_a": 1e-3, "cam_b": 1e-4}))
    print("\n" + "\n".join(map(str, warnings)))
    said = _by_code(warnings)
    assert said["NOTCHES_MISSING"][0].figures["missing"] == list(range(16))
    assert [(w.figures["camera"], round(w.figures["length_mm"])) for w in said["DISTAL_ONE_CAMERA"]] == [("cam_b", 10)]
    (short,) = said["TUBE_ENDS_SHORT"]
    assert short.figures["short_of_length_mm"] > 0
    (rolled,) = said["ROBOT_ROLLED"]
    assert rolled.figures["side_off_deg"] == pytest.approx(20.0)
    assert [(w.figures["camera"], w.figures["depth_step_mm"]) for w in said["DEPTH_QUANTISED"]] == [
        ("cam_a", pytest.approx(1.0))]
    assert quality["notches_found"] == 0 and quality["notch_side_deg"] == pytest.approx(20.0)
    assert not short.figures["at_crop_box"]
    # no uncertainty stated for the side: the offset is a roll
    assert rolled.figures["side_uncertainty_deg"] is None
    # a side measured +20 deg off yet known only to +-25 deg (one edge of the window placed it) is no proof of a roll
    for known_deg, rolled_beyond in ((5.0, True), (25.0, False)):  # is rolled / may be rolled
        side_warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=notches, coords_s=s, camera=camera,
            tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.05e-3, notch_side=math.radians(20),
            configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
            side_uncertainty=math.radians(known_deg)))[1]
        (side,) = _by_code(side_warnings)["ROBOT_ROLLED"]
        assert side.figures["side_uncertainty_deg"] == pytest.approx(known_deg)
        assert (abs(side.figures["side_off_deg"]) > side.figures["side_uncertainty_deg"]) == rolled_beyond
    cap_warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a",), notches=[], coords_s=s,
        camera=np.zeros(len(s), np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
        tip_uncertainty=0.26e-3, tip_from_cap=True))[1]
    (cap,) = _by_code(cap_warnings)["TIP_ON_END_CAP"]
    assert cap.figures["along_mm"] == pytest.approx(0.26)  # the cap's points smeared over that much
    assert "TIP_ON_ERODED_RIM" not in _by_code(cap_warnings)


def test_quality_tells_a_tube_cut_short_by_the_crop_box_from_one_that_ends_inside_it():
    box = (np.array([-0.05, -0.05, 0.0]), np.array([0.05, 0.05, 0.06]))
    s = np.linspace(0.0, 30e-3, 3000)

    def warnings_for(tip):
        return _by_code(assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a",), notches=[], coords_s=s,
            camera=np.zeros(len(s), np.int8), tip_s=30e-3, total_bend=0.0, footprint=FOOTPRINT,
            wall_residual=0.0, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
            depth_steps={}, tip_position=np.array(tip), crop_box=box))[1])

    (on_face,) = warnings_for([0.02, 0.0, 0.5e-3])["TUBE_ENDS_SHORT"]    # the robot curled down to the base plane
    print("\n" + str(on_face))
    assert on_face.figures["short_of_length_mm"] > 0 and on_face.figures["at_crop_box"]
    assert on_face.figures["crop_box_face"] == "z" and on_face.figures["crop_box_face_mm"] == pytest.approx(0.0)
    (inside,) = warnings_for([0.0, 0.0, 0.03])["TUBE_ENDS_SHORT"]
    assert inside.figures["short_of_length_mm"] > 0 and not inside.figures["at_crop_box"]
    assert inside.figures["crop_box_face"] is None


def test_quality_says_when_no_camera_showed_the_tubes_outline_whole():
    """The outline check runs on points that carry their camera: where no window's outline spanned the tube's
    diameter (outline_offset None) the centreline went unchecked across the views, and the result says so, and
    states it, and the tip at its free end, as uncertain as the pixel footprint the check resolves at least (the
    cameras' spread said 0.02 mm); an outline measured, or clouds without cameras (no check to run), say nothing of
    it and state the spread."""
    s = np.linspace(0.0, 30e-3, 3000)

    def assessed(camera, outline_offset):
        quality, warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s, camera=camera,
            tip_s=30e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
            bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}, outline_offset=outline_offset,
            cross_view_spread=0.02e-3))
        return quality, _by_code(warnings)

    cameras = (np.arange(len(s)) % 2).astype(np.int8)
    quality, unchecked = assessed(cameras, None)
    print("\n" + " ".join(map(str, unchecked.get("OUTLINE_UNCHECKED", []))))
    (outline,) = unchecked["OUTLINE_UNCHECKED"]
    assert outline.figures["pixel_footprint_mm"] == pytest.approx(0.20)  # stated at least that uncertain
    # the tip across the tube is the centreline's free end
    assert [w.figures["across_because"] for w in unchecked["TIP_ON_ERODED_RIM"]] == ["free_end"]
    assert quality["centerline_uncertainty_mm"] == pytest.approx(FOOTPRINT * 1e3)
    assert quality["tip_across_uncertainty_mm"] >= FOOTPRINT * 1e3
    for camera, offset in ((cameras, 0.02e-3), (None, None)):
        quality, checked = assessed(camera, offset)
        assert "OUTLINE_UNCHECKED" not in checked and quality["centerline_uncertainty_mm"] == pytest.approx(0.02)


def test_the_surface_depth_nearest_a_camera_is_the_axis_less_the_ring_it_turns_to_the_camera():
    looking_down_x = np.eye(4)
    looking_down_x[:3, :3] = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]  # optical z = base -x
    looking_down_x[:3, 3] = [0.08, 0.0, 0.0]
    axis = np.array([[0.0, 0.0, 0.01], [0.0, 0.0, 0.01], [0.0, 0.0, 0.01]])
    tangents = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [math.sqrt(0.5), 0.0, math.sqrt(0.5)]])
    depth = surface_depth(axis, tangents, looking_down_x, R_O)
    print(f"\nside-on, end-on, at 45 deg: {depth * 1e3} mm")
    # side-on the near wall, end-on the end cap's disc (at the axis's depth), at 45 deg its rim
    assert depth == pytest.approx([0.08 - R_O, 0.08, 0.08 - R_O * math.sqrt(0.5)], abs=1e-9)


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


def test_a_camera_that_missed_a_stretch_is_named_with_why_too_near_or_end_on():
    """A robot bent 90 deg towards cam_a of a 90 mm rig (matrix row bend90_toward_cam_a_90mm): its distal part
    comes within 60 mm of cam_a, which sees nothing nearer than 70 mm (here, than 70.5). Seen by cam_b alone
    there, or cut short where cam_a's view ends, the warning says why; bent away from cam_a along its line of
    sight, it names that; bent side-on, it gives no reason. Bent 90 deg along the cameras' lines of sight, its
    distal part points within 30 deg of both: every camera sees that wall edge-on, and the result says so."""
    from ntcr_recon.sim.camera import facing_pair

    cameras = facing_pair(0.09)
    extrinsics = {pose.name: pose.extrinsic for pose in cameras}

    def warned(towards_deg, tip_s=None, unsupported=(), carry=False):
        """The warnings of a robot bent 90 deg towards the camera at towards_deg (-90: cam_a, 90: cam_b) seen
        up to tip_s, cam_a's points only where the tube is 70 mm from it or more and short of 40 mm along it."""
        shape = TubeShape.from_bend_angle(dataclasses.replace(GEOMETRY, notch_side=math.radians(towards_deg)),
                                          math.radians(90.0))
        tip_s = shape.length if tip_s is None else tip_s
        sample = shape.sample_surface_parts(0.2e-3)
        by_a = (cameras[0].to_camera(sample.points)[:, 2] >= 0.07) & (sample.s < 40e-3)
        xyz = np.concatenate([sample.points[by_a], sample.points])
        camera = np.concatenate([np.zeros(np.count_nonzero(by_a)), np.ones(len(sample.points))]).astype(int)
        centres = expected_centres(shape.geometry, true_centerline(shape))
        carried = continued_bend(true_centerline(shape).up_to(tip_s), shape.length, centres, GEOMETRY)
        reach = camera_reach(carried, tip_s, shape.length, R_O, FOOTPRINT, extrinsics, xyz, camera)
        s = np.concatenate([sample.s[by_a], sample.s])
        total_bend, tip_along = math.radians(90.0 * tip_s / shape.length), None
        if carry:  # to the robot's length, as the pipeline does where the rest is hidden
            tip_along = carried_to_length(TipAlongTube(tip_s, 0.1e-3, tip_s, 0.1e-3, shape.length, 0.1e-3),
                                          continued_bend(true_centerline(shape).up_to(tip_s), GEOMETRY.reach,
                                                         centres, GEOMETRY))
            tip_s, total_bend = tip_along.s, math.radians(90.0)
        quality, warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s, camera=camera,
            tip_s=tip_s, total_bend=total_bend, footprint=FOOTPRINT, tip_along=tip_along,
            wall_residual=0.0, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
            depth_steps={}, reach=reach, notch_centres=expected_centres(shape.geometry, true_centerline(shape)),
            unsupported=unsupported))
        return quality, _by_code(warnings)

    quality, seen_alone = warned(-90.0)
    print(f"\n{_text(seen_alone)}\nnearest returned {quality['camera_nearest_depth_mm']}, "
          f"tube's nearest {quality['tube_nearest_depth_mm']}")
    (alone,) = seen_alone["DISTAL_ONE_CAMERA"]
    assert alone.figures["camera"] == "cam_b"
    assert alone.figures["too_near_mm"] == {"cam_a": pytest.approx(60.0, abs=0.5)} and alone.figures["end_on_deg"] == {}
    assert quality["camera_nearest_depth_mm"]["cam_a"] == pytest.approx(70.5, abs=0.3)
    assert quality["tube_nearest_depth_mm"]["cam_a"] == pytest.approx(59.9, abs=0.3)
    # no notch was found (none given): those past 40 mm, where cam_a's points stop, are named with why
    (missing,) = seen_alone["NOTCHES_MISSING"]
    assert missing.figures["unseen_by"] == {"cam_a": [12, 13, 14, 15]}
    assert 60.0 <= quality["tube_nearest_depth_mm"]["cam_a"] + 0.5 < 70.0  # (it comes within 6x mm of cam_a)
    short_quality, cut_short = warned(-90.0, tip_s=38e-3)  # the tube's end found where cam_a stops seeing it
    print(_text(cut_short))
    (ends,) = cut_short["TUBE_ENDS_SHORT"]  # not carried on
    assert "TIP_CARRIED" not in cut_short
    assert ends.figures["too_near_mm"] == {"cam_a": pytest.approx(60.0, abs=0.5)}  # continued at its last bend
    (missing,) = cut_short["NOTCHES_MISSING"]
    assert missing.figures["beyond_end"] == [12, 13, 14, 15] and short_quality["tip_seen_s_mm"] == pytest.approx(38.0)
    shortfall = ends.figures["short_of_length_mm"]
    assert 10.0 <= shortfall < 20.0
    # left at the end seen, the tip may lie as far off as the rest of the robot reaches, and its figures say so (a
    # controller reads those, not the warning): the shortfall along the tube and across it
    assert short_quality["tip_uncertainty_mm"] == pytest.approx(shortfall, abs=0.05)
    assert short_quality["tip_across_uncertainty_mm"] == pytest.approx(shortfall, abs=0.05)
    # carried on to the robot's length past where cam_a was too near to see: the tip and the centreline's stated
    # uncertainty count what a straight hidden part would leave them off, and the warning says where the tip is
    carried_quality, carried = warned(-90.0, tip_s=38e-3, carry=True)
    print(_text(carried))
    (carried_on,) = carried["TIP_CARRIED"]
    assert 10.0 <= carried_on.figures["short_of_length_mm"] < 20.0
    assert carried_on.figures["too_near_mm"] == {"cam_a": pytest.approx(60.0, abs=0.5)}
    assert carried["NOTCHES_MISSING"][0].figures["beyond_end"] == [12, 13, 14, 15]
    assert carried_quality["tip_seen_s_mm"] == pytest.approx(38.0)
    assert "TIP_ON_ERODED_RIM" not in carried  # (the tip is not where the end was seen)
    assert carried_quality["tip_across_uncertainty_mm"] > 1.0 and carried_quality["tip_uncertainty_mm"] > 0.1
    assert carried_quality["centerline_uncertainty_mm"] > 0.3
    assert carried_quality["tip_seen_s_mm"] == pytest.approx(38.0)
    assert carried_quality["tip_hidden_mm"] == pytest.approx(carried_quality["tip_s_mm"] - 38.0)
    assert carried_quality["tip_hidden_mm"] > 10.0
    assert quality["tip_hidden_mm"] == 0.0
    # bent towards cam_b, away from cam_a along its line of sight: cam_a sees the distal wall nearly edge-on
    _, away = warned(90.0)
    print(_text(away))
    (alone,) = away["DISTAL_ONE_CAMERA"]
    assert alone.figures["camera"] == "cam_b" and alone.figures["too_near_mm"] == {}
    assert set(alone.figures["end_on_deg"]) == {"cam_a"}
    # bent side-on, whatever hid the distal part from cam_a, it was neither: no reason given
    side_on_quality, side_on = warned(0.0)
    print(_text(side_on))
    (alone,) = side_on["DISTAL_ONE_CAMERA"]
    assert alone.figures["camera"] == "cam_b"
    assert alone.figures["too_near_mm"] == {} and alone.figures["end_on_deg"] == {}  # no reason given
    # along the lines of sight, the last ~20 deg of the bend lie within 30 deg of both (notch pitch 3.2 mm)
    assert 8.0 < quality["distal_end_on_mm"] < 16.0 and side_on_quality["distal_end_on_mm"] == 0.0
    (end_on,) = seen_alone["DISTAL_END_ON"]
    assert end_on.figures["length_mm"] == pytest.approx(quality["distal_end_on_mm"])
    assert set(end_on.figures["angles_deg"]) == {"cam_a", "cam_b"}
    assert "DISTAL_END_ON" not in side_on
    # where a stretch without trusted wall reaches the tip, its warning says as much: not said twice
    _, unsupported = warned(-90.0, unsupported=((42e-3, 50e-3),))
    (stretch,) = unsupported["CENTERLINE_UNSUPPORTED"]
    assert stretch.figures["to_tip"] and stretch.figures["stretches_mm"] == [[pytest.approx(42.0), pytest.approx(50.0)]]
    assert "DISTAL_END_ON" not in unsupported


def test_the_distal_stretch_every_camera_sees_end_on_is_measured_from_the_tip_back():
    """Sight angles sampled along s: cam_a's axis turns within 30 deg of its line of sight from 30 mm on, cam_b's
    from 25 mm on, and back out of it past 45 mm. Seen to 40 mm, the distal 10 mm is end-on to both (least angles
    20 and 10 deg); seen to 50 mm, the tube ends outside it: none."""
    from ntcr_recon.core.quality.measures import CameraReach

    s = np.arange(0.0, 50.25e-3, 0.25e-3)
    past = s > 45e-3
    sight = {"cam_a": np.radians(np.where((s >= 30e-3) & ~past, 20.0, 60.0)),
             "cam_b": np.radians(np.where((s >= 25e-3) & ~past, 10.0, 60.0))}
    reach = CameraReach(s, {name: np.full_like(s, 0.09) for name in sight}, {}, sight)
    length, angles = reach.end_on_to_every_camera(40e-3)
    assert length == pytest.approx(10e-3) and angles == pytest.approx({"cam_a": np.radians(20.0),
                                                                       "cam_b": np.radians(10.0)})
    assert reach.end_on_to_every_camera(50e-3) == (0.0, {})


def test_missing_notches_are_placed_beyond_the_end_seen_or_where_a_camera_did_not_see_the_tube():
    """Both cameras see the tube to 40 mm, cam_b alone beyond; the end is seen at 45 mm. Of the notches missing,
    one both cameras saw is named unmarked, with what a depth pixel is against its cut; those past 40 mm are where
    cam_a did not see the tube (the one whose cut straddles the end seen too); those whose cut lies past 45 mm are
    beyond the end seen."""
    s = np.linspace(0.0, 50e-3, 5000)
    camera = np.where(s < 40e-3, np.arange(len(s)) % 2, 1).astype(np.int8)
    centres = GEOMETRY.notch_centers_s  # 5.75, 8.75, ..., 41.75, 44.75, 47.75, 50.75 mm
    missing = [3, 12, 13, 14, 15]
    beyond, unseen = where_notches_went_unseen(missing, centres, GEOMETRY.notch_width / 2, s, camera,
                                               ("cam_a", "cam_b"), 45e-3, 0.25e-3, pool=3.5e-3)
    assert beyond == [14, 15] and unseen == {"cam_a": [12, 13]}
    width = GEOMETRY.notch_width
    found = [Notch(i, c, c - width / 2, c + width / 2, width, 0.0) for i, c in enumerate(centres) if i not in missing]
    quality, warnings = assess(Trace(
        geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=found,
        coords_s=s, camera=camera, tip_s=45e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
        notch_centres=centres))
    print("\n" + str(warnings[0]))
    assert warnings[0].code == "NOTCHES_MISSING" and warnings[0].severity == "warn"
    assert dict(warnings[0].figures) == {"missing": [3, 12, 13, 14, 15], "beyond_end": [14, 15],
                                         "unseen_by": {"cam_a": [12, 13]}, "unmarked": [3]}
    assert quality["notches_found"] == 11 and quality["tip_seen_s_mm"] == pytest.approx(45.0)
    assert quality["notches_missing_beyond_end"] == [14, 15] and quality["notches_missing_unmarked"] == [3]
    assert quality["notches_missing_unseen_by"] == {"cam_a": [12, 13]}


def test_quality_measures_a_wall_that_reads_deeper_between_the_notches_than_on_the_plain_tube():
    """Spines averaged with the slot floors behind them read deep; the plain tube beyond the notches does not.
    The figure does not depend on the pooled level's common part (where the axis was put), and above half a
    footprint it is a warning."""
    rng = np.random.default_rng(3)
    s = rng.uniform(0.0, 50e-3, 20000)
    cuts = np.array([(c - GEOMETRY.notch_width / 2, c + GEOMETRY.notch_width / 2) for c in GEOMETRY.notch_centers_s])
    between = (s > cuts[0, 0]) & (s < cuts[-1, 1])
    noise = rng.normal(0.0, 0.02e-3, len(s))

    def thinning(deep, common=0.0):
        offset = common - 0.1e-3 - np.where(between, deep, 0.0) + noise
        return notched_thinning(offset, s, cuts, 50e-3, gate=0.6e-3, margin=2 * FOOTPRINT)

    assert thinning(0.3e-3) == pytest.approx(0.3e-3, abs=0.02e-3)
    assert thinning(0.3e-3, common=0.1e-3) == pytest.approx(0.3e-3, abs=0.02e-3)
    assert abs(thinning(0.0)) < 0.02e-3
    assert notched_thinning(np.zeros(len(s)), s, cuts[:0], 50e-3, 0.6e-3, FOOTPRINT) is None

    def warnings_for(deep, looking=("cam_a",)):
        quality, warnings = assess(Trace(
            geometry=GEOMETRY, camera_names=("cam_a", "cam_b"), notches=[], coords_s=s,
            camera=np.zeros(len(s), np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT,
            wall_residual=0.0, notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0,
            depth_steps={}, notched_thinning=thinning(deep), looking_into_slots=looking))
        return quality, _by_code(warnings)

    quality, text = warnings_for(0.3e-3)
    assert quality["notched_thinning_mm"] == pytest.approx(0.3, abs=0.02)
    assert quality["cameras_looking_into_slots"] == ["cam_a"]
    (slots,) = text["SLOTS_LEAN"]
    assert slots.figures["cameras"] == ["cam_a"] and not slots.figures["levelled"]
    assert f"{slots.figures['notched_thinning_mm']:.2f}" == "0.30"
    assert f"{slots.figures['lean_mm']:.2f}" == "0.60"  # may lean up to that, away from cam_a
    # shared by cameras that see the slots edge-on (through them), a thinner wall between the notches does not
    # move the axis; and a deficit a quarter of a footprint below the floor stays quiet
    assert "SLOTS_LEAN" not in warnings_for(0.3e-3, looking=())[1]
    assert "SLOTS_LEAN" not in warnings_for(0.2 * FOOTPRINT)[1]


def test_a_centreline_over_stretches_nothing_measured_is_stated_as_uncertain_as_a_pixel_footprint_there():
    """Where no camera saw the wall facing it, nothing measured how far off the axis is: over that share of the
    length it is known no better than a pixel footprint, weighed into the stated RMS (overlapping stretches once)."""
    assert unmeasured_share((), 0.0, 50e-3) == 0.0
    assert unmeasured_share(((40e-3, 50e-3), (45e-3, 52e-3)), 0.0, 50e-3) == pytest.approx(0.2)
    assert unmeasured_share(((30e-3, 35e-3),), 8e-3, 50e-3) == pytest.approx(0.26)  # and a distal end-on stretch

    def stated(unsupported):
        quality, warnings = assess(Trace(
            geometry=dataclasses.replace(GEOMETRY, proximal_length=GEOMETRY.proximal_length - 3e-3),
            camera_names=("cam_a", "cam_b"), notches=[], coords_s=np.linspace(0.0, 50e-3, 1000),
            camera=np.zeros(1000, np.int8), tip_s=50e-3, total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0,
            notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
            cross_view_spread=0.03e-3, notched_thinning=0.04e-3, outline_offset=0.02e-3, unsupported=unsupported,
            notch_centres=GEOMETRY.notch_centers_s))
        return quality["centerline_uncertainty_mm"], _by_code(warnings)

    measured, quiet = stated(())
    assert measured == pytest.approx(0.05) and "CENTERLINE_UNSUPPORTED" not in quiet
    unmeasured, said = stated(((40e-3, 50e-3),))
    assert [w.figures["stretches_mm"] for w in said["CENTERLINE_UNSUPPORTED"]] == [[[pytest.approx(40.0),
                                                                                      pytest.approx(50.0)]]]
    assert unmeasured == pytest.approx(math.sqrt(0.05**2 + 0.2 * (FOOTPRINT * 1e3) ** 2))


def test_quality_gives_the_centreline_an_uncertainty_and_warns_above_its_floor():
    """The cameras' spread across their views and the lean along them (the wall's deficit between the notches,
    twice it for a camera looking into the slots) add in quadrature: 0.06 and 0.08 mm make 0.1 mm, over the
    0.08 mm floor, a warning; 0.03 and 0.04 mm make 0.05 mm, quiet."""
    assert centerline_uncertainty(0.06e-3, 0.08e-3) == pytest.approx(0.1e-3)
    assert centerline_uncertainty(None, 0.05e-3) == pytest.approx(0.05e-3)
    assert centerline_uncertainty(0.06e-3, 0.04e-3, ("cam_a",)) == pytest.approx(0.1e-3)
    assert centerline_uncertainty(None, None) is None
    # an axis the outline check found astray is known no better than its offset from the outlines' middles
    assert centerline_uncertainty(0.06e-3, 0.08e-3, astray=0.5e-3) == pytest.approx(0.5e-3)
    assert centerline_uncertainty(None, None, astray=0.5e-3) == pytest.approx(0.5e-3)
    # an alignment whose correction varies along the tube: that much again, in quadrature
    assert centerline_uncertainty(0.03e-3, 0.0, varying_lean=0.04e-3) == pytest.approx(0.05e-3)

    # a robot 50 mm long, seen to its tip (one ending short of its length states its tip as far off)
    seen_to_tip = dataclasses.replace(GEOMETRY, proximal_length=GEOMETRY.proximal_length - 3e-3)

    def assessed(spread, thinning, looking=(), at_end=None, held=None, cam_b_up_to=None, wall_level=None,
                 outline=0.02e-3, across_from_fit=None, fitted_end=None):  # (outline: checked, a sound axis's)
        s, seen_by = np.linspace(0.0, 50e-3, 1000), np.zeros(1000, np.int8)
        if cam_b_up_to is not None:  # cam_a sees the whole tube, cam_b up to there
            s = np.concatenate([s, np.linspace(0.0, cam_b_up_to, 750)])
            seen_by = np.concatenate([seen_by, np.ones(750, np.int8)])
        return assess(Trace(geometry=seen_to_tip, camera_names=("cam_a", "cam_b"), notches=[],
                      coords_s=s, camera=seen_by, tip_s=50e-3, wall_level=wall_level,
                      total_bend=0.0, footprint=FOOTPRINT, wall_residual=0.0, notch_side=0.0, configured_side=0.0,
                      bias_notch_side=0.1e-3, bias_binormal=0.0, depth_steps={}, notched_thinning=thinning,
                      looking_into_slots=looking, cross_view_spread=spread, distal_cross_view=at_end,
                      held_shift=held, outline_offset=outline, across_from_fit=across_from_fit,
                      fitted_end=fitted_end, notch_centres=GEOMETRY.notch_centers_s))

    quality, warnings = assessed(0.06e-3, 0.08e-3)
    print("\n" + "\n".join(map(str, warnings)))
    assert quality["centerline_uncertainty_mm"] == pytest.approx(0.1)
    assert quality["centerline_cross_view_mm"] == pytest.approx(0.06)
    (uncertain,) = _by_code(warnings)["CENTERLINE_UNCERTAIN"]
    assert uncertain.figures["uncertainty_mm"] == pytest.approx(0.1)
    assert uncertain.figures["cross_view_mm"] == pytest.approx(0.06)  # the cameras' axes that far apart
    quiet_quality, quiet = assessed(0.03e-3, 0.04e-3)
    assert quiet_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    assert "CENTERLINE_UNCERTAIN" not in _by_code(quiet)
    # the tip sits on the centreline's free end, sqrt(3) x its uncertainty across: with half a footprint along
    # the tube, 0.05 mm of centreline keep the tip within its floor, 0.1 mm do not
    assert not _by_code(quiet).keys() & TIP_CODES
    (tip,) = _tip_findings(warnings)
    assert tip.figures["across_mm"] == pytest.approx(math.sqrt(3) * 0.1)
    assert tip.figures["across_because"] == "free_end"  # the centreline's, at its free end
    assert quality["tip_across_uncertainty_mm"] == pytest.approx(math.sqrt(3) * 0.1)
    assert assessed(None, None)[0]["tip_across_uncertainty_mm"] is None  # nothing measured the centreline
    # where the cameras disagree more at the end than over the length, the tip is known no better than their axes
    # there lie apart, 2 x their RMS about the fused one: 0.05 mm over the length, 0.08 mm at the end make 0.16 mm
    ends_apart = assessed(0.03e-3, 0.04e-3, at_end=0.08e-3)
    assert ends_apart[0]["tip_across_uncertainty_mm"] == pytest.approx(0.16)
    assert ends_apart[0]["centerline_cross_view_at_tip_mm"] == pytest.approx(0.08)
    (tip,) = _tip_findings(ends_apart[1])
    assert tip.figures["across_mm"] == pytest.approx(0.16) and tip.figures["across_because"] == "cameras_apart"
    # the alignment's shift at the last wall it trusted, held unchecked to the tip, adds in quadrature to the free
    # end's: 0.05 x sqrt(3) and 0.12 mm make 0.15 mm
    held_quality, held = assessed(0.03e-3, 0.04e-3, held=(0.12e-3, 46e-3))
    assert held_quality["tip_across_uncertainty_mm"] == pytest.approx(math.hypot(math.sqrt(3) * 0.05, 0.12))
    assert held_quality["tip_held_shift_mm"] == pytest.approx(0.12)
    assert held_quality["tip_held_over_mm"] == pytest.approx(4.0)
    (tip,) = _tip_findings(held)  # the shift held unchecked over the tip_held_over_mm to the tip
    assert tip.figures["across_mm"] == pytest.approx(held_quality["tip_across_uncertainty_mm"])
    assert tip.figures["across_because"] == "held_shift"
    # the fit ended short of the tip (50 mm) and the centreline was carried on bending over the notches past its end
    # (centres 44.75 and 47.75 mm, 1.5 mm wide): each one's bend known as well as the turn over a pitch (0.05 / 3 mm),
    # its lever the rest to the tip: ended at 47.5 mm, two thirds of notch 14 at 2.25 mm add 0.025 mm in quadrature;
    # ended at 44 mm, notch 13 too (5.25 mm) makes 0.125 mm, over the free end's and said
    assert assessed(0.03e-3, 0.04e-3, fitted_end=50e-3)[0]["tip_carried_mm"] == 0.0
    near, _ = assessed(0.03e-3, 0.04e-3, fitted_end=47.5e-3)
    assert near["tip_carried_mm"] == pytest.approx(2.5)
    assert near["tip_across_uncertainty_mm"] == pytest.approx(math.hypot(math.sqrt(3) * 0.05, 0.05 / 3 * 1.5))
    short_quality, short = assessed(0.03e-3, 0.04e-3, fitted_end=44e-3)
    assert short_quality["tip_across_uncertainty_mm"] == pytest.approx(math.hypot(math.sqrt(3) * 0.05, 0.125))
    assert short_quality["tip_carried_mm"] == pytest.approx(6.0)
    assert [w.figures["across_because"] for w in _tip_findings(short)] == ["carried"]
    # looking into the slots, the deficit may lean the axis by twice it: 0.03 and 2 x 0.04 mm make 0.085 mm
    looking_quality, looking = assessed(0.03e-3, 0.04e-3, looking=("cam_a",))
    assert looking_quality["centerline_uncertainty_mm"] == pytest.approx(math.hypot(0.03, 0.08))
    assert [round(w.figures["uncertainty_mm"], 2) for w in _by_code(looking)["CENTERLINE_UNCERTAIN"]] == [0.09]
    # over a distal stretch one camera alone saw, the axis along its view rests on the wall's level, which no
    # second view checks: a quarter of the length at -0.16 mm adds 0.08 mm in quadrature (as an RMS over the
    # length), and 0.05 mm become 0.094 mm, over the floor
    assert centerline_uncertainty(0.03e-3, 0.04e-3, one_sided=(0.25, -0.16e-3)) == pytest.approx(
        math.sqrt(0.03 ** 2 + 0.04 ** 2 + 0.25 * 0.16 ** 2) * 1e-3)
    one_quality, one = assessed(0.03e-3, 0.04e-3, cam_b_up_to=37.5e-3, wall_level=-0.16e-3)
    alone = one_quality["distal_one_camera_mm"]["cam_a"] / 50.0
    assert alone == pytest.approx(0.25, abs=0.02) and one_quality["wall_level_mm"] == pytest.approx(-0.16)
    assert one_quality["centerline_uncertainty_mm"] == pytest.approx(math.sqrt(0.05 ** 2 + alone * 0.16 ** 2))
    (uncertain,) = _by_code(one)["CENTERLINE_UNCERTAIN"]
    assert round(uncertain.figures["uncertainty_mm"], 2) == 0.09
    assert uncertain.figures["one_camera_wall_level_mm"] == pytest.approx(-0.16)  # seen by one camera alone
    # both cameras seeing the whole tube, the level adds nothing
    both_quality, _ = assessed(0.03e-3, 0.04e-3, cam_b_up_to=50e-3, wall_level=-0.16e-3)
    assert both_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    # the axis 1.25 footprints from the middle of the tube's outline is within what a sound one shows: reported, no
    # more; 2.5 footprints (0.5 mm) away it went astray with the wall it rests on, and is known no better than that
    sound_quality, sound = assessed(0.03e-3, 0.04e-3, outline=0.25e-3)
    assert sound_quality["centerline_outline_offset_mm"] == pytest.approx(0.25)
    assert sound_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    assert "CENTERLINE_UNCERTAIN" not in _by_code(sound)
    astray_quality, astray = assessed(0.03e-3, 0.04e-3, outline=0.5e-3)
    print("\n".join(str(w) for w in astray if w.code == "CENTERLINE_UNCERTAIN"))
    assert astray_quality["centerline_uncertainty_mm"] == pytest.approx(0.5)
    (uncertain,) = _by_code(astray)["CENTERLINE_UNCERTAIN"]
    assert uncertain.figures["uncertainty_mm"] == pytest.approx(0.5)
    assert uncertain.figures["outline_offset_mm"] == pytest.approx(0.5)  # from the outline's middle
    assert uncertain.figures["outline_offset_mm"] / (FOOTPRINT * 1e3) == pytest.approx(2.5)  # px
    # the alignment astray (2.5 px) and the fit not (0.5 px): the fit placed the axis across the views, and the
    # result says so; the axis it gave (0.25 mm from the outline) is within what a sound one shows
    replaced_quality, replaced = assessed(0.03e-3, 0.04e-3, outline=0.25e-3, across_from_fit=(0.5e-3, 0.1e-3))
    assert replaced_quality["centerline_aligned_outline_offset_mm"] == pytest.approx(0.5)
    assert sound_quality["centerline_aligned_outline_offset_mm"] is None
    assert replaced_quality["centerline_uncertainty_mm"] == pytest.approx(0.05)
    (moved,) = _by_code(replaced)["ALIGNMENT_ASTRAY"]
    assert moved.figures["aligned_offset_mm"] == pytest.approx(0.5)
    assert moved.figures["aligned_offset_mm"] / (FOOTPRINT * 1e3) == pytest.approx(2.5)  # px, over OUTLINE_TOLERANCE_PX
    assert moved.figures["aligned_offset_mm"] / (FOOTPRINT * 1e3) > OUTLINE_TOLERANCE_PX
    assert moved.figures["fit_offset_mm"] / (FOOTPRINT * 1e3) == pytest.approx(0.5)  # the fit's axis, in px
    assert "ALIGNMENT_ASTRAY" not in _by_code(sound)


def test_a_camera_looks_into_the_slots_when_its_line_of_sight_through_them_meets_their_floor():
    """Default robot: the cut reaches d = 0.7 mm past the axis, so a line of sight within
    atan(sqrt(r^2 - d^2) / (r + d)) = 33 deg of the notch side (+x here) meets a slot's floor."""
    assert math.degrees(GEOMETRY.slot_floor_view_angle) == pytest.approx(33.2, abs=0.1)
    centerline = straight_centerline(50e-3)

    def looking(*angles_deg):
        origins = [[0.09 * math.cos(math.radians(a)), 0.09 * math.sin(math.radians(a)), 0.025] for a in angles_deg]
        return cameras_looking_into_slots(centerline, GEOMETRY, np.array(origins),
                                          tuple(f"cam{a}" for a in angles_deg))

    assert looking(-90, 90) == []            # the notches open between the cameras: seen through, edge-on
    assert looking(0, 180) == ["cam0"]       # facing cam0: it sees the floors, cam180 the backbone
    assert looking(30, 45, -30) == ["cam30", "cam-30"]


def test_depth_step_is_read_from_the_data():
    image = (np.arange(480 * 848).reshape(480, 848) % 700 + 800).astype(np.uint16)
    assert depth_step(image, 1e-4) == pytest.approx(1e-4)
    assert depth_step(image * 10, 1e-4) == pytest.approx(1e-3)
    assert depth_step(np.zeros((4, 4), np.uint16), 1e-4) == 0.0


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


def test_alignment_leaves_a_tube_seen_from_one_side_alone():
    """One camera sees one face: a shift towards it cannot be told from the wall's level, so nothing moves."""
    length = 30e-3
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, angles=(-math.pi, 0.0), rng=np.random.default_rng(5))  # the -y half
    points[:, 1] -= 0.1e-3
    centerline = straight_centerline(length)
    coords, frames = centerline.project_with_frames(points)
    viewpoints = np.tile([[0.0, -0.09, 0.015]], (len(points), 1))
    result = align_to_trusted_wall(centerline, coords, frames, viewpoints, geometry, 0.8e-3, FOOTPRINT, length)
    assert np.allclose(result.centerline.points, centerline.points, atol=1e-9)
    assert result.bias_notch_side == 0.0 and result.bias_binormal == 0.0


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


def test_projection_starts_from_the_nearest_sample_even_where_the_curve_comes_back_near_itself():
    """A hairpin (two legs 3 mm apart): points between the legs and far off are projected from their nearest
    sample, as a brute-force search over every sample finds it."""
    radius, leg = 1.5e-3, 10e-3
    turn = np.linspace(0.0, math.pi, 60)
    polyline = np.concatenate([
        np.stack([np.zeros(50), np.zeros(50), np.linspace(0.0, leg, 50)], axis=1),
        np.stack([radius - radius * np.cos(turn), np.zeros(60), leg + radius * np.sin(turn)], axis=1)[1:],
        np.stack([np.full(50, 2 * radius), np.zeros(50), np.linspace(leg, 0.0, 50)], axis=1)[1:]])
    centerline = Centerline.from_points(polyline, np.array([0.0, 1.0, 0.0]), 0.1e-3)
    rng = np.random.default_rng(7)
    points = np.concatenate([rng.uniform([-2e-3, -2e-3, -1e-3], [5e-3, 2e-3, 13e-3], (3000, 3)),
                             rng.normal(0.0, 20e-3, (200, 3))])
    squared = ((points[:, None, :] - centerline.points[None, :, :]) ** 2).sum(axis=2)
    nearest = np.argmin(squared, axis=1)
    guess = centerline.s[nearest] + ((points - centerline.points[nearest]) * centerline.tangents[nearest]).sum(axis=1)
    searched = centerline.project(points)
    brute = centerline.project(points, guess)
    on_far_leg = np.count_nonzero(centerline.s[nearest] > centerline.length / 2)
    print(f"\nhairpin: {on_far_leg} of {len(points)} points nearest the returning leg, "
          f"largest difference in s {np.abs(searched.s - brute.s).max():.1e} m")
    assert on_far_leg > 1000
    assert np.allclose(searched.s, brute.s, rtol=0.0, atol=1e-12)
    assert np.allclose(searched.x, brute.x, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("count", [1, 2, 7, 5400, 5401])
def test_median_is_numpys_median(count):
    from ntcr_recon.core.relocation.wall import median

    rng = np.random.default_rng(count)
    for values in (rng.normal(size=count), np.round(rng.normal(size=count), 1), np.sort(rng.normal(size=count)),
                   np.full(count, 0.25)):
        assert median(values) == np.median(values)
    assert math.isnan(median(np.zeros(0)))


@pytest.mark.parametrize("count", [1, 2, 7, 100, 5401])
def test_quantile_is_numpys_quantile(count):
    from ntcr_recon.core.relocation.wall import quantile

    rng = np.random.default_rng(count)
    for values in (rng.normal(size=count), np.round(rng.normal(size=count), 1), np.full(count, 0.25)):
        for q in (0.0, 0.25, 0.5, 0.75, 0.98, 1.0):
            assert quantile(values, q) == np.quantile(values, q), (count, q)
    assert math.isnan(quantile(np.zeros(0), 0.5)) and math.isnan(quantile(np.array([1.0, np.nan]), 0.5))


def test_compiled_steps_keep_the_edges_of_the_numpy_code_they_replaced():
    """The kernels check no index and unify types: their wrappers refuse or handle what numpy did."""
    from ntcr_recon.core.relocation.centerline import fixed_radius_circle_fit
    from ntcr_recon.core.relocation.wall import median, surface_band

    curve = Centerline.from_points(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.01], [1e-3, 0.0, 0.02]]),
                                   np.array([0.0, 1.0, 0.0]), 1e-3)
    assert curve.bend_angle(0.0, np.array([])).shape == (0,)
    with pytest.raises(ValueError):
        curve.bend_angle([0.0, 1e-3], [1e-3, 2e-3, 3e-3])  # lengths that do not pair
    assert np.isnan(median(np.array([1.0, np.nan, 3.0])))
    assert median(np.array([4.0, 1.0, 3.0, 2.0])) == 2.5
    with pytest.raises(ValueError, match="spine"):
        surface_band(np.zeros(50), 1e-4, np.ones(10, bool))
    with pytest.raises(ValueError, match="slab indices"):
        fixed_radius_circle_fit(np.array([0, 0, 5]), np.zeros(3), np.zeros(3), 2, 1e-3, 1e-4)
    assert not inside_intervals(np.array([0.0, 1.0]), np.empty((0, 2))).any()


def test_coverage_counts_bin_as_numpys_histogram_and_runs_are_found_around_their_centre():
    """The compiled counts put every value in the bin np.histogram does (values on an edge, beyond the last
    edge, NaN); a run of evidence is found from the cell nearest the centre, and none that touches an end."""
    from ntcr_recon.core.relocation.notches import _run_around
    from ntcr_recon.core.relocation.profile import _counts_in_bins

    rng = np.random.default_rng(3)
    cell = FOOTPRINT / 8
    edges = np.arange(0.0, 0.05 + cell, cell)
    values = np.concatenate([rng.uniform(-0.001, 0.052, 5000), edges[::7], [edges[-1], np.nan, -0.0]])
    assert np.array_equal(_counts_in_bins(values, edges), np.histogram(values[np.isfinite(values)], edges)[0])

    grid = np.arange(100) * 1.0
    evidence = np.zeros(100)
    evidence[20:30] = 1.0
    evidence[40:45] = 0.8
    evidence[19], evidence[30] = 0.25, 0.75   # the crossings of 1/2: 19 + 1/3 and 30 + 1/3
    assert _run_around(grid, evidence, 26.0, 10.0) == pytest.approx((19 + 1 / 3, 30 + 1 / 3))
    assert _run_around(grid, evidence, 41.0, 10.0) == pytest.approx((39.625, 44.375))  # the nearer run
    assert _run_around(grid, evidence, 70.0, 10.0) is None                         # nothing within reach
    evidence[:5] = 1.0
    assert _run_around(grid, evidence, 2.0, 10.0) is None                          # touches the base
