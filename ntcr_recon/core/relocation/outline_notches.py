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
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.relocation.limbs import CameraView, limb_edges
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


def _tube_like(contrast: np.ndarray) -> np.ndarray:
    """(N, STATIONS, 2): whether each limb read inside a notch (contrast (N, 3, STATIONS, 2, 3): the notch's
    stations, then the spines') took a tube against the background as the spines' limbs did on its side
    (LIMB_CONTRAST_SHARE of their median contrast, projected on it)."""
    spines = np.nanmedian(contrast[:, 1:].transpose(0, 3, 1, 2, 4).reshape(len(contrast), 2, -1, 3), axis=2)
    along = np.einsum("nksc,nkc->nsk", np.nan_to_num(contrast[:, 0].transpose(0, 2, 1, 3), nan=0.0),
                      np.nan_to_num(spines, nan=0.0))
    return along >= LIMB_CONTRAST_SHARE * np.sum(spines**2, axis=2)[:, None, :]
