"""sensor_msgs/PointCloud2 <-> numpy, for rclpy messages and `rosbags` messages alike.

One layout function, `dtype_from_fields`, turns a message's PointFields into a structured numpy dtype that
views the bytes in place; reading (`read_points`, `cloud_from_msg`) and writing (`create_cloud`,
`cloud_to_msg`) both go through it, for any fields. No Python loop runs over points.

Both kinds of message carry the same field names, so reading is duck-typed. Writing needs the message
classes, given as a `MessageTypes` namespace: `ROSBAGS` here, or `ntcr_recon.ros.messages.RCLPY` for rclpy
messages (kept in the ROS layer, so this module imports no ROS package).

The layout written is the one RViz2, PCL and sensor_msgs_py read: x, y, z float32, then `rgb` float32 whose
bits are 0x00RRGGBB, then any of the `STAGE_FIELDS` the pipeline's stages add. Reading accepts any field
order, padding, row padding, endianness and numeric type.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ntcr_recon.core.cloud.points import finite_rows

# sensor_msgs/PointField datatype constants
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
DATATYPES = {INT8: np.int8, UINT8: np.uint8, INT16: np.int16, UINT16: np.uint16,
             INT32: np.int32, UINT32: np.uint32, FLOAT32: np.float32, FLOAT64: np.float64}
_DATATYPE_OF = {np.dtype(scalar).newbyteorder("<"): code for code, scalar in DATATYPES.items()}
COLOR_FIELDS = ("rgb", "rgba")

# The fields the stages add after x, y, z, rgb, each declared once (meaning: ntcr_recon/ros/messages.py).
# float32 throughout, so RViz2 and PCL can colour a cloud by any of them.
STAGE_FIELDS: dict[str, np.dtype] = {name: np.dtype("<f4") for name in (
    "camera", "pixel_footprint", "pixel_u", "pixel_v", "normal_x", "normal_y", "normal_z",
    "part", "tube_s", "tube_x", "tube_y")}


class CloudFormatError(ValueError):
    """A PointCloud2 whose bytes or fields do not describe a cloud of points."""


@dataclass(frozen=True)
class MessageTypes:
    """The message classes a flavour of ROS messages is built from."""

    point_cloud2: Callable[..., Any]
    point_field: Callable[..., Any]
    header: Callable[..., Any]
    time: Callable[..., Any]
    wrap_data: Callable[[np.ndarray], Any]  # uint8 array -> what the message's `data` field takes


class _RosbagsTypes:
    @functools.cached_property
    def _types(self) -> MessageTypes:
        from rosbags.typesys import Stores, get_typestore

        types = get_typestore(Stores.ROS2_JAZZY).types
        return MessageTypes(
            types["sensor_msgs/msg/PointCloud2"],
            types["sensor_msgs/msg/PointField"],
            types["std_msgs/msg/Header"],
            types["builtin_interfaces/msg/Time"],
            lambda data: np.ascontiguousarray(data, dtype=np.uint8),
        )

    def __getattr__(self, name):
        return getattr(self._types, name)


ROSBAGS = _RosbagsTypes()


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (either flavour) -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def dtype_from_fields(fields: Iterable, point_step: int, big_endian: bool = False,
                      names: Iterable[str] | None = None) -> np.dtype:
    """Structured dtype of one point: the named fields (all when None; names absent from `fields` are left
    out) at their offsets, itemsize `point_step`. A colour field is viewed as its raw uint32 bits (packed
    float32 and uint32 share the 0x00RRGGBB layout)."""
    by_name = {field.name: field for field in fields}
    wanted = list(by_name) if names is None else [name for name in names if name in by_name]
    order = ">" if big_endian else "<"
    formats, offsets = [], []
    for name in wanted:
        field = by_name[name]
        if field.datatype not in DATATYPES:
            raise CloudFormatError(f"PointCloud2 field {name!r} has unknown datatype {field.datatype}")
        scalar = np.dtype(DATATYPES[field.datatype])
        if name in COLOR_FIELDS:
            if scalar.itemsize != 4:
                raise CloudFormatError(f"PointCloud2 colour field {name!r} must be 4 bytes wide")
            scalar = np.dtype(np.uint32)
        if field.offset + scalar.itemsize > point_step:
            raise CloudFormatError(f"PointCloud2 field {name!r} at offset {field.offset} overruns point_step "
                                   f"{point_step}")
        formats.append(scalar.newbyteorder(order))
        offsets.append(int(field.offset))
    return np.dtype({"names": wanted, "formats": formats, "offsets": offsets, "itemsize": int(point_step)})


def read_points(msg, names: Iterable[str] | None = None) -> np.ndarray:
    """The points of a PointCloud2 as a flat structured array (row-major; organised clouds flattened) of the
    named fields that it has (all when None). A view of the message's bytes when its rows are unpadded."""
    width, height, point_step = int(msg.width), int(msg.height), int(msg.point_step)
    if point_step <= 0 and width * height > 0:
        raise CloudFormatError(f"PointCloud2 has point_step {point_step}")
    structured = dtype_from_fields(msg.fields, max(point_step, 0), bool(msg.is_bigendian), names)
    row_step = int(msg.row_step) if height > 1 else max(int(msg.row_step), width * point_step)
    if row_step < width * point_step:
        raise CloudFormatError(f"PointCloud2 row_step {row_step} is shorter than width*point_step "
                               f"({width}*{point_step})")
    data = np.frombuffer(msg.data, dtype=np.uint8) if len(msg.data) else np.zeros(0, np.uint8)
    expected = row_step * (height - 1) + width * point_step if height and width else 0
    if data.size < expected:
        raise CloudFormatError(
            f"PointCloud2 data has {data.size} bytes, but width*height*point_step needs {expected} "
            f"({width}x{height} points of {point_step} bytes)"
        )
    if not expected:
        return np.zeros(0, dtype=structured)
    if row_step == width * point_step:
        return data[: width * height * point_step].view(structured)
    # rows padded: gather each row's points (one copy, no per-point loop)
    rows = np.lib.stride_tricks.as_strided(data, shape=(height, width * point_step), strides=(row_step, 1))
    return np.ascontiguousarray(rows).view(structured).reshape(-1)


def cloud_from_msg(msg, drop_nan: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Points of a PointCloud2 as float32 (N, 3) and colours as uint32 0x00RRGGBB (N,) or None.

    Organised clouds come out flattened row-major (N = height * width). With `drop_nan`, points with a
    non-finite coordinate are dropped (with their colours).
    """
    present = {field.name for field in msg.fields}
    missing = [axis for axis in "xyz" if axis not in present]
    if missing:
        raise CloudFormatError(f"PointCloud2 has no field {'/'.join(missing)} (fields: "
                               f"{', '.join(sorted(present)) or 'none'})")
    color_name = next((name for name in COLOR_FIELDS if name in present), None)
    points = read_points(msg, ("x", "y", "z") + ((color_name,) if color_name else ()))
    xyz = np.empty((points.size, 3), dtype=np.float32)
    for column, axis in enumerate("xyz"):
        xyz[:, column] = points[axis]
    rgb = (points[color_name].astype(np.uint32) & 0x00FFFFFF) if color_name else None
    if drop_nan:
        finite = finite_rows(xyz)
        if not finite.all():
            xyz = xyz[finite]
            rgb = rgb[finite] if rgb is not None else None
    return xyz, rgb


def create_cloud(points: np.ndarray, *, frame_id: str, stamp_ns: int, msgtypes: MessageTypes,
                 height: int = 1, is_dense: bool | None = None):
    """A PointCloud2 whose fields are those of the structured array `points` (little-endian scalars; N =
    height * width, row-major). The data is built in one piece from the array's bytes."""
    points = np.ascontiguousarray(points).reshape(-1)
    fields = []
    for name in points.dtype.names:
        scalar, offset = points.dtype.fields[name][:2]
        code = _DATATYPE_OF.get(scalar.newbyteorder("<") if scalar.byteorder != "|" else scalar)
        if code is None or scalar.byteorder == ">":
            raise CloudFormatError(f"field {name!r} has no PointField datatype for {scalar}")
        # rgb is stored as its uint32 bits but declared float32, as RViz2 and PCL expect
        fields.append(msgtypes.point_field(name=name, offset=offset,
                                           datatype=FLOAT32 if name in COLOR_FIELDS else code, count=1))
    width = points.size // height if height else 0
    if is_dense is None:
        is_dense = all(bool(np.isfinite(points[axis]).all()) for axis in "xyz" if axis in points.dtype.names)
    seconds, nanoseconds = divmod(int(stamp_ns), 1_000_000_000)
    header = msgtypes.header(stamp=msgtypes.time(sec=seconds, nanosec=nanoseconds), frame_id=frame_id)
    return msgtypes.point_cloud2(
        header=header, height=height, width=width, fields=fields, is_bigendian=False,
        point_step=points.dtype.itemsize, row_step=points.dtype.itemsize * width,
        data=msgtypes.wrap_data(points.view(np.uint8)), is_dense=bool(is_dense),
    )


def cloud_to_msg(xyz: np.ndarray, rgb: np.ndarray | None = None, *, frame_id: str, stamp_ns: int,
                 msgtypes: MessageTypes, columns: Mapping[str, np.ndarray | float] | None = None):
    """A PointCloud2 of x, y, z float32 (+ packed `rgb` float32, + `columns`, named from `STAGE_FIELDS`) in
    the flavour of `msgtypes`.

    `xyz` is (N, 3) for an unorganised cloud or (H, W, 3) for an organised one; `rgb` is uint32 0x00RRGGBB
    of the same leading shape (see `core.cloud.points.pack_rgb`); each column is one value per point or a scalar.
    """
    xyz = np.asarray(xyz, dtype=np.float32)
    if xyz.ndim not in (2, 3) or xyz.shape[-1] != 3:
        raise CloudFormatError(f"points must have shape (N, 3) or (H, W, 3), got {xyz.shape}")
    height, width = xyz.shape[:2] if xyz.ndim == 3 else (1, xyz.shape[0])
    columns = dict(columns or {})
    unknown = sorted(set(columns) - set(STAGE_FIELDS))
    if unknown:
        raise CloudFormatError(f"no declared PointCloud2 field {unknown[0]!r} (STAGE_FIELDS)")
    layout = [(axis, "<f4") for axis in "xyz"] + ([("rgb", "<u4")] if rgb is not None else [])
    layout += [(name, STAGE_FIELDS[name]) for name in columns]
    points = np.empty(height * width, dtype=layout)
    flat = xyz.reshape(-1, 3)
    for column, axis in enumerate("xyz"):
        points[axis] = flat[:, column]
    if rgb is not None:
        colors = np.asarray(rgb, dtype=np.uint32).reshape(-1)
        if colors.size != points.size:
            raise CloudFormatError(f"{colors.size} colours for {points.size} points")
        points["rgb"] = colors
    for name, values in columns.items():
        points[name] = values
    return create_cloud(points, frame_id=frame_id, stamp_ns=stamp_ns, msgtypes=msgtypes, height=height,
                        is_dense=bool(np.isfinite(flat).all()))
