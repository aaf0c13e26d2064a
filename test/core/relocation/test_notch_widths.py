"""relocation.notch_widths: the rims calibrated to the cut faces the cameras see, and each notch's width checked
against its bend and its neighbours'. Points are drawn analytically on the true surface (no renderer), so every
figure is known exactly; each number asserted is printed."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from support.analytic_tube import FOOTPRINT, straight_centerline

from ntcr_recon.core.quality.checks import assess
from ntcr_recon.core.quality.trace import Trace
from ntcr_recon.core.relocation.notches import Notch, steady_bend
from ntcr_recon.core.robot.geometry import TubeGeometry


@pytest.mark.parametrize("reach", [0.6e-3, -0.6e-3])
def test_rim_calibration_gives_back_the_cut_faces_the_cameras_see(reach):
    """A straight robot seen by two cameras 110 mm away across its middle: every edge eroded by 0.05 mm, and each
    cut face turned towards the cameras covers the gap beside its rim by 0.6 mm x tan(view angle from its plane)
    (0.14 mm at the end notches) - or, where a matcher averages the face's depth into the rim, uncovers as much
    (reach < 0). The spines' known length gives back both: the widths come out exact, where one erosion for every
    edge leaves the end notches 0.08 mm off (their seen face's cover is read as erosion spread over both edges)."""
    from ntcr_recon.core.relocation.notch_side import face_view_tangent
    from ntcr_recon.core.relocation.notch_widths import calibrate_rims
    from ntcr_recon.core.relocation.notches import Notch

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
    from ntcr_recon.core.relocation.notch_widths import calibrate_rims
    from ntcr_recon.core.relocation.notches import Notch

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
    from ntcr_recon.core.relocation.notch_widths import MISREAD_WIDTH_FRACTION, calibrate_and_check, calibrate_rims

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
    (six,) = [n for n in kept if n.index == 6]
    assert six.read_width - width > 0.04e-3  # still read wider: measured, not overwritten ...
    # ... but weighed with its bend, which its exact chords, not scattering at all, measure better than any rim
    assert six.width == pytest.approx(width, abs=1e-9)
    quality, warnings = assess(Trace(
        geometry=geometry, camera_names=("cam_a", "cam_b"), notches=checked, coords_s=np.linspace(0.0, 50e-3, 500),
        camera=None, tip_s=50e-3, total_bend=bend * geometry.notch_count, footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={},
        misread_widths=misread))
    # the misread one is given its bend's width, as a dip is: stated as uncertain as the widths' spread about their
    # bends', not as far off as its rims were misread
    bounds = quality["notch_width_uncertainty_mm"]
    assert abs(misread[6] - width) > 2 * MISREAD_WIDTH_FRACTION * geometry.notch_width
    assert bounds["6"] == pytest.approx(min(mm for i, mm in bounds.items() if i != "6"), rel=1e-6)
    assert bounds["6"] < MISREAD_WIDTH_FRACTION * geometry.notch_width * 1e3 / 2
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
    from ntcr_recon.core.relocation.notch_widths import calibrate_and_check

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
    steady bend given back (notch_widths.bump_at) its bend is 12 deg, and the width read is kept, also where the
    bump's own excess raises the scatter of all the chords (it is measured without the bump's span). The same width
    read where the chords show no bump is misread, and so is one where the chords scatter as much as the bump
    (noise, not a kink). A chord that wobbles turns two neighbours opposite ways: no bump."""
    from ntcr_recon.core.relocation.notch_widths import bump_at, calibrate_and_check, chord_scatter

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
    print(f"\nnotch 7 read {kept.read_width * 1e3:.3f} mm, given {kept.width * 1e3:.3f} (true {true_width * 1e3:.3f}; "
          f"its chord's bend implies {by_chord * 1e3:.3f}; its gathered bend {gathered:.1f} deg)")
    assert misread == {} and kept.signal != "bend" and kept.read_width == pytest.approx(true_width, abs=1e-6)
    # weighed with the width the bend gathered back (0.3 deg short of the kink's) implies
    implied = geometry.notch_width_at_bend(bump_at(dict(enumerate(chords)), 7).bend)
    assert min(true_width, implied) - 1e-9 <= kept.width <= max(true_width, implied) + 1e-9
    assert abs(kept.width - true_width) < 0.02e-3
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
    kept = next(n for n in checked if n.index == 7)
    assert 7 not in misread and kept.read_width == pytest.approx(true_width, abs=1e-6)
    # weighed with the width the bend gathered back from these chords implies (12.9 deg: 0.84 mm)
    implied = geometry.notch_width_at_bend(bump_at(dict(enumerate(as_read)), 7).bend)
    assert min(true_width, implied) - 1e-9 <= kept.width <= max(true_width, implied) + 1e-9
    assert abs(kept.width - true_width) < 0.04e-3
    # ... and as read once the limbs read shaded edges: the kink's spread split unevenly, its neighbours holding 0.29
    # and 0.52 of its excess (together enough; each alone need not be)
    split = np.radians([1.8, 2.1, 1.5, 1.9, 3.1, 1.5, 3.7, 7.8, 5.0, 1.7, 2.1, 1.6, 2.3, 1.5, 2.5, 1.5])
    assert np.degrees(bump_at(dict(enumerate(split)), 7).bend) == pytest.approx(11.7, abs=0.1)
    wobble = {i: np.radians(2.0) for i in range(16)} | {7: np.radians(3.0), 8: np.radians(1.0)}
    assert bump_at(wobble, 7) is None and bump_at(wobble, 8) is None
    # one neighbour beside the peak, the other the other way: no kink's spread, however much the one holds
    lopsided = {i: np.radians(2.0) for i in range(16)} | {6: np.radians(5.0), 7: np.radians(6.0), 8: np.radians(1.8)}
    assert bump_at(lopsided, 7) is None
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
    from ntcr_recon.core.relocation.notch_widths import bump_at, calibrate_and_check
    from ntcr_recon.core.relocation.notches import bend_implied

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
    # a notch two from the kink whose edges were not measured (a dip: its width its bend's, the mean of the chords
    # two notches either side, the kink's spread ones among them) takes the width of the steady bend given back
    steady = steady_bend(dict(enumerate(chords.tolist())), 9, geometry.max_notch_bend)
    dip = bend_implied(dataclasses.replace(notches[9], bend=steady), geometry, "dip")
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
    from ntcr_recon.core.relocation.notch_widths import calibrate_and_check

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


def test_the_weighing_of_a_width_follows_which_measurement_errs_less():
    # rims that disagree with exact chords weigh nothing; chords that scatter weigh the rims in
    from ntcr_recon.core.relocation.notch_widths import weighing

    geometry = TubeGeometry()
    ybar, r_o = geometry.neutral_axis_offset, geometry.outer_radius
    assert weighing([0.03e-3, -0.03e-3, 0.03e-3], 0.0, geometry) == (0.0, pytest.approx(0.0))
    bend_sd = math.radians(0.5)
    noisy = weighing([0.03e-3, -0.03e-3, 0.03e-3], bend_sd, geometry)
    assert noisy.read == pytest.approx(ybar * (ybar + r_o) * bend_sd**2 / 0.03e-3**2)
    # the weighed width errs less than either measurement would (read: arc and bend; implied: the bend's alone)
    arc_sd = math.sqrt(0.03e-3**2 - ybar**2 * bend_sd**2)
    assert noisy.error_sd < min(math.hypot(arc_sd, r_o * bend_sd), (ybar + r_o) * bend_sd)
    assert weighing([0.03e-3, -0.03e-3], bend_sd, geometry) == (0.5, None)  # too few checked
    assert weighing([0.03e-3] * 4, math.inf, geometry) == (0.5, None)       # too few chords


def test_a_kink_the_rims_agree_with_is_stated_as_known_as_its_neighbours():
    """A robot bent 2 deg at each notch but 12 at notch 7, its rims and chords read exactly: notch 7's chord stands
    10 deg out of its neighbours', but its rims agree with it, so it is the robot's own bend, not the chord's error,
    and its width is stated as known as any other (the chord's residual alone would put it 0.5 mm off)."""
    from ntcr_recon.core.relocation.notch_widths import calibrate_and_check

    geometry = TubeGeometry()
    bends = np.radians(np.where(np.arange(geometry.notch_count) == 7, 12.0, 2.0))
    notches, start = [], geometry.notch_centers_s[0] - geometry.notch_arc_at_bend(bends[0]) / 2
    rng = np.random.default_rng(5)
    for i, bend in enumerate(bends):  # rims off by up to 0.02 mm, chords by 0.3 deg: both scatter a little
        end = start + geometry.notch_arc_at_bend(bend)
        notches.append(read_notch(geometry, i, start + rng.normal(0, 0.01e-3), end + rng.normal(0, 0.01e-3),
                                  bend + np.radians(rng.normal(0, 0.3))))
        start = end + geometry.notch_pitch - geometry.notch_width
    checked, misread, _ = calibrate_and_check(notches, geometry)
    assert misread == {} and all(n.read_width is not None for n in checked)
    quality, _ = assess(Trace(
        geometry=geometry, camera_names=("cam_a", "cam_b"), notches=checked, coords_s=np.linspace(0.0, 50e-3, 500),
        camera=None, tip_s=50e-3, total_bend=float(bends.sum()), footprint=FOOTPRINT, wall_residual=0.0,
        notch_side=0.0, configured_side=0.0, bias_notch_side=0.0, bias_binormal=0.0, depth_steps={}))
    bounds = quality["notch_width_uncertainty_mm"]
    assert bounds["7"] < 0.05 and bounds["7"] <= 1.5 * float(np.median(list(bounds.values())))
    width_errors = [abs(n.width - geometry.notch_width_at_bend(bends[n.index])) * 1e3 for n in checked]
    assert max(width_errors) < max(bounds.values())
