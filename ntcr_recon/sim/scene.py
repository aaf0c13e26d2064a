"""The synthetic rig's scene and its exact (artefact-free) rendering from a camera.

What a camera sees: the robot (its true surface, notches and all), the post its base is clamped on, the
table the post stands on, the opposite camera's body and a backdrop wall behind it. Depth is exact: the
post, table, backdrop and camera body are intersected analytically with each pixel's ray; the robot is a
z-buffer splat of a dense sample of its true surface, refined per pixel by intersecting the pixel's ray
with the tangent plane of the sample nearest that ray (so the result does not carry the sampling step;
test_sim_camera measures it against an analytic tube: well under a micrometre off the silhouette).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.core.robot.surface import PART_OUTER_WALL
from ntcr_recon.sim.camera import CameraPose, D405Intrinsics

INSIDE_NOTCH_SHADE = 0.55  # cut faces, notch floor and bore: in the tube's shadow (Scene._shade)

LABEL_NONE = 0
LABEL_ROBOT = 1
LABEL_POST = 2
LABEL_TABLE = 3
LABEL_BACKDROP = 4
LABEL_CAMERA_BODY = 5

# Colours (RGB) of what the cameras see; the robot is shaded from this base colour.
COLOR_ROBOT = np.array([170.0, 170.0, 176.0])  # stainless / nitinol grey
COLOR_POST = np.array([215.0, 120.0, 45.0])  # orange 3D-printed post
COLOR_TABLE = np.array([70.0, 110.0, 75.0])  # green cutting mat
COLOR_BACKDROP = np.array([45.0, 75.0, 140.0])  # blue backdrop wall
COLOR_CAMERA_BODY = np.array([38.0, 38.0, 42.0])  # the opposite D405's dark housing

# Radius of the disc each surface sample stands for, in sample spacings (>= 1/sqrt(2) covers the surface).
_SURFEL_RADIUS = 0.8


@dataclass(frozen=True)
class RigProps:
    """The static things around the robot (metres, base frame)."""

    post_radius: float = 4.0e-3  # the post is a vertical cylinder below the robot base
    post_height: float = 60.0e-3  # from the table up to the robot base
    backdrop_distance: float = 0.30  # wall perpendicular to each camera's view, this far from it
    camera_body: tuple[float, float, float] = (0.042, 0.042, 0.023)  # D405 housing: width, height, depth


@dataclass
class ExactFrame:
    """An artefact-free rendering: what a perfect depth camera would report."""

    depth: np.ndarray  # (H, W) float64 metres along the optical axis; inf where the ray hits nothing
    normal: np.ndarray  # (H, W, 3) unit surface normal in the optical frame, facing the camera
    label: np.ndarray  # (H, W) uint8 LABEL_*
    color: np.ndarray  # (H, W, 3) uint8 RGB, aligned with depth (the D405 colours from the same imager)
    robot_part: np.ndarray  # (H, W) uint8 PART_* of the robot's surface seen, 255 where not the robot
    robot_sample: np.ndarray | None = None  # (H, W) index into Scene.surface of the sample hit, -1 where not the robot


class Scene:
    """A posed robot in the rig, rendered exactly from any camera."""

    def __init__(self, shape: TubeShape, cameras: list[CameraPose], intrinsics: D405Intrinsics | None = None,
                 props: RigProps | None = None, surface_spacing: float = 0.05e-3) -> None:
        self.shape = shape
        self.cameras = list(cameras)
        self.intrinsics = intrinsics or D405Intrinsics()
        self.props = props or RigProps()
        self.surface_spacing = surface_spacing

    @cached_property
    def surface(self):
        return self.shape.sample_surface_parts(self.surface_spacing)

    def props_clearance(self) -> tuple[float, float]:
        """How far (m) the robot's surface stays from the post and the table: the least distance from its
        centreline, past the clamped base, to the post's solid cylinder or the table's plane, less the tube's
        outer radius (negative: it passes through them), and the arc length (m) where it comes nearest."""
        geometry = self.shape.geometry
        base = np.asarray(geometry.base_position, dtype=float)
        s = np.append(np.arange(geometry.outer_diameter, self.shape.length, geometry.outer_radius / 4),
                      self.shape.length)
        points = np.asarray(self.shape.centerline(s)[0]) - base
        table = -self.props.post_height
        across = np.hypot(points[:, 0], points[:, 1]) - self.props.post_radius
        above = np.maximum(points[:, 2], table - points[:, 2])  # > 0 outside the post's height
        inside = (across < 0) & (above < 0)
        to_post = np.where(inside, np.maximum(across, above),
                           np.hypot(np.maximum(across, 0.0), np.maximum(above, 0.0)))
        clearance = np.minimum(to_post, points[:, 2] - table) - geometry.outer_radius
        nearest = int(np.argmin(clearance))
        return float(clearance[nearest]), float(s[nearest])

    def camera(self, name: str) -> CameraPose:
        for camera in self.cameras:
            if camera.name == name:
                return camera
        raise KeyError(f"no camera named {name!r} (have {[c.name for c in self.cameras]})")

    # ----------------------------------------------------------------------------------------- render
    def render_exact(self, camera: CameraPose) -> ExactFrame:
        intr = self.intrinsics
        rays = intr.pixel_rays().reshape(-1, 3)
        count = rays.shape[0]
        depth = np.full(count, np.inf)
        normal = np.zeros((count, 3))
        label = np.zeros(count, dtype=np.uint8)
        self._cast_props(camera, rays, depth, normal, label)
        robot_depth, robot_normal, robot_part, robot_sample = self._splat_robot(camera, rays)
        nearer = robot_depth < depth
        depth[nearer] = robot_depth[nearer]
        normal[nearer] = robot_normal[nearer]
        label[nearer] = LABEL_ROBOT
        # normals face the camera (inner walls seen through a notch face it too)
        flip = np.einsum("ij,ij->i", normal, rays) > 0
        normal[flip] *= -1
        color = self._shade(rays, normal, label, robot_part)
        shape2 = (intr.height, intr.width)
        robot_part[~nearer] = 255
        robot_sample[~nearer] = -1
        return ExactFrame(depth.reshape(shape2), normal.reshape(*shape2, 3), label.reshape(shape2),
                          color.reshape(*shape2, 3), robot_part.reshape(shape2), robot_sample.reshape(shape2))

    def _rays_towards(self, camera: CameraPose, corners_base: np.ndarray):
        """Flat indices of the pixels whose rays can meet a convex body with these corners (all, if the
        body reaches behind the camera)."""
        intr = self.intrinsics
        corners = camera.to_camera(corners_base)
        if np.any(corners[:, 2] <= 1e-6):
            return slice(None)
        u = intr.fx * corners[:, 0] / corners[:, 2] + intr.cx
        v = intr.fy * corners[:, 1] / corners[:, 2] + intr.cy
        columns = np.arange(max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())) + 1, intr.width))
        rows = np.arange(max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())) + 1, intr.height))
        return (rows[:, None] * intr.width + columns[None, :]).ravel()

    def _cast_props(self, camera: CameraPose, rays_cam, depth, normal, label) -> None:
        """Analytic ray casting of the post, table, backdrop and the other cameras' bodies."""
        origin = camera.translation
        all_directions = rays_cam @ camera.rotation.T  # base frame, scaled so that t = depth along the optical axis
        props = self.props
        base = np.asarray(self.shape.geometry.base_position, dtype=float)
        ez = np.array([0.0, 0.0, 1.0])
        table_z = base[2] - props.post_height

        def keep(index, t, n_base, which):
            pixels = np.arange(len(depth))[index]
            closer = np.isfinite(t) & (t > 0) & (t < depth[pixels])
            depth[pixels[closer]] = t[closer]
            normal[pixels[closer]] = (n_base[closer] if n_base.ndim == 2 else n_base) @ camera.rotation
            label[pixels[closer]] = which

        with np.errstate(divide="ignore", invalid="ignore"):
            # backdrop wall behind the robot, perpendicular to this camera's optical axis
            keep(slice(None), np.full(len(depth), props.backdrop_distance), np.array([0.0, 0.0, -1.0])
                 @ camera.rotation.T, LABEL_BACKDROP)
            # table: plane z = base_z - post_height
            keep(slice(None), (table_z - origin[2]) / all_directions[:, 2], ez, LABEL_TABLE)
            # post: vertical cylinder under the base, and its top disc
            corners = base + np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (0, 1)]) * [
                props.post_radius, props.post_radius, -props.post_height]
            index = self._rays_towards(camera, corners)
            directions = all_directions[index]
            rel = origin[:2] - base[:2]
            a = directions[:, 0] ** 2 + directions[:, 1] ** 2
            b = directions[:, :2] @ rel
            c = rel @ rel - props.post_radius**2
            t_side = (-b - np.sqrt(b * b - a * c)) / a
            hit_z = origin[2] + t_side * directions[:, 2]
            t_side[(hit_z < table_z) | (hit_z > base[2])] = np.nan
            side_normal = np.column_stack([(origin[:2] + t_side[:, None] * directions[:, :2]) - base[:2],
                                           np.zeros(len(t_side))]) / props.post_radius
            keep(index, t_side, side_normal, LABEL_POST)
            t_top = (base[2] - origin[2]) / directions[:, 2]
            top_xy = origin[:2] + t_top[:, None] * directions[:, :2] - base[:2]
            t_top[np.einsum("ij,ij->i", top_xy, top_xy) > props.post_radius**2] = np.nan
            keep(index, t_top, ez, LABEL_POST)
            # the other cameras' housings: boxes behind their optical centres
            low = np.array([-props.camera_body[0] / 2, -props.camera_body[1] / 2, -props.camera_body[2]])
            high = np.array([props.camera_body[0] / 2, props.camera_body[1] / 2, 0.0])
            box_corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1])
                                    for z in (low[2], high[2])])
            for other in self.cameras:
                if other.name == camera.name:
                    continue
                index = self._rays_towards(camera, other.to_base(box_corners))
                o_local = other.rotation.T @ (origin - other.translation)
                d_local = all_directions[index] @ other.rotation
                t1 = (low - o_local) / d_local
                t2 = (high - o_local) / d_local
                t_near = np.nanmax(np.minimum(t1, t2), axis=1)
                t_far = np.nanmin(np.maximum(t1, t2), axis=1)
                hit = t_near <= t_far
                axis = np.argmax(np.minimum(t1, t2), axis=1)
                rows = np.arange(len(axis))
                box_normal = np.zeros((len(axis), 3))
                box_normal[rows, axis] = -np.sign(d_local[rows, axis])
                keep(index, np.where(hit, t_near, np.nan), box_normal @ other.rotation.T, LABEL_CAMERA_BODY)

    def _splat_robot(self, camera: CameraPose, rays_cam):
        """Per pixel: exact depth of the robot (inf: missed), its normal (optical frame), surface part and the
        index of the surface sample hit (-1: missed)."""
        intr = self.intrinsics
        count = rays_cam.shape[0]
        surface = self.surface
        points = camera.to_camera(surface.points)
        normals = surface.normals @ camera.rotation
        z = points[:, 2]
        in_front = z > 1e-3
        u = np.full_like(z, -1.0)
        v = np.full_like(z, -1.0)
        u[in_front] = points[in_front, 0] / z[in_front] * intr.fx + intr.cx
        v[in_front] = points[in_front, 1] / z[in_front] * intr.fy + intr.cy
        column, row = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
        inside = in_front & (column >= 0) & (column < intr.width) & (row >= 0) & (row < intr.height)
        candidates = np.flatnonzero(inside)
        pixel = row[candidates] * intr.width + column[candidates]
        # Ray casting against surfels: each sample stands for a disc of radius _SURFEL_RADIUS spacings in
        # its tangent plane (any surface point is within spacing / sqrt(2) of a sample of a grid of step
        # `spacing`, so the discs cover the surface). A pixel's depth is its ray's nearest disc hit.
        ray = rays_cam[pixel]
        q = points[candidates]
        ray_norm = np.linalg.norm(ray, axis=1)
        along = np.einsum("ij,ij->i", q, ray) / ray_norm
        off_ray = np.sqrt(np.maximum(np.einsum("ij,ij->i", q, q) - along**2, 0.0))
        radius = _SURFEL_RADIUS * self.surface_spacing
        near = off_ray <= radius
        candidates, pixel, ray, q = candidates[near], pixel[near], ray[near], q[near]
        n = normals[candidates]
        with np.errstate(divide="ignore", invalid="ignore"):
            z_plane = np.einsum("ij,ij->i", n, q) / np.einsum("ij,ij->i", n, ray)
            hit_offset = np.linalg.norm(z_plane[:, None] * ray - q, axis=1)
        hits = np.isfinite(z_plane) & (z_plane > 0) & (hit_offset <= radius)
        candidates, pixel, z_plane = candidates[hits], pixel[hits], z_plane[hits]
        order = np.lexsort((z_plane, pixel))
        first = order[np.r_[True, pixel[order][1:] != pixel[order][:-1]]] if order.size else order
        best, pix, hit_depth = candidates[first], pixel[first], z_plane[first]
        n = normals[best]
        depth = np.full(count, np.inf)
        normal = np.zeros((count, 3))
        part = np.full(count, 255, dtype=np.uint8)
        depth[pix] = hit_depth
        normal[pix] = n
        part[pix] = surface.part[best]
        sample = np.full(count, -1, dtype=np.int64)
        sample[pix] = best
        return depth, normal, part, sample

    def _shade(self, rays_cam, normal, label, robot_part) -> np.ndarray:
        """Colour under a light near the camera: Lambert + a metallic highlight on the robot."""
        view = rays_cam / np.linalg.norm(rays_cam, axis=1, keepdims=True)
        facing = np.abs(np.einsum("ij,ij->i", normal, view))
        color = np.zeros((len(label), 3))
        props = ((LABEL_POST, COLOR_POST, 0.45), (LABEL_TABLE, COLOR_TABLE, 0.6),
                 (LABEL_BACKDROP, COLOR_BACKDROP, 0.8), (LABEL_CAMERA_BODY, COLOR_CAMERA_BODY, 0.6))
        for which, base, ambient in props:
            mask = label == which
            color[mask] = base * (ambient + (1 - ambient) * facing[mask, None])
        robot = label == LABEL_ROBOT
        # surfaces inside a notch (cut faces, floor, bore) are in the tube's shadow
        inside_cut = robot & (robot_part != PART_OUTER_WALL)
        lambert = 0.3 + 0.7 * facing[robot, None]
        color[robot] = COLOR_ROBOT * lambert * np.where(inside_cut[robot], INSIDE_NOTCH_SHADE, 1.0)[:, None]
        color[robot] += 70.0 * facing[robot, None] ** 40
        return np.clip(np.rint(color), 0, 255).astype(np.uint8)
