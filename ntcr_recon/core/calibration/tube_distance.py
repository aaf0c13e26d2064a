"""How far points lie from a posed robot's tube, and how that distance moves with the robot's notch bends.

The calibration (core.calibration.rig_fit) fits both cameras' poses and the robot's bends to what the cameras
see of the tube. Its model is the plain tube of the robot's outer radius about the kinematic centreline
(core.robot.kinematics.TubeShape), closed by the end cap at the tip: the notches are left out, and what a camera
sees of their cut faces and floors lies inside that tube, where the fit's robust loss discounts it.

Signed distance: positive outside the tube, negative inside (the nearer of the wall and the end cap). Its
gradient with respect to a point is the unit vector `direction`; moving the tube's centreline by dC at a point's
foot (its nearest centreline arc length) changes the distance by -direction . dC, which is how the fit takes the
bends' Jacobian from the centreline alone (a tube turning about its own axis does not change a wall distance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ntcr_recon.core.robot.kinematics import TubeShape

# Centreline samples this far apart (m) find each point's foot; a projection on the local tangent refines it.
SAMPLE_STEP = 1.0e-4


@dataclass(frozen=True)
class TubeDistance:
    """Per point: its signed distance to the tube (m), its gradient (N, 3, unit) and its foot's arc length (m)."""

    distance: np.ndarray
    direction: np.ndarray
    foot_s: np.ndarray
    below_base: np.ndarray      # points past the base plane (the clamp, the post): not the robot


def tube_distance(shape: TubeShape, points: np.ndarray, viewpoint: np.ndarray | None = None) -> TubeDistance:
    """The signed distance of each point (N, 3, base frame) to the shape's tube of outer radius and end cap.

    viewpoint: the camera's origin (base frame). A camera sees only the half of the wall that faces it, so a point
    placed on the far half (behind the plane of the limbs, as seen from there) is as far off as it lies behind that
    plane too: a camera's half-tube may not settle on the tube's far side, mirrored, a tube's width too far.
    """
    length, radius = shape.length, shape.geometry.outer_radius
    s_samples = np.linspace(0.0, length, max(int(np.ceil(length / SAMPLE_STEP)), 1) + 1)
    centres, frames = shape.centerline(s_samples)
    _, nearest = cKDTree(centres).query(points, workers=-1)
    tangents = frames[nearest, :, 2]
    foot_s = np.clip(s_samples[nearest] + np.einsum("ij,ij->i", points - centres[nearest], tangents), 0.0, length)
    foot, foot_frames = shape.centerline(foot_s)
    tangents = foot_frames[:, :, 2]
    offset = points - foot
    axial = np.einsum("ij,ij->i", offset, tangents)
    radial_vector = offset - axial[:, None] * tangents
    radial = np.linalg.norm(radial_vector, axis=1)
    outward = np.divide(radial_vector, radial[:, None], out=np.zeros_like(radial_vector), where=radial[:, None] > 0)
    wall = radial - radius
    distance, direction = wall, outward
    if viewpoint is not None:
        sight = points - viewpoint
        sight -= np.einsum("ij,ij->i", sight, tangents)[:, None] * tangents
        sight /= np.maximum(np.linalg.norm(sight, axis=1), 1e-12)[:, None]
        behind = np.maximum(np.einsum("ij,ij->i", radial_vector, sight), 0.0)
        far_half = behind > 0
        combined = np.hypot(wall, behind)
        distance = np.where(far_half, np.copysign(combined, wall), wall)
        gradient = (wall[:, None] * outward + behind[:, None] * sight) / np.maximum(combined, 1e-12)[:, None]
        direction = np.where(far_half[:, None], np.copysign(1.0, wall)[:, None] * gradient, outward)
    # Beyond the tip (the foot held at its end): the end cap, a disc across the tube, is the nearer surface.
    tip, tip_frame = shape.tip_pose()
    cap = (points - tip) @ tip_frame[:, 2]
    past_tip = foot_s >= length
    near_tip = foot_s >= length - 2 * radius  # the cap's plane, extended, means nothing further back
    on_cap = past_tip & (cap > 0) & (wall <= 0) | near_tip & (cap <= 0) & (wall < 0) & (cap > wall)
    corner = past_tip & (cap > 0) & (wall > 0)
    distance = np.where(on_cap, cap, distance)
    direction = np.where(on_cap[:, None], tip_frame[:, 2], direction)
    corner_distance = np.hypot(cap, wall)
    distance = np.where(corner, corner_distance, distance)
    corner_direction = (cap[:, None] * tip_frame[:, 2] + wall[:, None] * outward) / np.maximum(
        corner_distance, 1e-12)[:, None]
    direction = np.where(corner[:, None], corner_direction, direction)
    below_base = (foot_s <= 0.0) & (axial < 0.0)
    return TubeDistance(distance, direction, foot_s, below_base)


def bend_jacobian(shape: TubeShape, foot_s: np.ndarray, direction: np.ndarray, changes: np.ndarray,
                  step: float = 1.0e-4) -> np.ndarray:
    """d distance / d bend parameter (N, M) for points with these feet and distance gradients, each parameter
    changing the notches' bends by a row of `changes` (M, notch_count) per radian: the centreline's move at each
    foot under a small such change (finite differences, towards where the notches can still bend), against the
    gradient."""
    bends = shape.notch_bend
    base = shape.centerline_points(foot_s)
    columns = np.empty((len(foot_s), len(changes)))
    upper = shape.geometry.max_notch_bend
    for column, change in enumerate(changes):
        delta = step if np.all(bends + step * change <= upper) and np.all(bends + step * change >= 0) else -step
        moved = TubeShape(shape.geometry, np.clip(bends + delta * change, 0.0, upper))
        centre = moved.centerline_points(np.minimum(foot_s, moved.length))
        columns[:, column] = -np.einsum("ij,ij->i", direction, centre - base) / delta
    return columns
