"""Two opposed cameras 90 mm from the robot, as the simulator places them, and exact points of the tube's wall each
sees: calibration recordings with a known truth (test/core/calibration)."""

import numpy as np

from ntcr_recon.core.base.transforms import invert_transform, rigid_transform, transform_points
from ntcr_recon.core.calibration.rig_fit import Recording
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.core.robot.surface import PART_OUTER_WALL

GEOMETRY = TubeGeometry()
# Two opposed cameras 90 mm from the robot, as the simulator places them (looking along +y and -y).
TRUE_POSES = {"cam_a": rigid_transform([0.01, -0.09, 0.022], [-0.5, -0.5, -0.5, 0.5]),
              "cam_b": rigid_transform([0.01, 0.09, 0.022], [0.5, -0.5, 0.5, 0.5])}


def seen_wall(shape: TubeShape, camera: str, rng, count=3000, noise=10e-6) -> np.ndarray:
    """The outer wall facing the camera (optical frame), with depth noise along each pixel's ray."""
    sample = shape.sample_surface_parts(0.1e-3)
    wall = sample.part == PART_OUTER_WALL
    points, normals = sample.points[wall], sample.normals[wall]
    origin = TRUE_POSES[camera][:3, 3]
    facing = np.einsum("ij,ij->i", normals, points - origin) < 0
    optical = transform_points(invert_transform(TRUE_POSES[camera]), points[facing])
    optical = optical[rng.choice(len(optical), min(count, len(optical)), replace=False)]
    return optical * (1 + rng.normal(0, noise, len(optical)) / optical[:, 2])[:, None]


def recording(name, bends, rng, straight=False) -> Recording:
    shape = TubeShape(GEOMETRY, bends)
    points = {camera: seen_wall(shape, camera, rng) for camera in TRUE_POSES}
    return Recording(name, points, {camera: len(p) for camera, p in points.items()}, straight)
