"""PointCloud2 <-> numpy: round trips through both message flavours, CDR and an mcap bag; foreign layouts."""

from __future__ import annotations

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import PointCloud2, PointField

from ntcr_recon.core.cloud.points import pack_rgb, unpack_rgb
from ntcr_recon.io.pointcloud import (
    ROSBAGS,
    CloudFormatError,
    cloud_from_msg,
    cloud_to_msg,
    stamp_to_ns,
)
from ntcr_recon.ros.messages import RCLPY

STAMP_NS = 1_700_000_123_456_789_012


@pytest.fixture
def cloud():
    rng = np.random.default_rng(7)
    xyz = rng.normal(scale=0.05, size=(500, 3)).astype(np.float32)
    colors = rng.integers(0, 256, size=(500, 3), dtype=np.uint8)
    # Extreme values: subnormal, negative zero and colours whose packed float is a NaN pattern.
    xyz[0] = [np.float32(1e-40), -0.0, np.float32(3.4e38)]
    colors[1] = [255, 255, 255]
    return xyz, pack_rgb(colors)


def assert_bit_identical(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.tobytes() == b.tobytes()


def test_rgb_packing_round_trip():
    colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [18, 52, 86]], dtype=np.uint8)
    packed = pack_rgb(colors)
    assert packed.tolist() == [0xFF0000, 0x00FF00, 0x0000FF, 0x123456]
    assert_bit_identical(unpack_rgb(packed), colors)


@pytest.mark.parametrize("msgtypes", [RCLPY, ROSBAGS], ids=["rclpy", "rosbags"])
def test_round_trip_is_bit_identical(cloud, msgtypes):
    xyz, rgb = cloud
    msg = cloud_to_msg(xyz, rgb, frame_id="cam_a_optical_frame", stamp_ns=STAMP_NS, msgtypes=msgtypes)
    assert [f.name for f in msg.fields] == ["x", "y", "z", "rgb"]
    assert msg.point_step == 16 and msg.width == 500 and msg.height == 1 and msg.is_dense
    assert stamp_to_ns(msg.header.stamp) == STAMP_NS and msg.header.frame_id == "cam_a_optical_frame"
    xyz_back, rgb_back = cloud_from_msg(msg)
    assert_bit_identical(xyz_back, xyz)
    assert_bit_identical(rgb_back, rgb)


def test_round_trip_through_cdr(cloud):
    xyz, rgb = cloud
    msg = cloud_to_msg(xyz, rgb, msgtypes=RCLPY, frame_id="ntcr_base", stamp_ns=STAMP_NS)
    decoded = deserialize_message(serialize_message(msg), PointCloud2)
    xyz_back, rgb_back = cloud_from_msg(decoded)
    assert_bit_identical(xyz_back, xyz)
    assert_bit_identical(rgb_back, rgb)
    # The same bytes decode as a rosbags message too.
    typestore = get_typestore(Stores.ROS2_JAZZY)
    as_rosbags = typestore.deserialize_cdr(serialize_message(msg), "sensor_msgs/msg/PointCloud2")
    assert_bit_identical(cloud_from_msg(as_rosbags)[0], xyz)


def test_round_trip_through_mcap_bag(cloud, tmp_path):
    xyz, rgb = cloud
    typestore = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / "clouds"
    msgtype = "sensor_msgs/msg/PointCloud2"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/ntcr/cam_a/depth/color/points", msgtype, typestore=typestore)
        for i in range(3):
            msg = cloud_to_msg(xyz + i, rgb, frame_id="cam_a_optical_frame", stamp_ns=STAMP_NS + i, msgtypes=ROSBAGS)
            writer.write(connection, STAMP_NS + i, typestore.serialize_cdr(msg, msgtype))
    with Reader(bag) as reader:
        messages = [typestore.deserialize_cdr(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(messages) == 3
    for i, msg in enumerate(messages):
        xyz_back, rgb_back = cloud_from_msg(msg)
        assert_bit_identical(xyz_back, (xyz + i).astype(np.float32))
        assert_bit_identical(rgb_back, rgb)
        assert stamp_to_ns(msg.header.stamp) == STAMP_NS + i


def test_organised_cloud_keeps_row_major_order_and_nan_drop():
    grid = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    grid[1, 2] = np.nan
    msg = cloud_to_msg(grid, msgtypes=RCLPY, frame_id="cam", stamp_ns=0)
    assert (msg.height, msg.width, msg.is_dense) == (4, 5, False)
    xyz, rgb = cloud_from_msg(msg)
    assert rgb is None
    assert_bit_identical(xyz, grid.reshape(-1, 3))
    dropped, _ = cloud_from_msg(msg, drop_nan=True)
    assert dropped.shape == (19, 3)
    assert np.isfinite(dropped).all()


def _foreign_cloud(xyz: np.ndarray, rgb: np.ndarray, *, big_endian: bool, row_padding: int, width: int):
    """A cloud laid out as some drivers do: rgb first, padding, float64 z, padded rows."""
    order = ">" if big_endian else "<"
    record = np.dtype({"names": ["rgb", "x", "y", "z"],
                       "formats": [order + "u4", order + "f4", order + "f4", order + "f8"],
                       "offsets": [0, 8, 12, 20], "itemsize": 32})
    height = len(xyz) // width
    points = np.zeros(len(xyz), dtype=record)
    points["rgb"], points["x"], points["y"], points["z"] = rgb, xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rows = points.view(np.uint8).reshape(height, width * 32)
    padded = np.zeros((height, width * 32 + row_padding), dtype=np.uint8)
    padded[:, : width * 32] = rows
    fields = [PointField(name="rgb", offset=0, datatype=7, count=1),
              PointField(name="x", offset=8, datatype=7, count=1),
              PointField(name="y", offset=12, datatype=7, count=1),
              PointField(name="z", offset=20, datatype=8, count=1)]
    msg = PointCloud2(height=height, width=width, fields=fields, is_bigendian=big_endian, point_step=32,
                      row_step=width * 32 + row_padding, is_dense=True)
    msg.data = padded.tobytes()
    return msg


@pytest.mark.parametrize("big_endian", [False, True])
def test_foreign_layout_padding_and_endianness(cloud, big_endian):
    xyz, rgb = cloud
    msg = _foreign_cloud(xyz, rgb, big_endian=big_endian, row_padding=12, width=50)
    xyz_back, rgb_back = cloud_from_msg(msg)
    assert_bit_identical(xyz_back, xyz)
    assert_bit_identical(rgb_back, rgb)


def test_too_short_data_is_refused(cloud):
    msg = cloud_to_msg(*cloud, msgtypes=RCLPY, frame_id="cam", stamp_ns=0)
    msg.data = bytes(msg.data)[:-1]
    with pytest.raises(CloudFormatError, match="width\\*height\\*point_step"):
        cloud_from_msg(msg)


def test_missing_xyz_field_is_refused(cloud):
    msg = cloud_to_msg(*cloud, msgtypes=RCLPY, frame_id="cam", stamp_ns=0)
    msg.fields = [f for f in msg.fields if f.name != "y"]
    with pytest.raises(CloudFormatError, match="no field y"):
        cloud_from_msg(msg)


def test_field_overrunning_point_is_refused(cloud):
    msg = cloud_to_msg(*cloud, msgtypes=RCLPY, frame_id="cam", stamp_ns=0)
    msg.point_step = 12  # rgb at offset 12 no longer fits
    msg.row_step = 12 * msg.width
    with pytest.raises(CloudFormatError, match="overruns point_step"):
        cloud_from_msg(msg)


def test_empty_cloud_round_trips():
    msg = cloud_to_msg(np.zeros((0, 3), np.float32), msgtypes=RCLPY, frame_id="cam", stamp_ns=5)
    xyz, rgb = cloud_from_msg(msg)
    assert xyz.shape == (0, 3) and rgb is None
