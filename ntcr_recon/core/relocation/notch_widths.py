"""Notch widths checked against their bends: a kink the centreline spread over its neighbours (bump_at), the
chords' scatter, the rims calibrated where a stereo matcher eroded them, a width off what its bend implies
flagged as misread (calibrate_and_check), and one within weighed with its bend's (weighing, weighed_width)."""

from __future__ import annotations

import math
import statistics
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ntcr_recon.core.base.robust import median, robust_spread
from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.notch_side import face_view_tangent
from ntcr_recon.core.relocation.notches import Notch, bend_implied, steady_bend
from ntcr_recon.core.robot.geometry import TubeGeometry

# A notch whose width is off what its bend implies by more than this share of its cut width was misread (see
# calibrate_and_check): manufacturing keeps a cut to a few hundredths of a millimetre, a tenth of 1.0-1.8 mm.
MISREAD_WIDTH_FRACTION = 0.1

# Fewer notches than this checked against their bends leave their disagreement's scatter unknown (weighing,
# quality.findings.notch_width_uncertainties).
MIN_CHECKED_NOTCHES = 3

# The least share of a kink's excess chord its neighbours hold, on average (bump_at).
SPREAD_SHARE = 0.35



class Bump(NamedTuple):
    """A notch whose chord stands out of the bends beside it the way a kink's does (bump_at)."""
    bend: float    # rad: the bend with what the centreline spread over the notches beside it given back
    steady: float  # rad: the steady bend about it (_steady_chords' median), the bend of the notches beside it


def bump_at(bends: dict[int, float | None], index: int, scatter: float | None = None) -> Bump | None:
    """Whether the chord bends (rad, by index) show a kink at notch `index`, and its bend.

    The centreline spreads a notch bent much sharper than its neighbours (a kink: 12 deg among 2) over up to five, a
    bump: its own chord reads about half its bend, its neighbours' the rest. It moves the turn along the tube, it
    does not lose it: the kink's bend is the steady bend about it (the median of _steady_chords) plus the excess
    over it of the chords up to two notches either side. A bump has its own chord's excess the largest, beyond three
    times the chords' `scatter`, its two neighbours' the same way and on average at least SPREAD_SHARE of it, the span's
    excess beyond three sigma of a sum of that many chords (noisy chords give any notch some excess either way), and
    the chords three and four away within six of it and half its own excess of each other (a real bump three notches
    on is no steady bend, and a curve that waves along the tube has none: five chords' excess over it sums what it
    is off). A chord that wobbles where the curve's support changes is alone off its neighbours: no bump (the first
    notches of a robot bent 18 deg at each read 15.1, 18.7, 20.9, 17.7 deg; three of one bent 4.8 at each, 4.2, 0.3,
    4.4). The scatter (None: chord_scatter of the chords outside the span) leaves the bump out: it is no noise, and
    once it raised the scatter of all sixteen chords to 0.93 deg a kink was taken for a misread. None where there is
    no bump, or a neighbour's chord or the steady bend is not known."""
    own, neighbours = bends.get(index), [bends.get(i) for i in (index - 1, index + 1)]
    around = _steady_chords(bends, index)
    if own is None or None in neighbours or around is None:
        return None
    steady = float(statistics.median(around))  # plain Python: as chord_scatter's
    peak, beside = own - steady, [bend - steady for bend in neighbours]
    excess = [bend - steady for i in range(index - 2, index + 3) if (bend := bends.get(i)) is not None]
    # the smoothing spreads a kink over both neighbours: together they hold a good part of its excess (0.45-0.75 of
    # the kink's own each on bend_kink, 0.29 and 0.52 where the limbs moved the chords about it); a chord alone off
    # its neighbours (0.2 of it each) is the curve's wobble, no kink. Their mean, not each: chord noise splits it
    if (peak == 0.0 or not all(e / peak > 0.0 for e in beside) or sum(beside) / peak < 2.0 * SPREAD_SHARE
            or any(abs(e) > abs(peak) for e in excess)):
        return None
    if scatter is None:  # measured only where there is a bump to judge (a dozen medians)
        scatter = chord_scatter({i: bend for i, bend in bends.items() if abs(i - index) > 2})
    total = math.fsum(excess)
    if not (abs(peak) > 3.0 * scatter and abs(total) > 3.0 * scatter * math.sqrt(len(excess))
            and max(around) - min(around) <= min(6.0 * scatter, abs(peak) / 2.0)):
        return None
    return Bump(float(steady + total), steady)


def _steady_chords(bends: dict[int, float | None], index: int) -> list[float] | None:
    """The chord bends (rad, by index) of the notches three and four away from notch `index`, beyond the reach of a
    bump the centreline spread from it; None without one on either side (chords falling towards the tube's end
    are no bump)."""
    before = [bend for i in (index - 4, index - 3) if (bend := bends.get(i)) is not None]
    after = [bend for i in (index + 3, index + 4) if (bend := bends.get(i)) is not None]
    return before + after if before and after else None


def chord_scatter(bends: dict[int, float | None]) -> float:
    """How much the chord bends (rad, by index) scatter notch to notch: sigma from the median absolute deviation of
    their chord_residuals (a steady or steadily changing bend leaves none); inf with fewer than five chords."""
    residuals = chord_residuals(bends)
    return robust_spread(np.fromiter(residuals.values(), float), 0.0) if len(residuals) >= 5 else np.inf


def chord_residuals(bends: dict[int, float | None]) -> dict[int, float]:
    """Each chord bend (rad, by index) less the median of the two on either side of it."""
    indices = sorted(i for i, bend in bends.items() if bend is not None)
    values = [bends[i] for i in indices]
    # statistics.median of the two to four neighbours: a tenth of numpy's per-call cost on lists this short
    return {i: values[k] - statistics.median(values[max(k - 2, 0):k] + values[k + 1:k + 3] or [values[k]])
            for k, i in enumerate(indices)}


def calibrate_rims(notches: list[Notch], geometry: TubeGeometry, centerline: Centerline | None = None,
                   camera_origins: np.ndarray | None = None) -> list[Notch]:
    """Correct the notch edges for what the stereo matcher does to rims at depth edges.

    A matcher erodes (or, where it averages across a shallow gap, extends) the rim on both sides of every
    notch by about the same amount e. A cut face turned towards a camera is seen beside its rim, inside the
    wall's radius, and the matcher's window averages its first rows with the wall ahead: the rim moves over
    the face by k tan(view angle from the face's plane) (`face_view_tangent`), k the depth of face the window
    reaches (up to the tube's diameter; the tangent no more than width / diameter, where a face as deep as the
    tube hides the whole gap); a face turned away is not seen. A matcher that averages the face's depth into
    the rim's pixels instead pulls the rim down the face, away from its camera: k is then negative (a window
    mean over 7 px does so, test/support/synthetic_views.py; the package's simulator moves rims over the faces). The
    spines between notches are rigid, of the robot's nominal length pitch - width whatever the bend, so each
    spine between consecutive detected notches reads nominal - 2 e + k (v_end + v_start) (v: its two faces' view
    tangents); e and k are solved by least squares over the spines (e alone, the median over the spines, when
    their faces are all seen alike or no camera is known), and every edge moves back by e - k v (with fewer than
    three such spines, nothing moves). What each spine still reads off its length is then shared by its two rims
    (share_spines). (A robot whose spines are all shorter than its drawing says would have that read as erosion.)
    """
    spine = geometry.notch_pitch - geometry.notch_width
    pairs = _spine_pairs(notches)  # a dip's or a misread notch's edges are its bend's: nothing to correct
    if len(pairs) < 3:
        return share_spines(notches, spine)
    shortfall = np.array([spine - (after.start_s - before.end_s) for before, after in pairs])
    start_seen, end_seen = np.zeros(len(notches)), np.zeros(len(notches))
    if centerline is not None and camera_origins is not None and len(camera_origins):
        # a face as deep as the tube hides the whole gap once tan > width / diameter: no more can be hidden
        most = geometry.notch_width / geometry.outer_diameter
        # start faces look up the tube, end faces down it: both in one pass over the centreline's frames
        faces = np.array([n.start_s for n in notches] + [n.end_s for n in notches])
        facing = np.repeat([1.0, -1.0], len(notches))
        start_seen, end_seen = np.split(np.minimum(face_view_tangent(centerline, faces, camera_origins, facing),
                                                   most), 2)
    row = {n.index: i for i, n in enumerate(notches)}
    seen = np.array([end_seen[row[before.index]] + start_seen[row[after.index]] for before, after in pairs])
    reach = 0.0
    # least squares of shortfall = 2 e - k seen, by its 2x2 normal equations (numpy's lstsq and matrix_rank cost
    # 0.1 ms a frame here); both unknowns only where the spines' faces are seen differently (else k cannot be
    # told from e): the design's smaller singular value above 1e-3 of its first column's norm
    count, seen_sum, seen_square = len(pairs), float(seen.sum()), float(seen @ seen)
    a, b, c = 4.0 * count, -2.0 * seen_sum, seen_square
    smallest = (a + c) / 2 - np.hypot((a - c) / 2, b)  # the normal matrix's smaller eigenvalue
    if smallest > (1e-3 * 2.0 * np.sqrt(count)) ** 2:
        right_e, right_k = 2.0 * float(shortfall.sum()), -float(seen @ shortfall)
        solved_k = (a * right_k - b * right_e) / (a * c - b * b)
        reach = float(min(max(solved_k, -geometry.outer_diameter), geometry.outer_diameter))
    erosion = float(median(shortfall + reach * seen)) / 2.0  # e with k held, robust as the median
    # every edge back by e - k v: the start along s, the end against it (plain floats)
    start_moves = {n.index: erosion - reach * v for n, v in zip(notches, start_seen.tolist(), strict=True)}
    end_moves = {n.index: reach * v - erosion for n, v in zip(notches, end_seen.tolist(), strict=True)}
    return share_spines(_with_edges_moved(notches, start_moves, end_moves), spine)


class CheckedNotches(NamedTuple):
    """calibrate_and_check's result."""
    notches: list[Notch]
    misread: dict[int, float]  # the width each notch found misread was read at (by index), now its bend's
    unchecked: list[int]       # the measured notches whose bends no two whole spines measured: widths as read


def calibrate_and_check(notches: list[Notch], geometry: TubeGeometry, centerline: Centerline | None = None,
                        camera_origins: np.ndarray | None = None, tip_s: float = np.inf) -> CheckedNotches:
    """calibrate_rims, with the notches its widths show misread left out of it: the notches, the width each
    misread one was read at (by index), and the notches that could not be checked.

    A notch's width follows from its cut width and its bend (geometry.notch_width_at_bend), the bend measured by
    the spines on either side, apart from its rims; a laser-cut notch keeps its drawing's width to a few
    hundredths of a millimetre. One whose bend two whole spines measured (the next notch found, or the tube seen
    to tip_s a pitch past where it should be: a spine running to a tube cut short is no chord of it) and
    whose calibrated width is off what its bend implies by more than MISREAD_WIDTH_FRACTION of the cut width was
    misread (a rim lost where only a narrow run of the slot was seen through, a rim merged with a face): it is
    given the arc and width its steady bend (notches.steady_bend) implies, about its centre
    (signal "bend"), and the rims are calibrated again without it, so that no spine it bounds shares its error
    with a neighbour; so on, the farthest off first, until no measured notch is off its bend that far. One whose
    bend was not so measured (the last found: its distal rim, where the tube seen thins out, is the rim most often
    read far off, 0.25-0.4 mm in the sweeps) is checked against, and if misread given, the median of the bends of
    the one or two notches before it whose bends were; those with neither are listed unchecked.

    Where the chords show a kink (bump_at), the smoothed centreline spread its bend over the notches up to two away:
    the kink is checked against (and if misread given) the bend gathered back, those notches against the steady
    bend about it, not by their chords, the spread ones (taking whichever of its own chord's bend and the gathered
    one explained its width let bend_kink's notch 7, read 0.22 mm wide by a matcher with a 5 px window and no
    left-right check, stand); and those are the bends they report. Each width checked and not misread is then
    weighed with the one its bend implies by their errors (weighing, weighed_width)."""
    misread: dict[int, float] = {}
    limit = MISREAD_WIDTH_FRACTION * geometry.notch_width
    checked = _bends_measured(notches, geometry, tip_s)
    # a notch whose own bend no whole spine beyond measured (the last one found, its distal rim where the tube seen
    # thins out: the rim most often read far off) is checked against the bend of the measured notches before it
    measured_bends = {n.index: n.bend for n in notches if n.index in checked and n.bend is not None}
    # the bend a kink's bump gathers back, where the chords show one (fixed by the chords read: once); beside it,
    # whose chords the centreline gave part of the kink's bend, the notches bend as the steady bend does
    chord_bends = {n.index: n.bend for n in notches if n.edges_measured and n.index in checked}
    bumps = {i: bump for i in chord_bends if (bump := bump_at(chord_bends, i)) is not None}
    given_back = {i + k: bump.steady for i, bump in bumps.items() for k in (-2, -1, 1, 2)}
    given_back |= {i: bump.bend for i, bump in bumps.items()}
    before = {n.index: float(statistics.median(earlier)) for n in notches if n.index not in checked
              and (earlier := [measured_bends[i] for i in (n.index - 2, n.index - 1) if i in measured_bends])}
    while True:  # one at a time, the farthest off first: a misread rim shared over a spine puts its neighbour off too
        calibrated = calibrate_rims(notches, geometry, centerline, camera_origins)
        off = {n.index: abs(n.width - geometry.notch_width_at_bend(before.get(n.index, n.bend) or 0.0))
               for n in calibrated if n.edges_measured and (n.index in checked or n.index in before)}
        for n in calibrated:  # about a kink a width is judged by the bend given back: the chords are the spread ones
            if n.index in off and n.index in given_back:
                off[n.index] = abs(n.width - geometry.notch_width_at_bend(given_back[n.index]))
        worst = max(off, key=off.get, default=None)
        if worst is None or off[worst] <= limit:
            # about a kink the bends given back are the notches' (the span's turn is its chords'); one whose edges
            # were not measured takes the width its bend now implies
            calibrated = [n if (bend := given_back.get(n.index)) is None
                          else replace(n, bend=bend) if n.edges_measured
                          else bend_implied(replace(n, bend=bend), geometry, n.signal) for n in calibrated]
            # a width checked against its bend is known twice over: the two measurements weighed by their errors
            read_weight = weighing_of(calibrated, geometry).read
            calibrated = [weighed_width(n, geometry, before.get(n.index, n.bend), read_weight)
                          if n.edges_measured and (n.index in checked or n.index in before) else n for n in calibrated]
            return CheckedNotches(calibrated, misread, sorted(n.index for n in calibrated if n.edges_measured
                                                              and n.index not in checked and n.index not in before))
        read = next(n for n in calibrated if n.index == worst)
        misread[worst] = read.width
        steady = (before[worst] if worst in before else given_back[worst] if worst in given_back
                  else steady_bend({n.index: n.bend for n in notches}, worst, geometry.max_notch_bend))
        notches = [bend_implied(replace(read, bend=steady), geometry, "bend") if n.index == worst else n
                   for n in notches]


class Weighing(NamedTuple):
    """How a width read and the one its bend implies are weighed (weighing)."""
    read: float              # the weight of the width read; the implied one's is 1 - read
    error_sd: float | None   # m, the SD of the weighed width's error; None: not known


def weighing(disagreements: list[float], bend_sd: float, geometry: TubeGeometry) -> Weighing:
    """The weights of a notch's two measurements of its width that err least, from the widths' disagreements with
    their bends' (m, read - implied) and the chords' scatter (`bend_sd`, rad: chord_scatter).

    A width read is the arc between its rims less its bend's share, so it errs by e_arc - r_o e_bend; the one its
    bend implies (geometry.notch_width_at_bend) by -(ybar + r_o) e_bend: they disagree by e_arc + ybar e_bend, so
    e_arc's variance is the disagreements' less ybar^2 that of the bend. Of w e_read + (1 - w) e_implied the
    variance, w^2 var(e_arc) + (ybar + r_o - w ybar)^2 var(e_bend), is least at w = ybar (ybar + r_o) var(e_bend) /
    var(disagreement) (within 0..1): little where the rims read far worse than the chords (a matcher's smeared
    depth edges), much where the chords scatter (a centreline off). With fewer than MIN_CHECKED_NOTCHES
    disagreements or too few chords to scatter, the two alike, the error not known."""
    if len(disagreements) < MIN_CHECKED_NOTCHES or not math.isfinite(bend_sd):
        return Weighing(0.5, None)
    ybar, r_o = geometry.neutral_axis_offset, geometry.outer_radius
    var_d, var_bend = float(np.mean(np.square(disagreements))), bend_sd**2
    read = float(np.clip(ybar * (ybar + r_o) * var_bend / var_d, 0.0, 1.0)) if var_d > 0 else 0.5
    var_arc = max(var_d - ybar**2 * var_bend, 0.0)
    return Weighing(read, math.sqrt(read**2 * var_arc + (ybar + r_o - read * ybar) ** 2 * var_bend))


def weighing_of(notches: list[Notch], geometry: TubeGeometry) -> Weighing:
    """weighing over the notches whose edges were measured: their widths as read (read_width, once weighed) against
    their bends', and their chords' scatter - as calibrate_and_check weighs them and the quality states them."""
    measured = [n for n in notches if n.edges_measured]
    return weighing([width_as_read(n) - geometry.notch_width_at_bend(n.bend or 0.0) for n in measured],
                    chord_scatter({n.index: n.bend for n in measured}), geometry)


def width_as_read(notch: Notch) -> float:
    """The width the notch's edges read: its read_width where weighed_width weighed it with its bend's."""
    return notch.width if notch.read_width is None else notch.read_width


def weighed_width(notch: Notch, geometry: TubeGeometry, bend: float | None, read: float = 0.5) -> Notch:
    """The notch with its width `read` times the one its edges read and the rest the one its `bend` implies
    (geometry.notch_width_at_bend; weighing), its edges about its centre; the width its edges read kept as
    read_width. Its edges and its bend measure a notch's width independently: the rims where the matcher smeared a
    depth edge, the bend by the chords of the rigid spines either side, each a line through many points, through
    the robot's kinematics (a laser-cut notch keeps its drawing's width to a few hundredths of a millimetre). Off
    the drawing, a robot's notches read only the read share as far off it as they are, and the check
    (calibrate_and_check) flags none of them that is off by less than its limit; a misread one takes its bend's."""
    if bend is None:
        return notch
    width = read * notch.width + (1.0 - read) * geometry.notch_width_at_bend(bend)
    arc = width + abs(notch.bend or 0.0) * geometry.outer_radius  # as notches._measure reads a width off its arc
    return replace(notch, start_s=notch.center_s - arc / 2, end_s=notch.center_s + arc / 2, width=width,
                   read_width=notch.width)


def _bends_measured(notches: list[Notch], geometry: TubeGeometry, tip_s: float) -> set[int]:
    """The indices of the notches whose bend two whole spines measured: the next notch was found, or it is the
    robot's last, or the tube is seen to tip_s a whole pitch past the spine after it (a spine running into a tube
    cut short is no chord of it). Only their widths can be checked against their bends."""
    found = {n.index for n in notches}
    return {n.index for n in notches if n.index + 1 in found or n.index == geometry.notch_count - 1
            or n.end_s + 2 * geometry.notch_pitch - geometry.notch_width <= tip_s}


def share_spines(notches: list[Notch], spine: float) -> list[Notch]:
    """Each spine between two notches whose edges were measured set to its known length `spine`, its two rims
    moving by half of what it reads off it, opposite ways.

    A spine is rigid (the uncut tube), so its two rims, measured apart, are one unknown seen twice: each rim's
    error that is not the other's (pixel phase, a rim the matcher mixed alone) is halved, and one rim read a
    whole notch off shows as half of that on each of the two notches it bounds, not all of it on one. The first
    notch's start and the last one's end have no partner and stay as measured; a notch whose edges were not
    measured (a dip, a misread one) bounds no spine here. Width and centre follow their edges."""
    start_moves, end_moves = {}, {}
    for before, after in _spine_pairs(notches):
        off = (after.start_s - before.end_s) - spine
        end_moves[before.index], start_moves[after.index] = off / 2, -off / 2
    return _with_edges_moved(notches, start_moves, end_moves)


def _spine_pairs(notches: list[Notch]) -> list[tuple[Notch, Notch]]:
    """The consecutive notches (by index) whose edges were both measured: the two ends of each spine read."""
    by_index = {n.index: n for n in notches if n.edges_measured}
    return [(by_index[i], by_index[i + 1]) for i in sorted(by_index) if i + 1 in by_index]


def _with_edges_moved(notches: list[Notch], start_moves: dict[int, float], end_moves: dict[int, float]
                      ) -> list[Notch]:
    """The notches with each measured one's start moved by start_moves[index] and its end by end_moves[index]
    (m, + along s; none given: not moved), width and centre following; one whose edges were not measured as it
    was."""
    moved = []
    for n in notches:
        if not n.edges_measured:
            moved.append(n)
            continue
        start_move, end_move = start_moves.get(n.index, 0.0), end_moves.get(n.index, 0.0)
        start, end = n.start_s + start_move, n.end_s + end_move
        moved.append(Notch(n.index, (start + end) / 2, start, end, max(n.width - start_move + end_move, 0.0),
                           n.bend, n.signal))
    return moved
