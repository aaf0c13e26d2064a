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

from collections.abc import Callable, Collection
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.ndimage import percentile_filter

from ntcr_recon.core.base.compiled import jit
from ntcr_recon.core.base.robust import median, robust_spread
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates
from ntcr_recon.core.relocation.profile import coverage_profile
from ntcr_recon.core.relocation.wall import surface_band
from ntcr_recon.core.robot.comb import expected_centres, near_cuts
from ntcr_recon.core.robot.geometry import TubeGeometry

# a notch window whose density plateau is under this share of the tube's (90th percentile): seen by no camera
UNSEEN_PLATEAU_FRACTION = 0.1

# A notch neither signal measures is still found where the comb puts it when the wall's coverage dips there: its
# coverage gap peaks at DIP_PEAK or more within a quarter of a notch width of the comb's centre, DIP_PROMINENCE
# above its median over the spines either side (up to half a pitch away), the whole pitch seen by a camera. A slot
# narrower than the stereo matcher's window (4 px at 105 mm for a 1 mm notch, against 7 px) leaves that and no
# more: the window fills it with the spines' depth.
DIP_PEAK = 0.3
DIP_PROMINENCE = 0.25

# The wall's local density plateau is the upper quartile of its coverage over a pitch (a gap fills at most half of
# it). A matcher whose window mixes a backdrop behind the slots into the rims' pixels erodes each spine from both
# sides, down to a tenth of a pitch, and pulls what is left off the wall's level: the upper quartile then lies in
# the gaps and calls the window unseen. There the spines' top (this percentile of the coverage of all the window's
# points over a pitch, on either side) is the plateau, if it is a wall's: at least ERODED_SPINE_TOP of the density of
# the wall seen whole (a stray point's bump, where no camera sees the window, is a few hundredths of that).
SPINE_TOP_PERCENTILE = 95
ERODED_SPINE_TOP = 0.25

# The signals of notches found without their edges measured: placed by the comb, their widths their bends'.
BEND_IMPLIED = ("dip", "outline", "bend")


@dataclass(frozen=True)
class Notch:
    index: int            # position in the robot's notch order (0 = nearest the base)
    center_s: float       # m, centreline arc length of the notch centre
    start_s: float
    end_s: float
    width: float          # m, outer-surface gap facing the notches
    bend: float | None    # rad, the centreline's turn across the notch
    signal: str = "coverage"  # what measured it: "coverage" (a slot seen through), "depression" (seen obliquely:
                              # floor and faces inside the wall's radius), "dip" (a slot the matcher filled: placed,
                              # its width its bend's), "outline" (as a dip, only a colour image's outline marks it)
                              # or "bend" (found, but its edges read a width its bend rules out: its bend's)
    read_width: float | None = None  # m, its edges' width where `width` weighs it with its bend's (weighed_width)

    @property
    def edges_measured(self) -> bool:
        """Whether its edges are the data's: a dip's, an outline's or a misread one's are those its bend implies."""
        return self.signal not in BEND_IMPLIED


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
                   wall: tuple[np.ndarray, float, float] | None = None,
                   outline: Callable[[np.ndarray, list[int]], Collection[int]] | None = None,
                   comb_shift: Callable[[np.ndarray], float | None] | None = None) -> list[Notch]:
    """The robot's comb of notches matched to the evidence along s; each notch refined where the comb puts it.

    Evidence, per cell of s, within the angular window where a notch opens the outer surface:
    - coverage: 1 - (outer-wall point density / its local plateau): 1 where a slot is seen through, and
      where its floor and faces, seen obliquely, fill it with depth inside the wall's band;
    - depression: the share of the window's points lying inside the wall band.
    A notch reports "coverage" when its window is empty (a slot seen through), "depression" when points
    inside the wall's radius fill it (seen obliquely). The wall's level and band
      are measured on spine points only (away from the comb's cuts), so notch interiors cannot widen them.
    The comb (count and pitch from the configuration, bent by the centreline: comb.expected_centres) is
    slid along s as one matched filter to where the evidence agrees best (or where `comb_shift` says the colour
    images show it); each notch is then the run of
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
    outline: given the comb's centres and the notches depth did not find, those the tube's outline in the colour
    images shows (relocation.outline_notches): found as a dip is ("outline"). comb_shift: given the comb's
    centres, its shift the colour images show (relocation.outline_notches; None: not shown).
    """
    footprint = geometry.pixel_footprint_or_default(footprint)
    seen = coords if observed is None else observed
    centres = expected_centres(geometry, centerline)
    profiles = _evidence(coords, seen, centerline, geometry, gate, footprint, kernel_px, tip_s, wall)
    if profiles is None:
        return []
    shift = comb_shift(centres) if comb_shift is not None else None
    shift = _comb_shift(profiles, centres, geometry) if shift is None else shift
    gaps, indices, dipped, unfound = [], [], [], []
    half_width = geometry.notch_width / 2.0
    for k, centre in enumerate(centres + shift):
        if centre - half_width <= 0 or centre + half_width >= tip_s:
            continue
        found = _gap_at(profiles, centre, geometry, footprint, min_width_fraction)
        if found is None:
            unfound.append(k)
            continue
        gaps.append(found[0])
        indices.append(k)
        dipped.append(found[1])
    # the signal: a slot seen through leaves the window empty; one seen obliquely fills it with its floor and
    # faces, inside the wall's radius (all notches' cells at once: one call, not two means per notch)
    see_through = _seen_through(profiles.grid, profiles.anything, profiles.plateau, gaps)
    signals = ["dip" if dip else "coverage" if through else "depression"
               for dip, through in zip(dipped, see_through, strict=True)]
    shown = sorted(outline(centres + shift, unfound)) if outline is not None and unfound else []
    gaps += [(centres[k] + shift - half_width, centres[k] + shift + half_width) for k in shown]
    order = np.argsort(indices + shown, kind="stable")
    gaps, signals = [gaps[i] for i in order], [(signals + ["outline"] * len(shown))[i] for i in order]
    return _measure(gaps, sorted(indices + shown), signals, centerline, geometry, centres + shift, tip_s)


class _Profiles(NamedTuple):
    """The evidence along s on a grid of cells (see detect_notches)."""

    grid: np.ndarray
    cell: float
    coverage_gap: np.ndarray
    depression: np.ndarray
    window_seen: np.ndarray
    anything: np.ndarray   # density of every point in the window, on the wall or inside it
    plateau: np.ndarray
    rim_gaps: tuple[np.ndarray, np.ndarray] | None

    @property
    def evidence(self) -> np.ndarray:
        return np.maximum(self.coverage_gap, self.depression)


def _evidence(coords: TubeCoordinates, seen: TubeCoordinates, centerline: Centerline, geometry: TubeGeometry,
              gate: float, footprint: float, kernel_px: float, tip_s: float,
              wall: tuple[np.ndarray, float, float] | None) -> _Profiles | None:
    """Coverage gap and depression along s in the window where a notch opens the outer surface (detect_notches);
    None where too few points lie near the wall to say."""
    r_o = geometry.outer_radius
    # the window where a notch removes the outer surface, less the angular uncertainty of a point
    margin = np.arcsin(min(1.0, 2.0 * footprint / r_o))
    window = geometry.gap_half_angle - margin
    offset = seen.radius - r_o
    spine, level, _ = spine_wall(seen, centerline, geometry, gate, footprint) if wall is None else wall
    near = np.abs(offset) < gate
    if np.count_nonzero(near) < 10:
        return None
    # the band of the wall: its own spread on spines (robust), at least half a footprint, within the gate
    spine_near = near & spine if np.count_nonzero(near & spine) >= 10 else near
    band = min(gate, max(3.0 * robust_spread(offset[spine_near], level), footprint / 2))
    in_window = (np.abs(coords.angle) < window) & (coords.s > 0) & (coords.s < tip_s)
    on_outer = in_window & (np.abs(offset - level) < band)
    depressed = in_window & (offset < level - band) & (offset > level - gate - (r_o - geometry.inner_radius))
    if np.count_nonzero(on_outer) < 10:
        return None
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
    return _Profiles(grid, cell, coverage_gap, depression, window_seen, anything, plateau, rim_gaps)


def _comb_shift(profiles: _Profiles, centres: np.ndarray, geometry: TubeGeometry) -> float:
    """The comb as one matched filter: the shift along s (within half a pitch) maximising the evidence under it."""
    grid, cell = profiles.grid, profiles.cell
    half_width = geometry.notch_width / 2.0
    shifts = np.arange(-geometry.notch_pitch / 2, geometry.notch_pitch / 2 + cell, cell)
    cumulative = np.concatenate([[0.0], np.cumsum(profiles.evidence)])
    placed = centres[None, :] + shifts[:, None]
    i = np.clip(((placed - half_width - grid[0]) / cell).astype(np.intp), 0, len(grid))
    j = np.clip(((placed + half_width - grid[0]) / cell).astype(np.intp), 0, len(grid))
    score = np.where(j > i, (cumulative[j] - cumulative[i]) / np.maximum(j - i, 1), 0.0).sum(axis=1)
    return float(shifts[int(np.argmax(score))])


def _gap_at(profiles: _Profiles, centre: float, geometry: TubeGeometry, footprint: float,
            min_width_fraction: float) -> tuple[tuple[float, float], bool] | None:
    """The notch's gap around its comb place and whether only a dip placed it; None where nothing shows one."""
    grid, half_width = profiles.grid, geometry.notch_width / 2.0
    # wall coverage measures the edges (exact at half the plateau); where it shows no gap, the share of
    # depressed points does
    found = _run_around(grid, profiles.coverage_gap, centre, geometry.notch_pitch / 2)
    if found is not None and profiles.rim_gaps is not None:
        found = _with_mixed_rims(found, grid, profiles.rim_gaps, geometry, footprint, min_width_fraction)
    if found is None or not _plausible(found, centre, geometry, footprint, min_width_fraction):
        found = _run_around(grid, profiles.depression, centre, geometry.notch_pitch / 2)
    dip = found is None or not _plausible(found, centre, geometry, footprint, min_width_fraction)
    if dip and not _dip_at(grid, profiles.coverage_gap, profiles.window_seen, centre, half_width,
                           geometry.notch_pitch):
        return None
    return ((centre - half_width, centre + half_width) if dip else found), dip


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
    bends = {n.index: n.bend for n in measured}  # a dip's (or an outline's) arc and gap: its steady bend's
    return [bend_implied(replace(n, bend=steady_bend(bends, n.index, geometry.max_notch_bend)), geometry, n.signal)
            if n.signal in ("dip", "outline") else n for n in measured]


def steady_bend(bends: dict[int, float | None], index: int, max_bend: float) -> float:
    """The bend of notch `index` (rad) for a width its bend implies (its edges not measured, or misread): the mean of
    the chords (`bends`, by index) up to two notches either side. A spine's chord that wobbles turns the two notches
    it joins opposite ways, so a sum of consecutive chords is the turn between its end spines, which the centreline
    holds best (the real matcher's chords of a robot bent 4.8 deg at each notch read 1-14 deg). A chord beyond what
    a notch can bend (`max_bend`) is left out: it spans a spine read no longer than nothing (two gaps overlapping)."""
    known = [bend for i in range(index - 2, index + 3)
             if (bend := bends.get(i)) is not None and abs(bend) <= max_bend]
    return float(np.mean(known)) if known else 0.0
