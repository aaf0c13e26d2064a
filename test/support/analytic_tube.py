"""A straight or bent NTCR drawn analytically for the relocation's step tests (test/core): its true and displaced
centrelines, points on its wall, cameras round it. No renderer, so every figure is known exactly."""

from __future__ import annotations

import math

import numpy as np

from ntcr_recon.core.relocation.centerline import Centerline
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape

GEOMETRY = TubeGeometry()   # 3.5 mm, 16 notches, straight along base +z, notches towards +x
FOOTPRINT = 0.2e-3          # a D405 pixel at 90 mm
R_O = GEOMETRY.outer_radius


def straight_centerline(length: float) -> Centerline:
    s = np.linspace(0.0, length, int(length / 0.1e-3) + 1)
    points = np.stack([np.zeros_like(s), np.zeros_like(s), s], axis=1)
    return Centerline.from_points(points, np.array([0.0, 1.0, 0.0]), 0.1e-3)


def wall_points(length: float, spacing: float = FOOTPRINT, angles=(-math.pi, math.pi), radius: float = R_O,
                start: float = 0.0, rng=None) -> np.ndarray:
    """Points on a straight cylinder about base z, angle measured from +x (the notch side)."""
    s = np.arange(start, length, spacing)
    phi = np.arange(angles[0], angles[1], spacing / radius)
    ss, pp = (a.ravel() for a in np.meshgrid(s, phi, indexing="ij"))
    points = np.stack([radius * np.cos(pp), radius * np.sin(pp), ss], axis=1)
    if rng is not None:
        points += rng.normal(0.0, 0.01e-3, points.shape)
    return points


def true_centerline(shape: TubeShape, samples: int = 2000) -> Centerline:
    s = np.linspace(0.0, shape.length, samples)
    points, frames = shape.centerline(s)
    return Centerline.from_frames(s, points, frames)


def displaced_centerline(shape: TubeShape, towards_notches) -> Centerline:
    """The shape's centreline with each sample moved towards the notch side by towards_notches(s) (m): a fitted
    curve's local error, on a known robot."""
    s = np.linspace(0.0, shape.length, 4000)
    points, frames = shape.centerline(s)
    return Centerline.from_points(points + towards_notches(s)[:, None] * frames[:, :, 0], frames[0, :, 1], 0.1e-3)


def opposed_cameras_on_a_straight_tube(length: float = 30e-3):
    """A straight tube's wall (8 notches' geometry, none cut) seen by opposed cameras at -y and +y, each point by the
    one on its side: (geometry, points, camera index, viewpoints per point, centreline)."""
    geometry = TubeGeometry(notch_count=8, notch_pitch=3e-3)
    points = wall_points(length, rng=np.random.default_rng(4))
    camera = (points[:, 1] > 0).astype(np.intp)
    viewpoints = np.array([[0.0, -0.09, 0.015], [0.0, 0.09, 0.015]])[camera]
    return geometry, points, camera, viewpoints, straight_centerline(length)


def cameras_round_the_tube(angles_deg, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cameras 90 mm from a straight tube along z, at these angles round it from the notch side (+x), each point
    seen by the one it faces most: (angles in rad, the cameras' origins (C, 3), each point's camera index)."""
    angles = np.radians(angles_deg)
    origins = np.stack([0.09 * np.cos(angles), 0.09 * np.sin(angles), np.full(len(angles), 0.025)], axis=1)
    camera = (np.einsum("ij,cj->ic", points[:, :2], origins[:, :2]).argmax(axis=1)).astype(np.intp)
    return angles, origins, camera


def beyond_slot_edge(points: np.ndarray, camera_angle) -> np.ndarray:
    """Across the view of a camera at `camera_angle` round the straight tube (rad from the notch side; one, or one per
    point), from the slots' edge on its side to each wall point (m; +: towards the backbone): what
    alignment.clear_of_slots_in_view measures, written out here on the known geometry."""
    phi = np.arctan2(points[:, 1], points[:, 0])
    side = np.sign(camera_angle)
    return side * R_O * (np.sin(phi - camera_angle) - np.sin(side * GEOMETRY.gap_half_angle - camera_angle))
