"""Notches the tube's outline in the colour images shows where depth shows none (issue 61, part 1).

A cut deeper than the tube's radius (chord_offset > 0: it passes the axis) takes away the outer wall over
|angle| < gap_half_angle > 90 deg from the notch side, so from any line of sight at least one limb is cut: the
outline recedes there. The least it recedes is seen along the notch side (or the backbone), where both limbs fall
to the backbone's chord: r_o - sqrt(r_o^2 - d^2) (0.15 mm for a 3.5 mm tube cut 0.7 mm past its axis); turned from
it, one limb recedes further (to the backbone's edge, 2.45 mm, side on). A stereo matcher fills a slot narrower
than its window with the spines' depth (no gap, no dip), but the left imager's outline is sharp: where the comb
puts a notch, a limb lying inside the spines' outline by half that least recession, in a camera whose view shows
both the notch and the spines either side, marks the notch. Its place is the comb's; its edges are not measured
(a face seen obliquely blurs into a ramp), so its width is what its bend implies, as for a dip. A limb shaded dark
reads up to a pixel inward on the spines, as far as the least recession at 90 mm: a view square to the notch side
may then show none, a view turned from it (the other camera, or any at +-45 deg and beyond) still does.

In such a view (a cut limb falls out of the limbs' search) the comb itself is placed by the outline
(comb_shift_in_outline): a stereo matcher fattens the spines towards one side along its baseline, which shifts
the slots depth sees by a few tenths of a millimetre, and the comb with them.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline, cameras_round_tube
from ntcr_recon.core.relocation.limb_profile import SEARCH_PX
from ntcr_recon.core.relocation.limbs import CameraView, LimbEdges, limb_edges, stations_in_view
from ntcr_recon.core.robot.geometry import TubeGeometry

# Stations across the middle of the notch (this share of its width) and on each spine's middle (this share of the
# spine): away from the faces, whose ramp a tilted view spreads over a few tenths of a millimetre.
NOTCH_SHARE = 0.6
SPINE_SHARE = 0.5
STATIONS = 7

# A limb counts as receded where it lies inside the spines' outline by this share of the least recession a cut
# makes (the noise of a median over the stations is a few hundredths of a pixel on a sharp image).
RECESSION_SHARE = 0.5

# A crossing read inside the notch is the tube's limb only where the colour it took for the tube stands off the
# background by at least this share of the spines' (projected on theirs): a slot seen side on shows background on
# both sides of where the limb was, and the crossing found there is a shade of the background's texture.
LIMB_CONTRAST_SHARE = 0.5

# The comb is slid along s over half a pitch either way in steps of this share of the pitch (0.15 mm, under a
# pixel at 90 mm; then refined between the best step and its neighbours), the limbs read as finely.
COMB_STEP_SHARE = 1.0 / 20.0


def least_recession(geometry: TubeGeometry) -> float:
    """How far in (m) the outline recedes at a notch at least, whatever the line of sight (module docstring);
    0 for a cut short of the axis, which a camera looking along the notch side sees no limb of."""
    d, r_o = geometry.chord_offset, geometry.outer_radius
    return r_o - math.sqrt(r_o * r_o - d * d) if d > 0 else 0.0


def notches_in_outline(centerline: Centerline, views: dict[str, CameraView], geometry: TubeGeometry,
                       centres: np.ndarray, indices: list[int], end_s: float) -> dict[int, float]:
    """Of the comb's notches `indices` (their centres, m of s: `centres`), those whose cut the outline shows in
    some camera: per notch the most a limb receded there beyond the spines either side (m; one gone from where it
    was looked for counts as the tube's diameter). Up to end_s (the end seen), each notch and its spines within it."""
    least = least_recession(geometry)
    if least <= 0.0 or not views or not indices:
        return {}
    half, pitch = geometry.notch_width / 2, geometry.notch_pitch
    spine = max(pitch - geometry.notch_width, 0.0)
    notch_offsets = np.linspace(-NOTCH_SHARE, NOTCH_SHARE, STATIONS) * half
    spine_offsets = np.linspace(-SPINE_SHARE, SPINE_SHARE, STATIONS) * spine / 2
    candidates = [i for i in indices if centres[i] - pitch / 2 - spine / 2 > 0 and centres[i] + pitch / 2 < end_s]
    if not candidates:
        return {}
    middle = np.asarray([centres[i] for i in candidates])
    # per notch its stations, then the proximal spine's, then the distal one's
    s = np.concatenate([middle[:, None] + notch_offsets, middle[:, None] - pitch / 2 + spine_offsets,
                        middle[:, None] + pitch / 2 + spine_offsets], axis=1)
    found: dict[int, float] = {}
    for view in views.values():
        edges = limb_edges(centerline, s.ravel(), view, geometry.outer_radius, end_s)
        inward = edges.inward().reshape(len(candidates), 3, STATIONS, 2)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # numpy's all-NaN median: a station set unread
            # a limb not found inside the notch, or found where the tube does not stand off the background as on
            # the spines, is gone from where it was looked for: receded past the search
            gone = np.isnan(inward[:, 0]) | ~_tube_like(edges.contrast.reshape(len(candidates), 3, STATIONS, 2, 3))
            at_notch = np.nanmedian(np.where(gone, np.inf, inward[:, 0]), axis=1)
            spines = np.nanmedian(inward[:, 1:].reshape(len(candidates), 2 * STATIONS, 2), axis=1)
            # per side: the spines read at as many stations as the notch has
            whole = np.sum(np.isfinite(inward[:, 1:]), axis=(1, 2)) >= STATIONS
        receded = np.where(whole & np.isfinite(spines), at_notch - spines, -np.inf).max(axis=1)
        for index, recession in zip(candidates, receded, strict=True):
            if recession >= RECESSION_SHARE * least:
                found[index] = max(found.get(index, 0.0), float(min(recession, geometry.outer_diameter)))
    return found


def comb_shift_in_outline(centerline: Centerline, views: dict[str, CameraView], geometry: TubeGeometry,
                          centres: np.ndarray, end_s: float) -> float | None:
    """The shift along s (m, within half a pitch) of the comb's notch centres `centres` (m of s) at which the
    tube's outline in the colour images recedes most inside the notches against the spines between them: the
    matched filter notches._comb_shift runs on depth, run on the sharper image (a stereo matcher fattens the spines
    towards one side along its baseline, which shifts the slots it sees). In the views where a cut limb falls out
    of the limbs' search (limb_fall): there the outline shows the notch as the limb gone, ending where the cut's
    faces meet the limb edge on; seen along the notch side both limbs recede by the chord's least, which shading and
    the faces seen obliquely move along the tube as much. None without such a view, for a cut short of the axis,
    or where no shift shows the notches' recession (RECESSION_SHARE of the least)."""
    least = least_recession(geometry)
    if least <= 0.0 or not views:
        return None
    pitch, r_o = geometry.notch_pitch, geometry.outer_radius
    step = pitch * COMB_STEP_SHARE
    s = np.arange(max(centres[0] - pitch, step / 2), min(centres[-1] + pitch, end_s), step)  # the comb slid
    shifts = np.arange(-pitch / 2, pitch / 2 + step / 2, step)
    spine = max(pitch - geometry.notch_width, 0.0)
    score, weight = np.zeros(len(shifts)), np.zeros(len(shifts))
    middles = centres[None, :] + shifts[:, None]
    windows = ((0.0, NOTCH_SHARE * geometry.notch_width / 2), (-pitch / 2, SPINE_SHARE * spine / 2),
               (pitch / 2, SPINE_SHARE * spine / 2))  # the notch's middle, then its spines'
    falling = _falling_out(centerline, views, geometry, centres, end_s)
    for i, view in enumerate(falling):
        # the views share the stations out (each read costs 1 ms a camera): opposed views see a notch's cut faces
        # shifted opposite ways, which their mean cancels
        stations = s[i::len(falling)]
        receded = _receded(limb_edges(centerline, stations, view, r_o, end_s), least, r_o)
        notch, proximal, distal = _window_means(stations, receded, middles, windows)
        contrast = notch - (proximal + distal) / 2  # (shifts, notches): NaN where a window was unread
        read = np.isfinite(contrast)
        score += np.where(read, contrast, 0.0).sum(axis=1)
        weight += read.sum(axis=1)
    if not np.any(weight):
        return None
    score = np.where(weight > 0, score / np.maximum(weight, 1), -np.inf)
    best = int(np.argmax(score))
    if score[best] < RECESSION_SHARE * least:
        return None
    if 0 < best < len(shifts) - 1 and np.all(np.isfinite(score[best - 1:best + 2])):  # the parabola's vertex
        below, at, above = score[best - 1:best + 2]
        curvature = below - 2 * at + above
        return float(shifts[best] + (0.5 * step * (below - above) / curvature if curvature < 0 else 0.0))
    return float(shifts[best])


def _falling_out(centerline: Centerline, views: dict[str, CameraView], geometry: TubeGeometry,
                 centres: np.ndarray, end_s: float) -> list[CameraView]:
    """The views in which the cut limb falls out of the limbs' search (limb_fall, in pixels at the notches)."""
    falling = []
    for view in views.values():
        at_centres = stations_in_view(centerline, np.clip(centres, 0.0, end_s), view, geometry.outer_radius)
        distance = at_centres.depth[at_centres.in_front]
        if distance.size and (limb_fall(centerline, view, geometry, centres)
                              > SEARCH_PX * np.median(distance) / view.intrinsics.fx):
            falling.append(view)
    return falling


def limb_fall(centerline: Centerline, view: CameraView, geometry: TubeGeometry, centres: np.ndarray) -> float:
    """How far (m) the limb nearer the notch side falls at a notch in this view, median over the comb's notches:
    seen at an angle t from the notch side (the camera's direction round the tube turned by a right angle), the
    cut leaves the wall up to the gap's half angle g from it, whose corner lies r_o cos(g - t) out: it falls by
    r_o (1 - cos(g - t)) where t < g (side on, t = 0: past the axis to the backbone's chord)."""
    frames = centerline.frames_at(np.clip(centres, 0.0, centerline.length))
    round_tube = cameras_round_tube(frames, view.extrinsic[None, :3, 3])[:, 0]
    turned = np.abs(np.abs(np.arctan2(round_tube[:, 1], round_tube[:, 0])) - math.pi / 2)
    gap = geometry.gap_half_angle
    fall = np.where(turned < gap, geometry.outer_radius * (1.0 - np.cos(gap - turned)), 0.0)
    return float(np.median(fall))


def _receded(edges: LimbEdges, least: float, cap: float) -> np.ndarray:
    """(S,): how far in the more receded limb lies at each station (m; `cap` where one is gone, or read where the
    tube does not stand off the background as where the outline is whole; NaN where the station is unusable)."""
    inward = edges.inward()
    whole = np.abs(inward) <= least
    # a limb read is a contrast read: the whole limbs' contrasts are finite (none: no reference, every limb tube-like)
    reference = np.stack([np.median(edges.contrast[whole[:, j], j], axis=0) if np.any(whole[:, j])
                          else np.zeros(3) for j in range(2)])
    tube = _stands_off(edges.contrast, reference)
    receded = np.where(np.isnan(inward) | ~tube, cap, np.clip(inward, -cap, cap)).max(axis=1)
    return np.where(edges.usable, receded, np.nan)


def _window_means(s: np.ndarray, values: np.ndarray, middles: np.ndarray,
                  windows: tuple[tuple[float, float], ...]) -> list[np.ndarray]:
    """Per window (its offset from `middles`, any shape, and its half length): the mean of `values` (at stations s,
    ascending; NaN: unread), taken as linear between stations (so that the mean slides smoothly with the window),
    over the window about each middle; NaN where less than half the window was read."""
    read = np.isfinite(values).astype(float)
    step = np.diff(s)
    # the running integrals of the values and of being read, by the trapezoid rule (an unread station counts 0)
    total = np.concatenate([[0.0], np.cumsum(step * (np.nan_to_num(values[:-1]) + np.nan_to_num(values[1:])) / 2)])
    length = np.concatenate([[0.0], np.cumsum(step * (read[:-1] + read[1:]) / 2)])
    # per window its two ends about every middle, one interpolation for all
    ends = np.stack([middles + offset + sign * half for offset, half in windows for sign in (-1.0, 1.0)])
    totals = np.interp(ends, s, total).reshape(len(windows), 2, *middles.shape)
    lengths = np.interp(ends, s, length).reshape(len(windows), 2, *middles.shape)
    with np.errstate(all="ignore"):
        return [np.where(covered[1] - covered[0] >= half, (summed[1] - summed[0]) / (covered[1] - covered[0]), np.nan)
                for (_, half), summed, covered in zip(windows, totals, lengths, strict=True)]


def _tube_like(contrast: np.ndarray) -> np.ndarray:
    """(N, STATIONS, 2): whether each limb read inside a notch (contrast (N, 3, STATIONS, 2, 3): the notch's
    stations, then the spines') took a tube against the background as the spines' limbs did on its side
    (LIMB_CONTRAST_SHARE of their median contrast, projected on it)."""
    spines = np.nanmedian(contrast[:, 1:].transpose(0, 3, 1, 2, 4).reshape(len(contrast), 2, -1, 3), axis=2)
    return _stands_off(contrast[:, 0], np.nan_to_num(spines)[:, None])


def _stands_off(contrast: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Whether each limb's contrast (..., 3; NaN: none read) stands off the background along `reference` (the
    whole limbs' contrast, broadcast to it) by LIMB_CONTRAST_SHARE of the reference's own (a zero one: any does)."""
    along = np.sum(np.nan_to_num(contrast) * reference, axis=-1)
    return along >= LIMB_CONTRAST_SHARE * np.sum(reference**2, axis=-1)
