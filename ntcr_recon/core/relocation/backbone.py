"""The axis levelled by the cameras that face the backbone (level_by_backbone): the uncut wall opposite the notches
is read at the plain tube's level, where the notch side's camera reads the wall between the slots deep."""

from __future__ import annotations

import numpy as np

from ntcr_recon.core.relocation.alignment import WallTrust, camera_window_sums, clear_of_slots_in_view
from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates, cameras_round_tube
from ntcr_recon.core.robot.comb import clear_of_cuts, cut_intervals, inside_intervals, near_cuts


def level_by_backbone(centerline: Centerline, coords: TubeCoordinates, frames: tuple, viewpoints: np.ndarray,
                      camera: np.ndarray, origins: np.ndarray, trust: WallTrust,
                      minimum_points: int = 10) -> tuple[Centerline, float]:
    """The axis moved along the lines of sight of the cameras that face the backbone, so that the wall each of
    them sees between the notches lies at the level it sees on the plain tube; and the RMS of that move (m).

    A camera that sees the notch side reads the wall between the notches deeper than the plain tube (its
    matcher's window reaches into the slots: 0.3 mm at 100 mm), one that faces the backbone - the uncut wall
    opposite the notches, beyond the gap's half-angle from the notch side - hardly does. The alignment's common
    level splits the two cameras' difference between them and moves the axis away from the notch side's camera
    by half the deficit; the backbone's camera, whose level on the plain stretches (before the first cut and
    after the last) is measured, places it along its line of sight instead. Windows of a notch pitch, trusted
    points as the alignment's, and of those only the wall clear of the slots in the camera's image by a matcher's
    reach (clear_of_slots_in_view: a camera just past the gap's edge sees that edge a few pixels from the tube's
    middle, and a matcher that averages its window over the slot reads the wall there deep as well); a camera that
    sees such wall in fewer than half the windows it faces the backbone in (a thin tube, a coarse pixel, a camera
    just past the edge) levels by all the wall facing it, which a matcher that keeps the slot out of the wall's
    window leaves whole. The move, interpolated along s from none at the base, holds beyond the last window.
    Unchanged (and 0) where no camera faces the backbone or none saw the plain tube.
    """
    geometry, end_s = trust.geometry, trust.end_s
    window = geometry.notch_pitch
    cuts = cut_intervals(geometry, centerline, trust.cut_margin)
    windows = max(int(np.ceil(end_s / window)), 1)
    centres = (np.arange(windows) + 0.5) * window
    notched = (centres > cuts[0, 0]) & (centres < cuts[-1, 1])
    window_frames = centerline.frames_at(centres)
    # each camera's direction round the tube per window, from the notch side (x): past the gap's half-angle it
    # faces the backbone; one that sees the notch side's gaps reads no plain tube's level between them
    round_tube = cameras_round_tube(window_frames, origins)
    faces_backbone = notched[:, None] & (np.abs(np.arctan2(round_tube[..., 1], round_tube[..., 0]))
                                         > geometry.gap_half_angle)
    if not np.any(faces_backbone):
        return centerline, 0.0
    away_from_cuts = clear_of_cuts(coords, geometry, centerline, trust.cut_margin, inside_intervals(coords.s, cuts))
    # the backbone's wall, but within a matcher's reach of a slot in the image, reads deeper as the notch side does
    reach = trust.silhouette_margin
    backbone_wall = away_from_cuts & clear_of_slots_in_view(
        coords, frames, viewpoints, geometry, near_cuts(coords.s, geometry, centerline, reach), reach)

    def sums(selected, width):
        return camera_window_sums(centerline, coords, frames, viewpoints, camera, len(origins), trust, selected,
                                  width)

    plain = (coords.s < cuts[0, 0]) | (coords.s > cuts[-1, 1])
    # per camera the wall clear of the slots where it sees such wall in most windows it faces the backbone in,
    # else all its facing wall
    clear_plain, facing_plain = (sums(selected & plain, max(end_s, window))[0]
                                 for selected in (backbone_wall, away_from_cuts))
    clear_windows, facing_windows = (sums(selected, window) for selected in (backbone_wall, away_from_cuts))
    clear_seen = np.sum(faces_backbone & (clear_windows[:, :, 0] >= minimum_points), axis=0)
    clear = (2 * clear_seen >= np.sum(faces_backbone, axis=0)) & (clear_plain[:, 0] >= minimum_points)
    plain_sums = np.where(clear[:, None], clear_plain, facing_plain)
    per_window = np.where(clear[None, :, None], clear_windows, facing_windows)
    shifts = _window_shifts(faces_backbone, round_tube, plain_sums, per_window, window_frames, minimum_points)
    known = np.flatnonzero(np.any(shifts != 0.0, axis=1))
    if not len(known):
        return centerline, 0.0
    known_s = np.concatenate([[0.0], centres[known]])
    node_shift = np.stack([np.interp(centerline.s, known_s, np.concatenate([[0.0], shifts[known, axis]]))
                           for axis in range(3)], axis=1)
    step = float(centerline.s[1] - centerline.s[0])
    moved = Centerline.from_points(centerline.points + node_shift, centerline.binormals[0], step)
    return moved, float(np.sqrt(np.mean(np.einsum("ij,ij->i", shifts[known], shifts[known]))))


def _window_shifts(faces_backbone: np.ndarray, round_tube: np.ndarray, plain_sums: np.ndarray,
                   per_window: np.ndarray, window_frames: tuple, minimum_points: int) -> np.ndarray:
    """(W, 3) the move per window that brings the backbone's wall each camera facing it sees to the level it sees
    on the plain tube (0 where none does)."""
    _, _, window_normal, window_binormal = window_frames
    shifts = np.zeros((len(faces_backbone), 3))
    for k in np.flatnonzero(np.any(faces_backbone, axis=1)):
        system, rhs = np.zeros((2, 2)), np.zeros(2)
        for c in np.flatnonzero(faces_backbone[k]):
            if plain_sums[c, 0] < minimum_points or per_window[k, c, 0] < minimum_points:
                continue
            direction = round_tube[k, c] / np.linalg.norm(round_tube[k, c])
            # reading deeper than on the plain tube: the axis lies too near this camera, by the shift that
            # lowers each point's offset by shift x cos(its view angle) (least squares about the plain level)
            cosine, cosine2, cosine_offset = per_window[k, c, 5:]
            plain_level = plain_sums[c, 3] / plain_sums[c, 0]
            nearer = (plain_level * cosine - cosine_offset) / cosine2
            system += np.outer(direction, direction)
            rhs -= nearer * direction
        if np.any(system):
            move = np.linalg.pinv(system) @ rhs
            shifts[k] = move[0] * window_normal[k] + move[1] * window_binormal[k]
    return shifts
