"""Notches: gaps of outer-surface coverage on the notched side, measured in the tube's own coordinates.

In tube coordinates (arc length s of a point's cross-section, angle about the axis from the notch side) a
notch is the interval [s_start, s_end] of its cut at every angle where the cut opens the outer surface
(|angle| < gap_half_angle): its faces are the normal planes of the centreline at its ends. The coverage
profile along s of the outer-surface points in that angular window, smoothed by a kernel of about half a
pixel footprint, falls to half its local plateau exactly at an edge (each depth pixel stands for a cell of
one footprint), which gives the edges to a fraction of a pixel. A notch seen obliquely is no see-through
slot (its floor and faces fill it with foreground depth), but those points lie inside the wall's radius:
the depression of the wall is the second signal. The robot's known comb, matched to both, says where each
notch is (see detect_notches).

Width (the documented definition): the gap on the outer surface line facing the notches, s_n (1 - kappa r_o)
= s_n - theta r_o, with theta the bend of the centreline across the notch.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.ndimage import percentile_filter

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.relocation.profile import coverage_profile
from ntcr_recon.core.relocation.wall import median, robust_spread, surface_band
from ntcr_recon.core.robot.comb import expected_centres, inside_intervals, near_cuts
from ntcr_recon.core.robot.geometry import TubeGeometry

# a notch window whose density plateau is under this share of the tube's (its 90th percentile) is seen by no
# camera
UNSEEN_PLATEAU_FRACTION = 0.1

# A notch neither signal measures is still found where the comb puts it when the wall's coverage dips there: its
# coverage gap peaks at DIP_PEAK or more within a quarter of a notch width of the comb's centre, DIP_PROMINENCE
# above its median over the spines either side (up to half a pitch away), the whole pitch seen by a camera. A slot
# narrower than the stereo matcher's window (4 px at 105 mm for a 1 mm notch, against 7 px) leaves that and no
# more: the window fills it with the spines' depth.
DIP_PEAK = 0.3
DIP_PROMINENCE = 0.25

# A notch whose width is off what its bend implies by more than this share of its cut width was misread (see
# calibrate_and_check): manufacturing keeps a cut to a few hundredths of a millimetre, a tenth of 1.0-1.8 mm.
MISREAD_WIDTH_FRACTION = 0.1

# The wall's local density plateau is the upper quartile of its coverage over a pitch (a gap fills at most half of
# it). A matcher whose window mixes a backdrop behind the slots into the rims' pixels erodes each spine from both
# sides, down to a tenth of a pitch, and pulls what is left off the wall's level: the upper quartile then lies in
# the gaps and calls the window unseen. There the spines' top (this percentile of the coverage of all the window's
# points over a pitch, on either side) is the plateau, if it is a wall's: at least ERODED_SPINE_TOP of the density of
# the wall seen whole (a stray point's bump, where no camera sees the window, is a few hundredths of that).
SPINE_TOP_PERCENTILE = 95
ERODED_SPINE_TOP = 0.25


@dataclass(frozen=True)
class Notch:
    index: int            # position in the robot's notch order (0 = nearest the base)
    center_s: float       # m, centreline arc length of the notch centre
    start_s: float
    end_s: float
    width: float          # m, outer-surface gap facing the notches
    bend: float | None    # rad, the centreline's turn across the notch
    signal: str = "coverage"  # what measured it: "coverage" (a slot seen through), "depression" (seen
                              # obliquely: its floor and faces inside the wall's radius), "dip" (a slot the
                              # matcher filled: only its place is measured, its width is its bend's) or "bend"
                              # (found, but its edges read a width its bend rules out: its width is its bend's)

    @property
    def edges_measured(self) -> bool:
        """Whether its edges are the data's: a dip's or a misread one's ("bend") are those its bend implies."""
        return self.signal not in ("dip", "bend")


def bend_implied(notch: Notch, geometry: TubeGeometry, signal: str) -> Notch:
    """The notch given the arc and width its bend implies (geometry.notch_arc_at_bend, notch_width_at_bend)
    about its centre: what is known of a notch whose edges were not measured, or misread."""
    bend = notch.bend or 0.0
    arc = geometry.notch_arc_at_bend(bend)
    return Notch(notch.index, notch.center_s, notch.center_s - arc / 2, notch.center_s + arc / 2,
                 geometry.notch_width_at_bend(bend), notch.bend, signal)


def spine_wall(observed: TubeCoordinates, centerline: Centerline, geometry: TubeGeometry, gate: float,
               footprint: float) -> tuple[np.ndarray, float, float]:
    """The points on spines (away from the comb's cuts grown by two footprints) and the outer wall's level and
    spread measured on them (wall.surface_band), as detect_notches and measure_notch_side take it (`wall`)."""
    spine = ~near_cuts(observed.s, geometry, centerline, 2.0 * footprint)
    level, spread = surface_band(observed.radius - geometry.outer_radius, gate, spine)
    return spine, level, spread


def detect_notches(coords: TubeCoordinates, centerline: Centerline, geometry: TubeGeometry, gate: float,
                   footprint: float, kernel_px: float, min_width_fraction: float, tip_s: float,
                   observed: TubeCoordinates | None = None,
                   wall: tuple[np.ndarray, float, float] | None = None) -> list[Notch]:
    """The robot's comb of notches matched to the evidence along s; each notch refined where the comb puts it.

    Evidence, per cell of s, within the angular window where a notch opens the outer surface:
    - coverage: 1 - (outer-wall point density / its local plateau): 1 where a slot is seen through, and
      where its floor and faces, seen obliquely, fill it with depth inside the wall's band;
    - depression: the share of the window's points lying inside the wall band.
    A notch reports "coverage" when its window is empty (a slot seen through), "depression" when points
    inside the wall's radius fill it (seen obliquely). The wall's level and band
      are measured on spine points only (away from the comb's cuts), so notch interiors cannot widen them.
    The comb (count and pitch from the configuration, bent by the centreline: comb.expected_centres) is
    slid along s as one matched filter to where the evidence agrees best; each notch is then the run of
    evidence above one half around its comb position, its edges where the evidence crosses one half (for
    coverage that is the half-plateau level: each depth pixel stands for a cell of one footprint), centred
    within the comb's notch (a run centred farther off is not that notch). Where neither gives a run, a dip of
    the coverage at the comb's place (_dip_at) finds the notch without edges ("dip": placed by the comb, its
    width what its bend with its neighbours' implies, steady_bend). A rim the matcher mixed with the
    floor behind it is measured where its viewing rays put it (_rim_gaps). Where no camera sees the window
    (its plateau under UNSEEN_PLATEAU_FRACTION of the tube's) no notch is found, nor one reaching into it; where
    the matcher ate the spines down to a tenth of the pitch (SPINE_TOP_PERCENTILE), the slots are the gaps between
    what is left of them, on the wall or off its level.

    wall: spine_wall(observed) when the caller has it already.
    observed: the points' coordinates as measured, when `coords` are those points moved (e.g. along their
    viewing rays onto the wall): which points lie on the outer wall is judged by where they were seen, as a
    cut face seen through a notch would otherwise be moved onto the wall inside the notch and fill it.
    """
    r_o = geometry.outer_radius
    footprint = geometry.pixel_footprint_or_default(footprint)
    # the window where a notch removes the outer surface, less the angular uncertainty of a point
    margin = np.arcsin(min(1.0, 2.0 * footprint / r_o))
    window = geometry.gap_half_angle - margin
    seen = coords if observed is None else observed
    offset = seen.radius - r_o
    centres = expected_centres(geometry, centerline)
    spine, level, _ = spine_wall(seen, centerline, geometry, gate, footprint) if wall is None else wall
    near = np.abs(offset) < gate
    if np.count_nonzero(near) < 10:
        return []
    # the band of the wall: its own spread on spines (robust), at least half a footprint, within the gate
    spine_near = near & spine if np.count_nonzero(near & spine) >= 10 else near
    band = min(gate, max(3.0 * robust_spread(offset[spine_near], level), footprint / 2))
    in_window = (np.abs(coords.angle) < window) & (coords.s > 0) & (coords.s < tip_s)
    on_outer = in_window & (np.abs(offset - level) < band)
    depressed = in_window & (offset < level - band) & (offset > level - gate - (r_o - geometry.inner_radius))
    if np.count_nonzero(on_outer) < 10:
        return []
    cell = footprint / 8.0
    kernel = kernel_px * footprint
    grid, density = coverage_profile(coords.s[on_outer], 0.0, tip_s, cell, kernel)
    # local plateau: the upper quartile over one notch pitch (a gap fills at most half of it)
    span = max(int(round(geometry.notch_pitch / cell)), 3)
    plateau = percentile_filter(density, 75, size=2 * span + 1, mode="nearest")
    # where no camera sees the window (the notched side turned away from both, or nearer one than its depth
    # range), its density and plateau are a few stray points, whose gaps are no slots: the wall counts as
    # missing there all along, so a run reaching into it has no far edge (it runs on to the tip, or wider than
    # any notch) and is no notch
    whole_wall = np.percentile(plateau, 90)
    _, anything = coverage_profile(coords.s[in_window & (np.abs(offset) < gate + r_o - geometry.inner_radius)],
                                   0.0, tip_s, cell, kernel)
    # spines eaten to under a quarter of the pitch (SPINE_TOP_PERCENTILE): where the upper quartile calls the window
    # unseen but the window's points stand as dense as a wall's on a spine within a pitch on either side, the slots
    # are the gaps between them, on the wall or pulled off its level by the backdrop their pixels mixed in
    spine_top = _spine_top_either_side(anything, span)
    eroded = (plateau < UNSEEN_PLATEAU_FRACTION * whole_wall) & (spine_top >= ERODED_SPINE_TOP * whole_wall)
    window_seen = eroded | (plateau >= UNSEEN_PLATEAU_FRACTION * whole_wall)
    plateau = np.where(eroded, spine_top, plateau)
    coverage_gap = np.where(window_seen, np.clip(1.0 - np.where(eroded, anything, density) / np.maximum(plateau, 1e-12),
                                                 0.0, 1.0), 1.0)
    rim_gaps = _rim_gaps(coords, seen, density, depressed, r_o, level, band, plateau, tip_s, cell, kernel)
    _, deep = coverage_profile(coords.s[depressed], 0.0, tip_s, cell, kernel)
    # share of the window's points that are depressed; where the window holds few points it says nothing, nor
    # where the spines' own points were pulled off the wall
    total = deep + density
    depression = np.where(window_seen & ~eroded & (total > 0.25 * plateau), deep / np.maximum(total, 1e-12), 0.0)
    evidence = np.maximum(coverage_gap, depression)
    # the comb as one matched filter: shift along s (within half a pitch) maximising the evidence under it
    half_width = geometry.notch_width / 2.0
    shifts = np.arange(-geometry.notch_pitch / 2, geometry.notch_pitch / 2 + cell, cell)
    cumulative = np.concatenate([[0.0], np.cumsum(evidence)])

    def mean_over(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        i = np.clip(((lo - grid[0]) / cell).astype(np.intp), 0, len(grid))
        j = np.clip(((hi - grid[0]) / cell).astype(np.intp), 0, len(grid))
        return np.where(j > i, (cumulative[j] - cumulative[i]) / np.maximum(j - i, 1), 0.0)

    placed = centres[None, :] + shifts[:, None]
    score = mean_over(placed - half_width, placed + half_width).sum(axis=1)
    shift = float(shifts[int(np.argmax(score))])
    gaps, indices, dipped = [], [], []
    for k, centre in enumerate(centres + shift):
        if centre - half_width <= 0 or centre + half_width >= tip_s:
            continue
        # wall coverage measures the edges (exact at half the plateau); where it shows no gap, the share of
        # depressed points does
        found = _run_around(grid, coverage_gap, centre, geometry.notch_pitch / 2)
        if found is not None and rim_gaps is not None:
            found = _with_mixed_rims(found, grid, rim_gaps, geometry, footprint, min_width_fraction)
        if found is None or not _plausible(found, centre, geometry, footprint, min_width_fraction):
            found = _run_around(grid, depression, centre, geometry.notch_pitch / 2)
        dip = found is None or not _plausible(found, centre, geometry, footprint, min_width_fraction)
        if dip and not _dip_at(grid, coverage_gap, window_seen, centre, half_width, geometry.notch_pitch):
            continue
        gaps.append((centre - half_width, centre + half_width) if dip else found)
        indices.append(k)
        dipped.append(dip)
    # the signal: a slot seen through leaves the window empty; one seen obliquely fills it with its floor and
    # faces, inside the wall's radius (all notches' cells at once: one call, not two means per notch)
    signals = ["dip" if dip else "coverage" if see_through else "depression"
               for dip, see_through in zip(dipped, _seen_through(grid, anything, plateau, gaps), strict=True)]
    return _measure(gaps, indices, signals, centerline, geometry, centres + shift, tip_s)


def _spine_top_either_side(density: np.ndarray, span: int) -> np.ndarray:
    """Per cell the lower of the spines' tops (SPINE_TOP_PERCENTILE of the density) over the pitch (`span` cells)
    before it and the pitch after it: a comb of narrow spines has one in each, the last spine before a stretch no
    camera sees has none beyond it."""
    half = span // 2
    top = percentile_filter(density, SPINE_TOP_PERCENTILE, size=2 * half + 1, mode="nearest")
    padded = np.pad(top, half, mode="edge")
    return np.minimum(padded[:-2 * half], padded[2 * half:])


def _rim_gaps(coords: TubeCoordinates, seen: TubeCoordinates, density: np.ndarray, depressed: np.ndarray,
              r_o: float, level: float, band: float, plateau: np.ndarray, tip_s: float, cell: float, kernel: float
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """Coverage gaps that count the rims the matcher mixed with what lies behind them, one per rim side.

    A rim whose cut face is turned away from a camera is a depth edge to it: the matcher's window mixes the
    rim's first pixels with the floor seen past it, so they read inside the wall's radius, yet on their viewing
    rays they still lie on the wall. Moved along its ray onto the wall, a point inside the wall's radius goes
    towards its camera along s (rise = moved s - seen s); one that lands on the wall past a notch's rim on
    that side cannot be on that rim's face (turned away from that camera): it is the rim. Points of a face
    that camera sees move the same way but land inside the gap, short of the far rim. So the far rim of each
    notch (its end for points that rose, its start for those that fell) is measured with those points as wall.
    None when the points were not moved (no viewing rays). density: the wall points' coverage profile.
    Returns (gap for end rims, gap for start rims).
    """
    if coords is seen:
        return None
    landed = depressed & (np.abs(coords.radius - r_o - level) < band)
    rise = coords.s - seen.s
    gaps = []
    for towards in (landed & (rise > 0), landed & (rise < 0)):
        # the profile is linear in the points: the wall's own density plus that of the rims given back
        _, recovered = coverage_profile(coords.s[towards], 0.0, tip_s, cell, kernel)
        gaps.append(np.clip(1.0 - (density + recovered) / np.maximum(plateau, 1e-12), 0.0, 1.0))
    return gaps[0], gaps[1]


def _with_mixed_rims(found: tuple[float, float], grid: np.ndarray, rim_gaps: tuple[np.ndarray, np.ndarray],
                     geometry: TubeGeometry, footprint: float, min_width_fraction: float) -> tuple[float, float]:
    """The gap `found` with its end taken where the end rims' gap puts it and its start where the start rims'
    gap does (_rim_gaps), each only when that gap still holds a run around the notch's centre; else as found."""
    centre, reach = (found[0] + found[1]) / 2, (found[1] - found[0]) / 2
    start, end = found
    for_end = _run_around(grid, rim_gaps[0], centre, reach)
    for_start = _run_around(grid, rim_gaps[1], centre, reach)
    if for_end is not None:
        end = min(end, for_end[1])
    if for_start is not None:
        start = max(start, for_start[0])
    candidate = (start, end)
    return candidate if _plausible(candidate, centre, geometry, footprint, min_width_fraction) else found


def _dip_at(grid: np.ndarray, coverage_gap: np.ndarray, window_seen: np.ndarray, centre: float,
            half_width: float, pitch: float) -> bool:
    """Whether the coverage gap dips at a comb centre (see DIP_PEAK): its peak within half_width / 2 of the
    centre at least DIP_PEAK and DIP_PROMINENCE above its median over the spines beside it (beyond half_width,
    within half a pitch), the run above half that peak centred within half_width (as _plausible's runs), every
    cell within half a pitch seen (window_seen)."""
    distance = np.abs(grid - centre)
    near, pitch_cells = distance <= half_width / 2, distance <= pitch / 2
    beside = pitch_cells & (distance > half_width)
    if not near.any() or not beside.any() or not window_seen[pitch_cells].all():
        return False
    top = int(np.flatnonzero(near)[np.argmax(coverage_gap[near])])
    peak = coverage_gap[top]
    # the dip's own middle (its run above half its peak) at the comb's place: a full slot cut off it, reaching in
    # from one side, is not this notch (_plausible); as near as a run's, not nearer: seen obliquely, the part of a
    # slot left open moves along s by a good part of its half width (0.4-0.45 mm on a robot bent 90 degrees towards the
    # camera its notches face)
    first, last = top, top
    while first > 0 and pitch_cells[first - 1] and coverage_gap[first - 1] >= peak / 2:
        first -= 1
    while last < len(grid) - 1 and pitch_cells[last + 1] and coverage_gap[last + 1] >= peak / 2:
        last += 1
    centred = abs((grid[first] + grid[last]) / 2 - centre) <= half_width
    return bool(centred and peak >= DIP_PEAK and peak - median(coverage_gap[beside]) >= DIP_PROMINENCE)


def _seen_through(grid: np.ndarray, anything: np.ndarray, plateau: np.ndarray, gaps: list[tuple[float, float]]
                  ) -> np.ndarray:
    """Per gap, whether the window's points over its cells hold under half the plateau (an empty cell range
    counts as seen through)."""
    if not gaps:
        return np.zeros(0, bool)
    first = np.searchsorted(grid, [start for start, _ in gaps], side="left")
    stop = np.searchsorted(grid, [end for _, end in gaps], side="right")
    # reduceat sums each [first, stop) when given them interleaved (a sentinel cell lets stop reach the end)
    bounds = np.stack([first, np.maximum(stop, first + 1)], axis=1).ravel()
    held = np.add.reduceat(np.append(anything, 0.0), bounds)[::2]
    level = np.add.reduceat(np.append(plateau, 0.0), bounds)[::2]
    return (stop <= first) | (held < 0.5 * level)


def _plausible(gap: tuple[float, float], centre: float, geometry: TubeGeometry, footprint: float,
               min_width_fraction: float) -> bool:
    """Not narrower than the configured fraction of a notch, not wider than a notch could look, and centred
    within half a notch width of `centre`: where the comb puts the notch (it places one to a small fraction of
    its width, so a run centred farther off is something else, and no two notches can take the same run), or
    the gap a refinement started from."""
    width = gap[1] - gap[0]
    return (min_width_fraction * geometry.notch_width <= width <= 2.0 * geometry.notch_width + 2 * footprint
            and abs((gap[0] + gap[1]) / 2 - centre) <= geometry.notch_width / 2)


def _run_around(grid: np.ndarray, evidence: np.ndarray, centre: float, reach: float) -> tuple[float, float] | None:
    """The run of evidence >= 1/2 nearest `centre` (within `reach`), its ends at the half crossings."""
    start, end = _run_edges(grid, evidence, centre, reach)
    return None if np.isnan(start) else (float(start), float(end))


@jit
def _run_edges(grid, evidence, centre, reach):
    """The run of evidence >= 1/2 holding the cell nearest `centre` among those within `reach` of it (the first
    such on a tie), its ends where evidence crosses 1/2 between cells (linear interpolation); NaNs when no cell
    within reach is high, or the run touches either end of the grid (the base or the tip: not a notch). Scans
    outwards from the seed, not the whole grid once per notch."""
    seed, nearest = -1, np.inf
    for i in range(grid.shape[0]):
        if centre - reach <= grid[i] <= centre + reach and evidence[i] >= 0.5 and abs(grid[i] - centre) < nearest:
            seed, nearest = i, abs(grid[i] - centre)
    if seed < 0:
        return np.nan, np.nan
    first, last = seed, seed
    while first > 0 and evidence[first - 1] >= 0.5:
        first -= 1
    while last < grid.shape[0] - 1 and evidence[last + 1] >= 0.5:
        last += 1
    if first == 0 or last == grid.shape[0] - 1:
        return np.nan, np.nan
    return _half_crossing(grid, evidence, first - 1, first), _half_crossing(grid, evidence, last, last + 1)


@jit
def _half_crossing(grid, evidence, i, j):
    """Sub-cell s where evidence crosses 1/2 between grid cells i and j (linear interpolation)."""
    a, b = evidence[i] - 0.5, evidence[j] - 0.5
    if a == b:
        return 0.5 * (grid[i] + grid[j])
    t = min(max(a / (a - b), 0.0), 1.0)
    return grid[i] + t * (grid[j] - grid[i])


def _measure(gaps: list[tuple[float, float]], indices: list[int], signals: list[str], centerline: Centerline,
             geometry: TubeGeometry, comb: np.ndarray, tip_s: float) -> list[Notch]:
    """Width (the outer-surface gap facing the notches) and bend of each notch found.

    The bend of a notch is the turn between the two spines it joins, each spine's direction its chord (the
    spines are straight; a chord is what the smoothed centreline holds best, also at the base and the tip,
    where a local tangent is dragged by the smoothing's boundary). A neighbouring notch not found is taken
    where the comb puts it.
    """
    if not gaps:
        return []
    r_o = geometry.outer_radius
    intervals = [(c - geometry.notch_width / 2, c + geometry.notch_width / 2) for c in comb]
    for gap, index in zip(gaps, indices, strict=True):
        intervals[index] = gap
    spine_starts = np.array([0.0] + [b for _, b in intervals])
    spine_ends = np.array([a for a, _ in intervals] + [tip_s])
    ends = np.clip(np.concatenate([spine_starts, spine_ends]), 0.0, max(tip_s, 0.0))
    position = centerline.frames_at(ends)[0]
    chords = position[len(spine_starts):] - position[:len(spine_starts)]
    chords /= np.maximum(np.linalg.norm(chords, axis=1, keepdims=True), 1e-15)
    start, end = np.array(gaps).T
    normals = centerline.frames_at((start + end) / 2)[2]
    before, after = chords[indices], chords[np.array(indices) + 1]
    bends = np.arccos(np.clip(np.einsum("ij,ij->i", before, after), -1.0, 1.0))
    bends *= np.where(np.einsum("ij,ij->i", after - before, normals) >= 0, 1.0, -1.0)  # + towards the notch side
    widths = np.maximum((end - start) - bends * r_o, 0.0)  # s_n (1 - kappa r_o) with kappa s_n = theta
    measured = [Notch(index, float((a + b) / 2), float(a), float(b), float(width), float(bend), signal)
                for index, signal, a, b, width, bend in zip(indices, signals, start, end, widths, bends, strict=True)]
    # a dip has no edges measured: the arc and gap its steady bend implies, about the comb's place
    bends = {n.index: n.bend for n in measured}
    return [bend_implied(replace(n, bend=steady_bend(bends, n.index)), geometry, "dip") if n.signal == "dip" else n
            for n in measured]


def steady_bend(bends: dict[int, float | None], index: int) -> float:
    """The bend of notch `index` (rad) taken with its found neighbours' (`bends` by index): the median of the
    three. A spine's chord on the smoothed centreline that wobbles (where the curve's support changes, as a stretch
    becomes seen by one camera alone) turns the two notches it joins opposite ways; where a notch's width is the one
    its bend implies (its edges not measured, or misread), one chord's wobble is not its width."""
    known = [bend for i in (index - 1, index, index + 1) if (bend := bends.get(i)) is not None]
    return float(statistics.median(known)) if known else 0.0


# The least share of a kink's excess chord each of its neighbours holds (bump_at).
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
    times the chords' `scatter`, its two neighbours' the same way and each at least SPREAD_SHARE of it, the span's
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
    # the smoothing spreads a kink over both neighbours alike: each holds a good part of its excess (0.45-0.75 of
    # the kink's own on bend_kink); a chord alone off its neighbours (0.2 of it) is the curve's wobble, no kink
    if peak == 0.0 or not all(e / peak >= SPREAD_SHARE for e in beside) or any(abs(e) > abs(peak) for e in excess):
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
    each about the median of the two on either side of it (a steady or steadily changing bend leaves none)."""
    indices = sorted(i for i, bend in bends.items() if bend is not None)
    if len(indices) < 5:
        return np.inf
    values = [bends[i] for i in indices]
    # statistics.median of the two to four neighbours: a tenth of numpy's per-call cost on lists this short
    local = [statistics.median(values[max(k - 2, 0):k] + values[k + 1:k + 3]) for k in range(len(values))]
    return robust_spread(np.subtract(values, local), 0.0)


class SideMeasurement(NamedTuple):
    roll: float         # rad, how far the notches open from the frame's x axis (the configured side)
    uncertainty: float  # rad: half the spread of the window's two edges where both placed it (never under half a
                        # sector), else half the range of sides the sectors allow alike, plus half a sector
    by_edges: bool = False  # both window edges placed it (a matcher's even smear of the two cancels in their mean)


def measure_notch_side(observed: TubeCoordinates, notches: list[Notch], geometry: TubeGeometry, centerline: Centerline,
                       gate: float, footprint: float, search: float = np.radians(45.0),
                       wall: tuple[np.ndarray, float, float] | None = None) -> SideMeasurement | None:
    """How far (rad) the notches open from the frame's x axis (the configured side), measured on the data, and
    how well.

    Inside the found notches the outer wall is missing over |angle - side| < gap_half_angle; spines keep it
    all round. Per sector of angle, the wall points' density inside the notches relative to that on the
    spines (what the cameras can see cancels in the ratio) is matched to that window, slid over +-`search`
    (to a sector), then placed within a sector by its two edges where both are seen (_window_edges).
    None when fewer than two notches were found or half the ring or less is seen. wall:
    spine_wall(observed) when the caller has it already.
    """
    if len(notches) < 2:
        return None
    offset = observed.radius - geometry.outer_radius
    spine, level, spread = spine_wall(observed, centerline, geometry, gate, footprint) if wall is None else wall
    on_wall = np.abs(offset - level) <= spread
    intervals = np.array([[n.start_s + footprint, n.end_s - footprint] for n in notches])
    intervals = intervals[intervals[:, 1] > intervals[:, 0]]
    in_notch = on_wall & inside_intervals(observed.s, intervals)
    on_spine = on_wall & spine & (observed.s > notches[0].start_s) & (observed.s < notches[-1].end_s)
    sectors = 36
    width = 2 * np.pi / sectors
    index = ((observed.angle + np.pi) / width).astype(np.intp) % sectors
    notch_count = np.bincount(index[in_notch], minlength=sectors).astype(float)
    spine_count = np.bincount(index[on_spine], minlength=sectors).astype(float)
    seen = spine_count >= max(5.0, 0.1 * spine_count.max(initial=0.0))
    # the open window is wide: with half the ring unseen or more (one camera alone) its position is not fixed; and
    # the wall inside the notches has to be seen where the spines' is, for the one to be measured against the other
    if np.count_nonzero(seen) <= sectors // 2 or notch_count[seen].sum() == 0:
        return None
    ratio = (notch_count / np.maximum(spine_count, 1.0)) / (notch_count[seen].sum() / spine_count[seen].sum())
    centres = -np.pi + (np.arange(sectors) + 0.5) * width
    sides = np.arange(-search, search + 1e-9, np.radians(1.0))
    coarse = _coarse_side(ratio, seen, centres, sides, geometry.gap_half_angle)
    if coarse is None:
        return None
    side, allowed, outside = coarse
    # the sectors place the window to a sector; a window edge between two seen neighbouring sectors is
    # placed within them, where the ratio crosses half its level outside the window
    located = _window_edges(ratio, seen, centres, width, side, geometry.gap_half_angle, outside)
    if located:
        low, high = allowed[0] - width / 2, allowed[1] + width / 2  # what the sectors allow
        # the edges' spread shows a matcher smearing them unevenly inwards, not one edge smeared in and the other
        # out (which shifts both alike): each edge is placed between two sectors' centres, to half a sector
        return SideMeasurement(float(np.clip(np.mean(located), low, high)),
                               max(abs(located[0] - located[1]) / 2, width / 2), by_edges=True)
    # an edge that falls where nothing is seen: the sectors at the border of what is seen (grazing views thin
    # the wall there unevenly, which reads as the window's edge) may have placed the window; judged without
    # them as well, the smaller turn of the two stands (a side no edge placed moves no further than it must)
    judged = _coarse_side(ratio, seen & np.roll(seen, 1) & np.roll(seen, -1), centres, sides,
                          geometry.gap_half_angle)
    if judged is not None and abs(judged[0]) < abs(side):
        side, allowed = judged[0], judged[1]
    return SideMeasurement(side, (allowed[1] - allowed[0]) / 2 + width / 2)


def _coarse_side(ratio: np.ndarray, judged: np.ndarray, centres: np.ndarray, sides: np.ndarray, half_angle: float
                 ) -> tuple[float, tuple[float, float], np.ndarray] | None:
    """The candidate side whose open window (within half_angle of it) best separates the wall ratio over the
    judged sectors (mean outside minus mean inside; ties: the smallest turn), the range of sides tied with it,
    and its outside mask; None when no candidate has judged sectors both inside and outside its window.
    Every candidate at once: (candidates, sectors) masks."""
    distance = np.abs(_wrapped(centres[None, :] - sides[:, None]))
    inside = judged[None, :] & (distance < half_angle)
    outside = judged[None, :] & ~(distance < half_angle)
    count_in, count_out = inside.sum(axis=1), outside.sum(axis=1)
    valid = (count_in > 0) & (count_out > 0)
    if not np.any(valid):
        return None
    score = (outside @ ratio) / np.maximum(count_out, 1) - (inside @ ratio) / np.maximum(count_in, 1)
    score = np.where(valid, score, -np.inf)
    best = np.flatnonzero(score >= score.max() - 1e-12)
    chosen = best[np.argmin(np.abs(sides[best]))]
    return float(sides[chosen]), (float(sides[best].min()), float(sides[best].max())), outside[chosen]


def _window_edges(ratio: np.ndarray, seen: np.ndarray, centres: np.ndarray, width: float, side: float,
                  half_angle: float, outside: np.ndarray) -> list[float]:
    """The side the window's two edges put the notches at, when each falls between two seen neighbouring
    sectors, one mostly open and one mostly walled (their ratios either side of half the median outside the
    window): a sector holds as much wall as the share of it outside the window, which places the edge within
    them. Near an edge the matcher thins the wall as much on one side of the window as on the other, so only
    both edges together (their mean) place it; an empty list when one is not seen so. Sectors at the border
    of what is seen are left out: grazing views thin the wall there unevenly, which would read as an edge."""
    sectors = len(ratio)
    usable = seen & np.roll(seen, 1) & np.roll(seen, -1)
    if not np.any(usable & outside):
        return []
    level = float(median(ratio[usable & outside]))
    share = np.clip(ratio / max(level, 1e-12), 0.0, 1.0)
    found = []
    for sign in (1, -1):  # the edge at side + half_angle (wall beyond it at larger angles), at side - half_angle
        edge = side + sign * half_angle
        nearest = int(np.argmin(np.abs(_wrapped(centres - edge))))
        for step in (0, -1, 1, -2):
            open_, walled = (nearest + sign * step) % sectors, (nearest + sign * (step + 1)) % sectors
            if usable[open_] and usable[walled] and share[open_] < 0.5 <= share[walled]:
                boundary = centres[open_] + sign * width / 2
                located = boundary - sign * share[open_] * width + sign * (1.0 - share[walled]) * width
                found.append(float(_wrapped(located - sign * half_angle)))
                break
    return found if len(found) == 2 else []


def _wrapped(angle):
    """Angles wrapped into [-pi, pi) (a fifth of the cost of np.angle(np.exp(1j * angle)))."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


def face_view_tangent(centerline: Centerline, s: np.ndarray, camera_origins: np.ndarray,
                      facing: float | np.ndarray) -> np.ndarray:
    """Per cut face at arc lengths s (outward normal `facing` x the tangent: +1 a notch's start face, -1 its end
    face; one for all, or one per face), how much of it the cameras see beside its rim: the mean over the cameras
    of the tangent of the angle between the view and the face's plane where the face turns towards the camera,
    0 where it turns away."""
    position, tangent, _, _ = centerline.frames_at(np.asarray(s, dtype=float))
    view = camera_origins[None, :, :] - position[:, None, :]
    facing = np.asarray(facing, dtype=float)[..., None]
    cosine = facing * np.einsum("nj,ncj->nc", tangent, view) / np.linalg.norm(view, axis=2)
    cosine = np.clip(cosine, 0.0, 1.0 - 1e-9)
    return np.mean(cosine / np.sqrt(1.0 - cosine * cosine), axis=1)


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
    mean over 7 px does so, test/synthetic_views.py; the package's simulator moves rims over the faces). The
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
    given the arc and width its bend (the median of its own and its neighbours') implies, about its centre
    (signal "bend"), and the rims are calibrated again without it, so that no spine it bounds shares its error
    with a neighbour; so on, the farthest off first, until no measured notch is off its bend that far. One whose
    bend was not so measured (the last found: its distal rim, where the tube seen thins out, is the rim most often
    read far off, 0.25-0.4 mm in the sweeps) is checked against, and if misread given, the median of the bends of
    the one or two notches before it whose bends were; those with neither are listed unchecked.

    Where the chords show a kink (bump_at), the smoothed centreline spread its bend over the notches up to two away:
    the kink is checked against (and if misread given) the bend gathered back, those notches against the steady
    bend about it, not by their chords, the spread ones (taking whichever of its own chord's bend and the gathered
    one explained its width let bend_kink's notch 7, read 0.22 mm wide by a matcher with a 5 px window and no
    left-right check, stand); and those are the bends they report."""
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
            return CheckedNotches(calibrated, misread, sorted(n.index for n in calibrated if n.edges_measured
                                                              and n.index not in checked and n.index not in before))
        read = next(n for n in calibrated if n.index == worst)
        misread[worst] = read.width
        steady = (before[worst] if worst in before else given_back[worst] if worst in given_back
                  else steady_bend({n.index: n.bend for n in notches}, worst))
        notches = [bend_implied(replace(read, bend=steady), geometry, "bend") if n.index == worst else n
                   for n in notches]


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
