"""relocation.notches: notches found where the comb puts them, by the signal that shows each (a gap seen through, a
dip seen obliquely), and their rims measured. Points are drawn analytically on the true surface (no renderer), so
every figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.analytic_tube import FOOTPRINT, GEOMETRY, R_O, displaced_centerline, straight_centerline, wall_points

from ntcr_recon.core.relocation.notches import detect_notches
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape


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


def test_a_notch_no_depth_marks_is_found_where_the_outline_shows_it():
    """The slot filled to 85 % (no dip: depth marks nothing): the outline in a colour image is asked about the
    notches depth did not find and shows notch 5 (relocation.outline_notches); found where the comb puts it
    ("outline"), its width the one its bend implies. Without the outline's word it stays missing."""
    geometry, centerline, coords, start, end = _tube_with_one_notch(False, filled=0.85)
    asked = []

    def outline(centres, unfound):
        asked.extend(unfound)
        return {5: 0.15e-3} if 5 in unfound else {}

    [notch] = detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3,
                             outline=outline)
    assert 5 in asked
    assert (notch.index, notch.signal, notch.edges_measured) == (5, "outline", False)
    assert abs(notch.center_s - (start + end) / 2) < FOOTPRINT / 2
    assert notch.width == pytest.approx(geometry.notch_width_at_bend(notch.bend))
    assert detect_notches(coords, centerline, geometry, 0.8e-3, FOOTPRINT, 0.5, 0.25, geometry.length - 0.1e-3,
                          outline=lambda centres, unfound: {}) == []


def test_a_dips_width_is_its_bend_taken_with_its_neighbours_not_one_chords_wobble():
    """A robot bent 3.75 deg at each notch whose centreline wobbles 0.1 mm across the spine between notches 9 and
    10 (where its support changes from two cameras to one): that spine's chord turns 3.8 deg, notch 9 reads 7.6
    deg and notch 10 0 deg. Notch 9 is a dip (the matcher filled its slot: no edges), so its width is the one its
    bend implies: with its own chord's bend 0.2 mm narrow, with the mean of the chords two notches either side true."""
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


def test_a_steady_bend_keeps_the_turn_of_wobbling_chords_and_leaves_out_a_chord_no_notch_can_bend():
    """Chords of a robot bent 4.8 deg at each notch, on a centreline whose spines' directions wobble by 3 deg (each
    wobble turns the two notches its spine joins opposite ways; the real matcher's rows read such chords 1-14 deg):
    the steady bend's RMS error is a fifth of the chords' (the span's two end wobbles over five notches), under a
    third of it at every seed, where the chords themselves are up to 8 deg off. Two gaps read
    overlapping leave a spine no longer than nothing between them, its direction reversed: the chords either side read
    -180 and +180 deg, beyond what a notch bends, and are left out."""
    from ntcr_recon.core.relocation.notches import steady_bend

    bend, max_bend = math.radians(4.8), GEOMETRY.max_notch_bend
    for seed in range(5):
        spine_turns = np.radians(np.random.default_rng(seed).normal(0.0, 3.0, 17))
        chords = {i: bend + spine_turns[i + 1] - spine_turns[i] for i in range(16)}
        steady = np.array([steady_bend(chords, i, max_bend) for i in range(16)])
        chord_errors = np.array(list(chords.values())) - bend
        assert np.max(np.abs(chord_errors)) > math.radians(6.0)
        assert np.sqrt(np.mean((steady[2:-2] - bend) ** 2)) < np.sqrt(np.mean(chord_errors ** 2)) / 3
    reversed_spine = chords | {10: chords[10] - math.pi, 11: chords[11] + math.pi}
    assert steady_bend(reversed_spine, 8, max_bend) == pytest.approx(np.mean([chords[i] for i in (6, 7, 8, 9)]))
    assert steady_bend(reversed_spine, 12, max_bend) == pytest.approx(np.mean([chords[i] for i in (12, 13, 14)]))


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
