"""A small depth renderer for the reconstruction's unit tests: a posed TubeShape seen by two opposed
pinhole cameras, splatted from a dense surface sample into a z-buffer, then blurred like a stereo matcher
(flattening), given depth noise growing with z^2 and quantised to the camera's depth unit.

It is deliberately independent of the simulator (ntcr_recon.sim), so the core is tested against depth
made by other means than the one its sample bags come from. `posed_scene` poses any robot: notches opening
obliquely between the cameras (notch_side_deg 30-60), or bent so that its distal part points at a camera
(notch side -90 deg faces cam_a, and a 90 deg bend turns the tip towards it).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter
from scipy.spatial.transform import Rotation

from ntcr_recon.core.base.transforms import invert_transform, matrix_to_quaternion, transform_points
from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import CameraFrame, FramePair
from ntcr_recon.core.config.rig import rig_config_from_mapping

INTRINSICS = Intrinsics(848, 480, 430.0, 430.0, 424.0, 240.0)
DEPTH_UNIT = 1e-4


def camera_poses(distance: float, height: float, yaw: float = 0.0,
                 tilts: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.0, 0.0))) -> dict[str, tuple[list, list]]:
    """Two cameras on the base frame's +-y axis (rotated by yaw about z), looking at each other; `tilts` turns
    each in place by (yaw, pitch) about its own image axes (radians), as a camera mounted a little off its
    nominal pose."""
    poses = {}
    turn = Rotation.from_euler("z", yaw).as_matrix()
    for name, side, (tilt_yaw, tilt_pitch) in zip(("cam_a", "cam_b"), (-1.0, 1.0), tilts, strict=True):
        z_axis = -turn @ np.array([0.0, side, 0.0])          # optical axis, towards the robot
        y_axis = np.array([0.0, 0.0, -1.0])                  # image down = against the robot's axis
        x_axis = np.cross(y_axis, z_axis)
        position = -z_axis * distance + np.array([0.0, 0.0, height])
        # intrinsic rotations: about the camera's own y (image down), then its x
        rotation = np.stack([x_axis, y_axis, z_axis], axis=1) @ Rotation.from_euler(
            "YX", [tilt_yaw, tilt_pitch]).as_matrix()
        poses[name] = (position.tolist(), matrix_to_quaternion(rotation).tolist())
    return poses


def rig_mapping(geometry_mapping: dict, distance: float = 0.09, height: float = 0.025, yaw: float = 0.0,
                tilts: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.0, 0.0)),
                intrinsics: Intrinsics = INTRINSICS) -> dict:
    mapping = {"base_frame": "ntcr_base", "camera_names": ["cam_a", "cam_b"], "robot": dict(geometry_mapping)}
    for name, (translation, rotation) in camera_poses(distance, height, yaw, tilts).items():
        mapping[name] = {"width": intrinsics.width, "height": intrinsics.height, "fps": 30, "depth_unit": DEPTH_UNIT,
                         "frame_id": f"{name}_optical_frame", "translation": translation, "rotation": rotation}
    return mapping


def post_surface(radius: float, height: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and outward normals of a post the robot's base stands on: a cylinder of `radius` about the base
    frame's z from -height up to the base plane, and its top disc."""
    angles = np.arange(0.0, 2 * np.pi, spacing / radius)
    heights = np.arange(-height, 0.0, spacing)
    angle, z = (grid.ravel() for grid in np.meshgrid(angles, heights))
    side = np.stack([radius * np.cos(angle), radius * np.sin(angle), z], axis=1)
    side_normals = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(z)], axis=1)
    across = np.arange(-radius, radius, spacing)
    x, y = (grid.ravel() for grid in np.meshgrid(across, across))
    top = np.stack([x, y, np.zeros_like(x)], axis=1)[x ** 2 + y ** 2 <= radius ** 2]
    return (np.concatenate([side, top]),
            np.concatenate([side_normals, np.tile([0.0, 0.0, 1.0], (len(top), 1))]))


def render_pair(shape, config, seed: int = 0, blur_px: int = 3, noise_at_90mm: float = 2e-5,
                spacing: float = 0.03e-3, stamp_ns: int = 0, backdrop: float | None = None,
                post_radius: float | None = None, intrinsics: Intrinsics = INTRINSICS) -> FramePair:
    """backdrop: depth (m) of a wall perpendicular to each camera's optical axis behind the robot, or none (the
    robot alone has depth). With a wall, the blur mixes its depth into the robot's edge pixels and the robot's
    into the wall's: each side of an edge spoils by about half the blur window. post_radius: a post of that
    radius under the robot's base (post_surface, 40 mm high), or none."""
    rng = np.random.default_rng(seed)
    sample = shape.sample_surface_parts(spacing)
    surface, surface_normals = sample.points, sample.normals
    if post_radius is not None:
        post, post_normals = post_surface(post_radius, 0.04, 2 * spacing)
        surface, surface_normals = np.concatenate([surface, post]), np.concatenate([surface_normals, post_normals])
    frames = {}
    for name in config.camera_names:
        pose = config.cameras[name].extrinsic
        to_camera = invert_transform(pose)
        points = transform_points(to_camera, surface)
        normals = surface_normals @ to_camera[:3, :3].T
        facing = np.einsum("ij,ij->i", normals, -points) > 0
        points = points[facing]
        z = points[:, 2]
        # z-buffer at 3x resolution, then each pixel keeps its centre sub-pixel: a ray through the pixel
        # centre, as a ray caster would (plain splatting would fatten every silhouette by half a pixel)
        fine = 3
        u = np.floor(fine * (intrinsics.fx * points[:, 0] / z + intrinsics.cx + 0.5)).astype(int)
        v = np.floor(fine * (intrinsics.fy * points[:, 1] / z + intrinsics.cy + 0.5)).astype(int)
        inside = (u >= 0) & (u < fine * intrinsics.width) & (v >= 0) & (v < fine * intrinsics.height)
        depth = np.full((fine * intrinsics.height, fine * intrinsics.width), np.inf)
        np.minimum.at(depth, (v[inside], u[inside]), z[inside])
        depth = depth[fine // 2::fine, fine // 2::fine]
        if backdrop is not None:
            depth = np.minimum(depth, backdrop)
        valid = np.isfinite(depth)
        depth[~valid] = 0.0
        if blur_px > 1:
            # stereo matching window: depth averaged over the window's valid pixels (flattens the tube);
            # a pixel whose window is mostly background is lost
            weight = uniform_filter(valid.astype(float), blur_px)
            blurred = uniform_filter(depth, blur_px) / np.maximum(weight, 1e-9)
            depth = np.where(valid & (weight > 0.6), blurred, 0.0)
        sigma = noise_at_90mm * (depth / 0.09) ** 2
        depth = np.where(depth > 0, depth + rng.normal(size=depth.shape) * sigma, 0.0)
        raw = np.round(depth / DEPTH_UNIT).astype(np.uint16)
        color = np.full((intrinsics.height, intrinsics.width, 3), 180, np.uint8)
        frames[name] = CameraFrame(name, stamp_ns, depth=raw, intrinsics=intrinsics, color=color)
    return FramePair(stamp_ns, frames)


def make_config(geometry_mapping: dict, **kwargs):
    return rig_config_from_mapping(rig_mapping(geometry_mapping, **kwargs))



def posed_scene(robot: dict, bend_deg: float, notch_side_deg: float, distance: float = 0.09, height: float = 0.025,
                seed: int = 0):
    """(config, shape, frame pair) of a robot (geometry fields) with its notches opening `notch_side_deg` from
    base +x (towards +y; cam_a sits at -y, cam_b at +y), bent by `bend_deg` shared evenly by its notches."""
    from ntcr_recon.core.robot.kinematics import TubeShape

    config = make_config({**robot, "notch_side": float(np.radians(notch_side_deg))}, distance=distance, height=height)
    shape = TubeShape.from_bend_angle(config.robot, np.radians(bend_deg))
    return config, shape, render_pair(shape, config, seed=seed)
