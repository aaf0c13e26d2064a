"""Serialized (CDR) messages built from numpy arrays, for the messages that hold one Python object per point.

An rclpy Path of 120 poses, or a Marker of 10 000 triangle corners, costs tens of milliseconds to build as
Python objects (each Point or PoseStamped a constructor call and checked setters) and again to convert for
publication. A Publisher also takes the message as serialized bytes (`publish(bytes)`), so these builders write
the bytes directly: the fixed parts come from rclpy's own serialization of a template message (so every other
field is exactly what rclpy writes), and the per-point arrays are spliced in with numpy in one piece.

CDR (XCDR1, little endian, as rmw_fastrtps writes it): a 4-byte encapsulation header, then the fields in order,
each primitive aligned to its size relative to the end of that header; a sequence is a uint32 count and its
elements; a string a uint32 length (with the terminating NUL) and its bytes. The readers (`header_stamp_ns`,
`cloud_size`) take either byte order, as the encapsulation says, and read a header before a message is decoded.
"""

from __future__ import annotations

import struct

import numpy as np
from geometry_msgs.msg import Point
from rclpy.serialization import serialize_message

ENCAPSULATION = 4  # bytes before the aligned payload


def _align(offset: int, size: int) -> int:
    """`offset` (from the start of the buffer) moved up to a multiple of `size` relative to the payload."""
    payload = offset - ENCAPSULATION
    return offset + (-payload) % size


_PROBE = (1.2345678901234567e-300, -9.87654321e-299, 3.14159e-301)  # a point no message holds by chance


def _byte_order(raw: bytes) -> str:
    """struct's byte order of a serialized message: encapsulation CDR_BE (0x0000) or CDR_LE (0x0001)."""
    return ">" if raw[1] == 0 else "<"


def header_stamp_ns(raw: bytes) -> int:
    """The header stamp of a serialized message that starts with a std_msgs/Header (int32 sec, uint32 nanosec
    right after the encapsulation); ValueError for bytes too short for it."""
    if len(raw) < ENCAPSULATION + 8:
        raise ValueError(f"message of {len(raw)} bytes is too short for a header stamp")
    seconds, nanoseconds = struct.unpack_from(_byte_order(raw) + "iI", raw, ENCAPSULATION)
    return seconds * 1_000_000_000 + nanoseconds


def cloud_size(raw: bytes) -> tuple[int, int]:
    """(height, width) of a serialized PointCloud2: after its header (stamp, then the string frame_id), two uint32
    4-aligned; ValueError for bytes too short for them."""
    try:
        order = _byte_order(raw)
        (length,) = struct.unpack_from(order + "I", raw, ENCAPSULATION + 8)
        height, width = struct.unpack_from(order + "II", raw, _align(ENCAPSULATION + 12 + length, 4))
    except (IndexError, struct.error):
        raise ValueError(f"a PointCloud2 of {len(raw)} bytes is too short for its header") from None
    return int(height), int(width)


def _points_count_offset(empty_bytes: bytes, one_point_bytes: bytes) -> int:
    """Where the count of a sequence<Point> holding only `_PROBE` lies in a serialized message: right before
    the element, or 4 bytes of padding before it when the count ends off an 8-byte boundary. Which one is told
    by the lengths (with nothing after the field aligned above 4, one point adds 24 bytes and the padding):
    never by the bytes before the element, since rclpy leaves padding unset and a stale count of 1 may sit
    there. Not cached: the bytes hold the header stamp, a key that would never repeat."""
    element = one_point_bytes.index(struct.pack("<3d", *_PROBE))
    padding = len(one_point_bytes) - len(empty_bytes) - 24
    return element - 4 - padding


def with_points(template, field: str, points: np.ndarray) -> bytes:
    """`template` (a message whose `field` is an empty sequence<geometry_msgs/Point>, and nothing after that
    field needs an alignment above 4) serialized with `points` (N, 3) in that field."""
    points = np.ascontiguousarray(points, dtype="<f8").reshape(-1, 3)
    empty = serialize_message(template)
    if not len(points):
        return empty
    setattr(template, field, [Point(x=_PROBE[0], y=_PROBE[1], z=_PROBE[2])])
    try:
        one = serialize_message(template)
    finally:
        setattr(template, field, [])
    count_at = _points_count_offset(empty, one)
    padding = _align(count_at + 4, 8) - (count_at + 4)
    return b"".join((empty[:count_at], struct.pack("<I", len(points)), bytes(padding), points.tobytes(),
                     empty[count_at + 4:]))


def _string(buffer: bytearray, text: str) -> None:
    data = text.encode() + b"\0"
    buffer += bytes(_align(len(buffer), 4) - len(buffer))
    buffer += struct.pack("<I", len(data)) + data


def _header(buffer: bytearray, stamp_ns: int, frame_id: str) -> None:
    seconds, nanoseconds = divmod(int(stamp_ns), 1_000_000_000)
    buffer += bytes(_align(len(buffer), 4) - len(buffer))
    buffer += struct.pack("<iI", seconds, nanoseconds)
    _string(buffer, frame_id)


def path(positions: np.ndarray, quaternions: np.ndarray, frame_id: str, stamp_ns: int) -> bytes:
    """nav_msgs/Path: the header, then one PoseStamped (same header) per row of positions (N, 3) and
    quaternions (N, 4: x, y, z, w)."""
    buffer = bytearray(b"\x00\x01\x00\x00")  # CDR little endian
    _header(buffer, stamp_ns, frame_id)
    buffer += bytes(_align(len(buffer), 4) - len(buffer))
    buffer += struct.pack("<I", len(positions))
    poses = np.concatenate([np.asarray(positions, "<f8").reshape(-1, 3),
                            np.asarray(quaternions, "<f8").reshape(-1, 4)], axis=1)
    for row in poses:  # a few bytes per pose; the doubles of each pose in one piece
        _header(buffer, stamp_ns, frame_id)
        buffer += bytes(_align(len(buffer), 8) - len(buffer))
        buffer += row.tobytes()
    return bytes(buffer)


def mesh(vertices: np.ndarray, triangles: np.ndarray) -> bytes:
    """shape_msgs/Mesh: triangles (uint32[3] each), then vertices (Points)."""
    triangles = np.ascontiguousarray(triangles, dtype="<u4").reshape(-1, 3)
    vertices = np.ascontiguousarray(vertices, dtype="<f8").reshape(-1, 3)
    buffer = bytearray(b"\x00\x01\x00\x00")
    buffer += struct.pack("<I", len(triangles)) + triangles.tobytes()
    buffer += struct.pack("<I", len(vertices))
    if len(vertices):
        buffer += bytes(_align(len(buffer), 8) - len(buffer))
        buffer += vertices.tobytes()
    return bytes(buffer)
