"""The robot's bend read off an estimated centreline: from the base to an arc length, held short of the curve's free
end, and the curve carried on past its end at the steady bend per notch."""

from __future__ import annotations

import math

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline, base_pose
from ntcr_recon.core.robot.geometry import TubeGeometry

# A curve's bend at its free end is checked against the bend read this many notch pitches short of it (held_bend).
END_TURN_PITCHES = 2


def turn_from_base(centerline: Centerline, geometry: TubeGeometry, s: float) -> float:
    """The robot's bend from its base to arc length s (rad, + towards the notch side): the curve's turn from its
    start, plus the tilt of its start from the base axis the rig configures. A smoothed curve's end tangent leans
    with the bend beside it (the first notches' curvature spreads back over the straight proximal part), so the
    clamp's axis is the better start: on the robot's largest bend the curve's own start tilts 3 deg back."""
    _, axis, binormal = base_pose(geometry)
    start = centerline.frames_at(np.zeros(1))[1][0]
    notch_side = np.cross(binormal, axis)
    tilt = math.atan2(float(start @ notch_side), float(start @ axis))
    return float(centerline.bend_angle(0.0, s)) + tilt


def held_bend(centerline: Centerline, geometry: TubeGeometry, s: float, notch_centres: np.ndarray) -> float | None:
    """The robot's bend from its base to arc length s (rad) read END_TURN_PITCHES pitches short of s, where the
    smoothing has data on both sides, and carried over the rest at the steady bend of the pitches before
    (continued_bend); None on a curve too short for that. At a curve's free end its tangent follows only the data
    before it: on the second renderer's coarse cameras it leant up to 9 deg off, where this stayed within 2.6 (1.0
    deg RMS against 2.2 over 70 scenes); on the simulator the two do as well (1.6 and 1.8 deg RMS over 40 scenes),
    and the end tangent better over the matrix (1.2 against 1.7)."""
    held_to = s - END_TURN_PITCHES * geometry.notch_pitch
    if held_to < END_TURN_PITCHES * geometry.notch_pitch:
        return None
    return turn_from_base(continued_bend(centerline.up_to(held_to), s, notch_centres, geometry), geometry, s)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b of two 3-vectors: np.cross's broadcasting costs some 30 us a call, and continued_bend runs three
    times a frame."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def continued_bend(centerline: Centerline, to_s: float, notch_centres: np.ndarray, geometry: TubeGeometry
                   ) -> Centerline:
    """The curve carried on from its end to arc length `to_s` as the robot bends: over what of each notch lies past
    the curve's end it turns by the steady bend per notch (the curve's turn over its last two pitches, about the
    tangents' common normal, shared by the notches in them), spread over the notch's arc at that bend about its
    centre (notch_centres: the comb's); straight along the spines between and beyond the last notch. The curve
    itself is unchanged."""
    length = centerline.length
    step = float(centerline.s[1] - centerline.s[0])
    if to_s <= length + 1e-12:
        return centerline
    extra = np.arange(1, int(np.ceil((to_s - length) / step - 1e-9)) + 1) * step  # (samples stay uniform)
    start = max(length - 2 * geometry.notch_pitch, 0.0)
    position, tangents_at, normal, binormal = centerline.frames_at(np.array([start, length]))
    first_tangent, tangent = tangents_at
    position, normal, binormal = position[1], normal[1], binormal[1]
    axis = _cross(first_tangent, tangent)
    turn = math.atan2(float(np.linalg.norm(axis)), float(first_tangent @ tangent))
    axis = axis / np.linalg.norm(axis) if turn > 1e-9 else binormal
    centres = np.asarray(notch_centres, float)
    # the turn shared by the notches' arcs within it: the arc a notch spans shrinks with its bend (twice suffices)
    arc, per_notch = geometry.notch_width, 0.0
    for _ in range(2):
        spanned = float(np.sum(np.clip((np.minimum(centres + arc / 2, length) - np.maximum(centres - arc / 2, start))
                                       / arc, 0.0, 1.0)))
        per_notch = turn / spanned if spanned > 0 else 0.0
        arc = max(geometry.notch_arc_at_bend(per_notch), 1e-9)
    # the tangent's turn along the extension, integrated finely (the notches' arcs are a few samples long); each
    # notch's share of its bend past the curve's end (the curve turned through what of it lies before)
    fine = np.linspace(0.0, extra[-1], 16 * len(extra) + 1)
    arc_starts = centres[centres + arc / 2 > length] - arc / 2
    turned_by = np.clip((length - arc_starts) / arc, 0.0, 1.0)
    progress = np.clip((length + fine[:, None] - arc_starts) / arc, 0.0, 1.0) - turned_by
    angle = per_notch * progress.sum(axis=1)
    side = _cross(axis, tangent)
    directions = np.cos(angle)[:, None] * tangent + np.sin(angle)[:, None] * side
    travelled = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (directions[1:] + directions[:-1])
                                                           * np.diff(fine)[:, None], axis=0)])
    picked = np.searchsorted(fine, extra - 1e-12)
    cos_a, sin_a = np.cos(angle[picked])[:, None], np.sin(angle[picked])[:, None]

    def turned(v: np.ndarray) -> np.ndarray:  # Rodrigues about `axis`
        along = float(v @ axis) * axis
        return along + cos_a * (v - along) + sin_a * _cross(axis, v)

    return Centerline(np.concatenate([centerline.s, length + extra]),
                      np.concatenate([centerline.points, position + travelled[picked]]),
                      np.concatenate([centerline.tangents, turned(tangent)]),
                      np.concatenate([centerline.normals, turned(normal)]),
                      np.concatenate([centerline.binormals, turned(binormal)]))
