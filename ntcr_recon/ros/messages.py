"""Core results <-> ROS messages for the stage nodes (rclpy messages; no algorithm here).

Stage clouds (`<ns>/fused/points`, `<ns>/filtered/points`, `<ns>/relocated/points`) are PointCloud2 with
x, y, z, rgb float32, plus the fields a later stage needs to compute what the offline command computes on
the same frames, all float32 and declared once in `io.pointcloud.STAGE_FIELDS`:
  `camera`            index in the rig's camera_names of the camera that saw the point
  `pixel_footprint`   metres, the size of one depth pixel on the robot (same for every point; 0 = unknown)
  `pixel_u`, `pixel_v` the point's pixel in its camera image (the filters find neighbours in the image by
                      it); absent when the camera's cloud had no pixel layout
  `normal_x/y/z`      relocated cloud only: the reference surface's outward normal (the mesh is oriented by it)
  `part`, `tube_s`, `tube_x`, `tube_y`   relocated cloud only: the robot surface each point lies on
                      (core.robot.surface.PART_*) and its tube coordinates (arc length, offset towards the notch side,
                      offset along the binormal): with the centreline Path, what the mesh stage needs
Readers that know only x, y, z (and rgb) are unaffected.

camera_node's clouds (`<ns>/<cam>/depth/color/points`) are unorganised (only the valid points: a crop window
organised would be megabytes a frame) with x, y, z, rgb and `pixel_u`, `pixel_v`; an organised cloud (e.g.
from realsense-ros with ordered_pc) carries its pixels in its layout.

The relocation's results (centreline Path, tip pose, notches, their markers, meshes): ros/result_messages.py.
"""

from __future__ import annotations

import math

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Path
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from ntcr_recon.core.base.transforms import quaternion_to_matrix
from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import CameraFrame
from ntcr_recon.core.cloud.points import Cloud, finite_rows
from ntcr_recon.io.pointcloud import (
    STAGE_FIELDS,
    MessageTypes,
    cloud_from_msg,
    cloud_to_msg,
    read_points,
    stamp_to_ns,
)
from ntcr_recon.ros import cdr

# the rclpy flavour of PointCloud2 writing (io.pointcloud.cloud_to_msg / create_cloud)
RCLPY = MessageTypes(PointCloud2, PointField, Header, Time, lambda data: data.tobytes())
_NORMAL_FIELDS = ("normal_x", "normal_y", "normal_z")
# Largest cloud a node reads by default: two D405 depth frames at 848x480, every pixel a point.
DEFAULT_MAX_POINTS = 2 * 848 * 480


class RefusedInputError(ValueError):
    """An input dropped before it is used; `reason` is the count it goes under (oversized, inconsistent, ...)."""

    def __init__(self, message: str, reason: str = "invalid") -> None:
        super().__init__(message)
        self.reason = reason


def check_point_count(cloud: PointCloud2 | bytes, max_points: int) -> None:
    """Refuse a cloud of more than `max_points` points from its header alone, before a byte of it is read: a
    PointCloud2, or one still serialized (a raw subscription's bytes, whose decoding by rclpy took 75-150 MB for a
    5-million-point cloud, which the process kept: issue 66). Bytes that hold no PointCloud2 header pass: decoding
    them refuses them by their fault."""
    if isinstance(cloud, bytes):
        try:
            height, width = cdr.cloud_size(cloud)
        except ValueError:
            return
    else:
        height, width = int(cloud.height), int(cloud.width)
    if height * width > max_points:
        raise RefusedInputError(f"cloud of {width}x{height} = {width * height} points exceeds max_points "
                                f"{max_points}", "oversized")


def decode(raw: bytes, kind, what: str):
    """A serialized message of type `kind` decoded, or a RefusedInputError naming it as `what` (rclpy raises its
    own errors for broken bytes)."""
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(raw, kind)
    except Exception as error:
        raise RefusedInputError(f"{what} cannot be decoded: {type(error).__name__}: {error}", "invalid") from error


def decode_cloud(raw: bytes, max_points: int) -> PointCloud2:
    """A stage's serialized input cloud: refused when oversized before it is decoded (check_point_count), then
    decoded."""
    check_point_count(raw, max_points)
    return decode(raw, PointCloud2, "cloud")


def check_pixels(pixel: np.ndarray, width: int, height: int, what: str) -> None:
    """Refuse pixel_u/pixel_v outside a width x height image (the grid they are laid out on is sized by them)."""
    if not len(pixel):
        return
    low, high = pixel.min(axis=0), pixel.max(axis=0)
    if low.min() < 0 or high[0] >= width or high[1] >= height:
        raise RefusedInputError(f"pixel_u/pixel_v span [{low[0]}, {high[0]}] x [{low[1]}, {high[1]}], outside the "
                             f"{width}x{height} image of {what}", "inconsistent")


# Bounds of a camera's intrinsics: beyond them the crop window's arithmetic overflows or spans absurd sizes.
MAX_FOCAL_PX = 1e5
CENTRE_MARGIN_IMAGES = 2  # how many image sizes the principal point may lie outside the image


def checked_intrinsics(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> Intrinsics:
    """Intrinsics, or a RefusedInputError naming the value that cannot be a camera's (a non-finite, non-positive
    or above MAX_FOCAL_PX focal length, a centre not finite or more than CENTRE_MARGIN_IMAGES image sizes off
    the image, an empty or absurd image size)."""
    if not (0 < int(width) <= 100_000 and 0 < int(height) <= 100_000):
        raise RefusedInputError(f"image size {width}x{height} is not a camera's", "inconsistent")
    values = {"fx": float(fx), "fy": float(fy), "cx": float(cx), "cy": float(cy)}
    for name, value in values.items():
        if not math.isfinite(value) or (name in ("fx", "fy") and value <= 0):
            raise RefusedInputError(f"{name} is {value}: a camera's {name} must be a finite"
                                    f"{' positive' if name in ('fx', 'fy') else ''} number", "inconsistent")
    for name in ("fx", "fy"):
        if values[name] > MAX_FOCAL_PX:
            raise RefusedInputError(f"{name} is {values[name]}: a camera's focal length is at most {MAX_FOCAL_PX:g} px",
                                    "inconsistent")
    for name, size in (("cx", int(width)), ("cy", int(height))):
        low, high = -CENTRE_MARGIN_IMAGES * size, (CENTRE_MARGIN_IMAGES + 1) * size
        if not low <= values[name] <= high:
            raise RefusedInputError(f"{name} is {values[name]}: a camera's principal point lies within "
                                    f"[{low}, {high}] px for an image of {width}x{height}", "inconsistent")
    return Intrinsics(int(width), int(height), values["fx"], values["fy"], values["cx"], values["cy"])


def intrinsics_from_camera_info(msg) -> Intrinsics:
    """The Intrinsics of a CameraInfo (K row-major), checked as `checked_intrinsics` does."""
    k = np.asarray(msg.k, dtype=float).reshape(-1)
    if k.size != 9:
        raise RefusedInputError(f"K must have 9 entries, got {k.size}", "inconsistent")
    return checked_intrinsics(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5])


def stamp_msg(stamp_ns: int) -> Time:
    seconds, nanoseconds = divmod(int(stamp_ns), 1_000_000_000)
    return Time(sec=seconds, nanosec=nanoseconds)


def header(frame_id: str, stamp_ns: int) -> Header:
    return Header(frame_id=frame_id, stamp=stamp_msg(stamp_ns))


# ---- stage clouds ---------------------------------------------------------------------------------------------

def stage_cloud_to_msg(cloud: Cloud, frame_id: str, normals: np.ndarray | None = None,
                       extra: dict[str, np.ndarray] | None = None) -> PointCloud2:
    """A Cloud as a PointCloud2: x, y, z, rgb, `camera`, `pixel_footprint`, `pixel_u`/`pixel_v` when the cloud
    has pixels, `normal_x`/`normal_y`/`normal_z` when normals are given, then `extra` stage fields."""
    columns = {"camera": cloud.camera if cloud.camera is not None else -1, "pixel_footprint": cloud.pixel_footprint}
    if cloud.pixel is not None:
        columns.update(pixel_u=cloud.pixel[:, 0], pixel_v=cloud.pixel[:, 1])
    if normals is not None:
        columns.update(zip(_NORMAL_FIELDS, np.asarray(normals).T, strict=True))
    columns.update(extra or {})
    rgb = cloud.rgb if cloud.rgb is not None else np.zeros(len(cloud), np.uint32)
    return cloud_to_msg(cloud.xyz, rgb, frame_id=frame_id, stamp_ns=cloud.stamp_ns, msgtypes=RCLPY,
                        columns=columns)


def relocation_cloud_msg(relocation, frame_id: str) -> PointCloud2:
    """The relocated cloud of a core.reconstruction.relocate.RelocationResult with its normals, the surface `part`
    of each point and its tube coordinates `tube_s`, `tube_x`, `tube_y` (what the mesh stage needs besides the
    centreline)."""
    extra = {}
    if relocation.part is not None:
        extra["part"] = relocation.part
    coordinates = relocation.relocated_coordinates
    if coordinates is not None:
        extra.update(tube_s=coordinates.s, tube_x=coordinates.x, tube_y=coordinates.y)
    return stage_cloud_to_msg(relocation.relocated, frame_id, relocation.normals, extra)


def relocation_from_msgs(cloud_msg: PointCloud2, path: Path, expected_frame: str, rig=None):
    """A core RelocationResult rebuilt from relocation_node's cloud (`relocation_cloud_msg`) and centreline Path of
    the same stamp: what the core's mesher reads (centreline, relocated cloud, normals, parts, tube
    coordinates). Notches and rejected counts are not carried (0 / empty)."""
    from ntcr_recon.core.reconstruction.relocate import RelocationResult
    from ntcr_recon.core.relocation.centerline import Centerline, TubeCoordinates

    require_frame(path, expected_frame)
    cloud, columns = _stage_cloud(cloud_msg, expected_frame, rig)
    normals = _normals(columns)
    if normals is None:
        raise ValueError("relocated cloud has no normal_x/normal_y/normal_z fields (is it relocation_node's?)")
    if len(path.poses) < 2:
        raise ValueError(f"centreline has {len(path.poses)} poses, needs at least 2")
    part = columns["part"].astype(np.int8) if "part" in columns else None
    coordinates = None
    if all(name in columns for name in ("tube_s", "tube_x", "tube_y")):
        coordinates = TubeCoordinates(*(columns[name].astype(float) for name in ("tube_s", "tube_x", "tube_y")))
    points = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path.poses])
    quaternions = np.array([[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                             p.pose.orientation.w] for p in path.poses])
    rotations = np.stack([quaternion_to_matrix(q) for q in quaternions])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    centerline = Centerline.from_frames(s, points, rotations)
    return RelocationResult(centerline, points[-1], [], cloud, normals, 0, coordinates, 0, part, coordinates)


def camera_cloud_to_msg(xyz: np.ndarray, rgb: np.ndarray | None, pixel: np.ndarray, frame_id: str,
                        stamp_ns: int) -> PointCloud2:
    """A camera's deprojected points (optical frame) with their pixel (u, v) as `pixel_u`, `pixel_v`."""
    rgb = rgb if rgb is not None else np.zeros(len(xyz), np.uint32)
    return cloud_to_msg(xyz, rgb, frame_id=frame_id, stamp_ns=stamp_ns, msgtypes=RCLPY,
                        columns={"pixel_u": pixel[:, 0], "pixel_v": pixel[:, 1]})


def camera_cloud_from_msg(msg: PointCloud2, expected_frame: str
                          ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, int]:
    """A camera cloud, compact: (points, colours, pixels (N, 2) or None, organised width).

    An organised cloud comes back whole (NaN = no return) with its width; an unorganised one as its finite
    points with their `pixel_u`/`pixel_v` when it carries them (width 0). An empty cloud is a camera that saw
    nothing in its crop box (camera_node publishes only the points inside it): a frame with no points, not an
    error. `camera_frame` makes the core's CameraFrame of it; kept apart so that a frame waiting for its
    partner costs its points, not a grid.
    """
    xyz, rgb = input_cloud(msg, expected_frame, keep_nan=True, allow_empty=True)
    if msg.height > 1:
        return xyz, rgb, None, int(msg.width)
    pixels = read_points(msg, ("pixel_u", "pixel_v"))
    finite = finite_rows(xyz)
    xyz, rgb = xyz[finite], None if rgb is None else rgb[finite]
    if len(pixels.dtype.names) < 2:
        return xyz, rgb, None, 0
    u, v = pixels["pixel_u"][finite], pixels["pixel_v"][finite]
    if not (np.isfinite(u).all() and np.isfinite(v).all()):
        return xyz, rgb, None, 0
    return xyz, rgb, np.stack([u, v], axis=1).astype(np.int64), 0


def camera_frame(camera: str, stamp_ns: int, xyz: np.ndarray, rgb: np.ndarray | None, pixel: np.ndarray | None,
                 organised_width: int, intrinsics: Intrinsics | None = None) -> CameraFrame:
    """The core's CameraFrame of a camera cloud (`camera_cloud_from_msg`): points with pixels are laid out
    row-major on the grid of the pixels they span (NaN where none), which the core reads as an organised
    cloud; others go as they are."""
    if pixel is None or not len(xyz):
        # an empty cloud with pixels is an empty grid (width 1): the fused cloud keeps the other camera's pixels
        width = 1 if pixel is not None else organised_width
        return CameraFrame(camera, stamp_ns, points=xyz, rgb=rgb, organised_width=width, intrinsics=intrinsics)
    u, v = pixel[:, 0] - pixel[:, 0].min(), pixel[:, 1] - pixel[:, 1].min()
    width, height = int(u.max() + 1), int(v.max() + 1)
    cell = v * width + u
    grid = np.full((height * width, 3), np.nan, dtype=np.float32)
    grid[cell] = xyz
    colors = None
    if rgb is not None:
        colors = np.zeros(height * width, dtype=np.uint32)
        colors[cell] = rgb
    return CameraFrame(camera, stamp_ns, points=grid, rgb=colors, organised_width=width, intrinsics=intrinsics)


def input_cloud(msg: PointCloud2, expected_frame: str, keep_nan: bool = False, allow_empty: bool = False
                ) -> tuple[np.ndarray, np.ndarray | None]:
    """The points (and colours) of an input cloud, NaN points dropped unless `keep_nan` (an organised cloud
    keeps its grid); ValueError naming the defect for a cloud in another frame than the configuration's, with
    broken layout, or without a single finite point (a cloud of 0 points passes with `allow_empty`)."""
    require_frame(msg, expected_frame)
    xyz, rgb = cloud_from_msg(msg, drop_nan=False)  # validates the layout and names what is wrong
    if not len(xyz):
        if allow_empty:
            return xyz, rgb
        raise ValueError("empty cloud (0 points)")
    finite = finite_rows(xyz)
    if not finite.any():
        raise ValueError(f"cloud has no finite point ({len(xyz)} points, all NaN or infinite)")
    if keep_nan or finite.all():
        return xyz, rgb
    return xyz[finite], None if rgb is None else rgb[finite]


def stage_cloud_from_msg(msg: PointCloud2, expected_frame: str, rig=None) -> Cloud:
    """A stage cloud back as a Cloud (checked as `input_cloud` does; NaN points dropped). Any PointCloud2 with
    x, y, z is accepted: a cloud without the extra fields gets no camera / pixels and footprint 0. A node
    passes its `rig` (RigConfig) so that camera indices and pixels are bounded by it (`_stage_cloud`)."""
    return _stage_cloud(msg, expected_frame, rig)[0]


def stage_cloud_and_normals(msg: PointCloud2, expected_frame: str, rig=None) -> tuple[Cloud, np.ndarray | None]:
    """`stage_cloud_from_msg` plus the (N, 3) normals when the cloud carries normal_x/y/z, else None."""
    cloud, columns = _stage_cloud(msg, expected_frame, rig)
    return cloud, _normals(columns)


def _stage_cloud(msg: PointCloud2, expected_frame: str, rig=None) -> tuple[Cloud, dict[str, np.ndarray]]:
    """A stage cloud's finite points as a Cloud, and the stage fields it carries (finite points only).

    The fields are bounded before they size anything (the filters lay pixels out on a grid per camera, the
    notches cut the tube in cells of a footprint / 8): a `pixel_footprint` outside FOOTPRINT_RANGE_M (0 =
    unknown), and with `rig`, a `camera` index past its camera_names or pixels outside its largest camera
    image, are refused (RefusedInputError, "inconsistent")."""
    xyz, rgb = input_cloud(msg, expected_frame, keep_nan=True)
    # float64 as the offline pipeline's clouds: the core's kernels then run (and were compiled and cached) for
    # one type, whichever of the two calls them first
    xyz = xyz.astype(np.float64)
    points = read_points(msg, STAGE_FIELDS)
    finite = finite_rows(xyz)
    if not finite.all():
        xyz, rgb, points = xyz[finite], None if rgb is None else rgb[finite], points[finite]
    columns = {name: points[name].astype(np.float32) for name in points.dtype.names}
    camera = columns.get("camera")
    camera = camera.astype(np.int8) if camera is not None and np.all(camera >= 0) else None
    footprint = _footprint(columns.get("pixel_footprint"))
    pixel = None
    if "pixel_u" in columns and "pixel_v" in columns:
        pixel = np.stack([columns["pixel_u"], columns["pixel_v"]], axis=1)
        if not np.isfinite(pixel).all():
            raise RefusedInputError("pixel_u/pixel_v are not all finite", "inconsistent")
        if rig is not None:
            width = max(rig.cameras[name].width for name in rig.camera_names)
            height = max(rig.cameras[name].height for name in rig.camera_names)
            check_pixels(pixel, width, height, "the rig's largest camera")
        pixel = pixel.astype(np.int32)
    if rig is not None and camera is not None and len(camera) and int(columns["camera"].max()) >= len(rig.camera_names):
        raise RefusedInputError(f"camera index {int(columns['camera'].max())} but the rig has "
                                f"{len(rig.camera_names)} cameras", "inconsistent")
    return Cloud(xyz, rgb, camera, stamp_to_ns(msg.header.stamp), footprint, pixel), columns


# What one depth pixel can cover on the robot (metres): a D405 pixel at 7 cm is ~0.1 mm.
FOOTPRINT_RANGE_M = (1e-6, 1e-3)


def _footprint(footprints: np.ndarray | None) -> float:
    """The cloud's pixel footprint (0 = unknown), refused outside FOOTPRINT_RANGE_M."""
    if footprints is None or not len(footprints) or np.isnan(footprints).all():
        return 0.0
    footprint = float(np.nanmax(footprints))
    low, high = FOOTPRINT_RANGE_M
    if footprint != 0.0 and not low <= footprint <= high:
        raise RefusedInputError(f"pixel_footprint {footprint} m is outside [{low}, {high}] m (0 = unknown)",
                                "inconsistent")
    return footprint


def _normals(columns: dict[str, np.ndarray]) -> np.ndarray | None:
    if not all(name in columns for name in _NORMAL_FIELDS):
        return None
    return np.stack([columns[name] for name in _NORMAL_FIELDS], axis=1).astype(float)


def require_frame(msg, expected: str) -> None:
    """A ValueError naming both frames when a message is not in the frame the configuration gives."""
    if msg.header.frame_id != expected:
        raise ValueError(f"message in frame '{msg.header.frame_id}', expected '{expected}' (rig configuration)")


# ---- diagnostics ----------------------------------------------------------------------------------------------

def diagnostics(name: str, hardware_id: str, level: bytes, message: str, values: dict[str, object],
                stamp_ns: int) -> DiagnosticArray:
    """A /diagnostics array of one status (level: DiagnosticStatus.OK / WARN / ERROR / STALE, bytes)."""
    status = DiagnosticStatus(level=level, name=name, hardware_id=hardware_id, message=message,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    return DiagnosticArray(header=header("", stamp_ns), status=[status])
