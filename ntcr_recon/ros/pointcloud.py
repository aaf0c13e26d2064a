"""sensor_msgs/PointCloud2 <-> numpy, for rclpy messages and `rosbags` messages alike.

Both kinds of message carry the same field names, so reading is duck-typed. Writing needs the message
classes, given as a `MessageTypes` namespace: `RCLPY` (imported only when first used, so this module works
on a machine with no ROS) or `ROSBAGS`.

The layout written is the one RViz2, PCL and sensor_msgs_py read: x, y, z float32 then `rgb` float32 whose
bits are 0x00RRGGBB. Reading accepts any field order, padding, row padding, endianness and numeric type.
No Python loop runs over points: a structured numpy dtype views the bytes in place.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

# sensor_msgs/PointField datatype constants -> numpy scalar type.
_POINTFIELD_DTYPES = {
    1: np.int8, 2: np.uint8, 3: np.int16, 4: np.uint16,
    5: np.int32, 6: np.uint32, 7: np.float32, 8: np.float64,
}
FLOAT32 = 7
_COLOR_FIELDS = ("rgb", "rgba")


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


class _RclpyTypes:
    """Resolves the rclpy message classes on first use, so importing this module needs no ROS."""

    @functools.cached_property
    def _types(self) -> MessageTypes:
        from builtin_interfaces.msg import Time
        from sensor_msgs.msg import PointCloud2, PointField
        from std_msgs.msg import Header

        return MessageTypes(PointCloud2, PointField, Header, Time, lambda data: data.tobytes())

    def __getattr__(self, name):
        return getattr(self._types, name)


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


RCLPY = _RclpyTypes()
ROSBAGS = _RosbagsTypes()


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time (either flavour) -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def pack_rgb(rgb_u8: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 colours -> (N,) uint32 0x00RRGGBB."""
    rgb = np.asarray(rgb_u8, dtype=np.uint32)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]


def unpack_rgb(packed: np.ndarray) -> np.ndarray:
    """(N,) uint32 0x00RRGGBB -> (N, 3) uint8 colours."""
    packed = np.asarray(packed, dtype=np.uint32)
    return np.stack([(packed >> 16) & 0xFF, (packed >> 8) & 0xFF, packed & 0xFF], axis=-1).astype(np.uint8)


def _field_dtype(msg) -> tuple[np.dtype, str | None]:
    """Structured dtype viewing one point of `msg`, and the name of its colour field if any."""
    byte_order = ">" if msg.is_bigendian else "<"
    fields = {field.name: field for field in msg.fields}
    missing = [axis for axis in "xyz" if axis not in fields]
    if missing:
        present = ", ".join(fields) or "none"
        raise CloudFormatError(f"PointCloud2 has no field {'/'.join(missing)} (fields: {present})")
    color_name = next((name for name in _COLOR_FIELDS if name in fields), None)
    names, formats, offsets = [], [], []
    for name in ("x", "y", "z") + ((color_name,) if color_name else ()):
        field = fields[name]
        if field.datatype not in _POINTFIELD_DTYPES:
            raise CloudFormatError(f"PointCloud2 field {name!r} has unknown datatype {field.datatype}")
        # Colour is read as its raw 4 bytes: packed float32 and uint32 share the 0x00RRGGBB bits.
        scalar = np.uint32 if name == color_name else _POINTFIELD_DTYPES[field.datatype]
        dtype = np.dtype(scalar).newbyteorder(byte_order)
        if name == color_name and np.dtype(_POINTFIELD_DTYPES[field.datatype]).itemsize != 4:
            raise CloudFormatError(f"PointCloud2 colour field {name!r} must be 4 bytes wide")
        if field.offset + dtype.itemsize > msg.point_step:
            raise CloudFormatError(
                f"PointCloud2 field {name!r} at offset {field.offset} overruns point_step {msg.point_step}"
            )
        names.append(name)
        formats.append(dtype)
        offsets.append(field.offset)
    structured = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": msg.point_step})
    return structured, color_name


def cloud_from_msg(msg, drop_nan: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Points of a PointCloud2 as float32 (N, 3) and colours as uint32 0x00RRGGBB (N,) or None.

    Organised clouds come out flattened row-major (N = height * width). With `drop_nan`, points with a
    non-finite coordinate are dropped (with their colours).
    """
    width, height, point_step = int(msg.width), int(msg.height), int(msg.point_step)
    if point_step <= 0 and width * height > 0:
        raise CloudFormatError(f"PointCloud2 has point_step {point_step}")
    structured, color_name = _field_dtype(msg)
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
    if row_step == width * point_step:
        points = data[: width * height * point_step].view(structured)
    else:  # rows padded: gather each row's points (one copy, no per-point loop)
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, width * point_step), strides=(row_step, 1))
        points = np.ascontiguousarray(rows).view(structured).reshape(-1)
    xyz = np.empty((points.size, 3), dtype=np.float32)
    for column, axis in enumerate("xyz"):
        xyz[:, column] = points[axis]
    rgb = (points[color_name].astype(np.uint32) & 0x00FFFFFF) if color_name else None
    if drop_nan:
        finite = np.isfinite(xyz).all(axis=1)
        if not finite.all():
            xyz = xyz[finite]
            rgb = rgb[finite] if rgb is not None else None
    return xyz, rgb


def cloud_to_msg(xyz: np.ndarray, rgb: np.ndarray | None = None, *, frame_id: str, stamp_ns: int,
                 msgtypes: MessageTypes = RCLPY):
    """A PointCloud2 of x, y, z float32 (+ packed `rgb` float32) in the flavour of `msgtypes`.

    `xyz` is (N, 3) for an unorganised cloud or (H, W, 3) for an organised one; `rgb` is uint32 0x00RRGGBB
    of the same leading shape (see `pack_rgb`).
    """
    points = np.asarray(xyz, dtype=np.float32)
    if points.ndim not in (2, 3) or points.shape[-1] != 3:
        raise CloudFormatError(f"points must have shape (N, 3) or (H, W, 3), got {points.shape}")
    height, width = points.shape[:2] if points.ndim == 3 else (1, points.shape[0])
    names = ["x", "y", "z"] + (["rgb"] if rgb is not None else [])
    record = np.dtype({"names": names, "formats": ["<f4"] * 3 + (["<u4"] if rgb is not None else []),
                       "offsets": [0, 4, 8, 12][: len(names)], "itemsize": 4 * len(names)})
    flat = np.zeros(height * width, dtype=record)
    for column, axis in enumerate("xyz"):
        flat[axis] = points.reshape(-1, 3)[:, column]
    if rgb is not None:
        colors = np.asarray(rgb, dtype=np.uint32).reshape(-1)
        if colors.size != flat.size:
            raise CloudFormatError(f"{colors.size} colours for {flat.size} points")
        flat["rgb"] = colors
    fields = [msgtypes.point_field(name=name, offset=4 * i, datatype=FLOAT32, count=1) for i, name in enumerate(names)]
    seconds, nanoseconds = divmod(int(stamp_ns), 1_000_000_000)
    header = msgtypes.header(stamp=msgtypes.time(sec=seconds, nanosec=nanoseconds), frame_id=frame_id)
    return msgtypes.point_cloud2(
        header=header, height=height, width=width, fields=fields, is_bigendian=False,
        point_step=record.itemsize, row_step=record.itemsize * width,
        data=msgtypes.wrap_data(flat.view(np.uint8)), is_dense=bool(np.isfinite(points).all()),
    )
