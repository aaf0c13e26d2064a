"""Write a simulated rig into a rosbag2 directory as realsense-ros would have recorded it.

Per camera `<cam>` under namespace `<ns>` (Jazzy message types, mcap storage, zstd-compressed chunks):
    <ns>/<cam>/depth/image_rect_raw   sensor_msgs/Image 16UC1, raw device units (depth_unit m each)
    <ns>/<cam>/depth/camera_info      sensor_msgs/CameraInfo
    <ns>/<cam>/color/image_rect_raw   sensor_msgs/Image rgb8, aligned with depth (same imager on a D405)
    <ns>/<cam>/color/camera_info      sensor_msgs/CameraInfo
    <ns>/<cam>/depth/color/points     sensor_msgs/PointCloud2 (x, y, z, rgb; optical frame), on request
Beside the mcap, inside the bag directory: ground_truth.json and rig.yaml (a rig configuration that
`ntcr-recon reconstruct BAG --config BAG/rig.yaml` reads).

Public API:
    TOPIC_KINDS, topic_name(namespace, camera, kind)
    BagContents(namespace, intrinsics, frames, with_points=False)
    write_rig_bag(out_dir, contents, extra_files, overwrite=False) -> Path
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ntcr_recon.core.cloud.deproject import Intrinsics, depth_to_points
from ntcr_recon.io.pointcloud import ROSBAGS, cloud_to_msg
from ntcr_recon.io.staging import staged_directory
from ntcr_recon.sim.camera import CameraPose, D405Intrinsics

TOPIC_KINDS = {
    "depth": ("depth/image_rect_raw", "sensor_msgs/msg/Image"),
    "depth_info": ("depth/camera_info", "sensor_msgs/msg/CameraInfo"),
    "color": ("color/image_rect_raw", "sensor_msgs/msg/Image"),
    "color_info": ("color/camera_info", "sensor_msgs/msg/CameraInfo"),
    "points": ("depth/color/points", "sensor_msgs/msg/PointCloud2"),
}
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
# A recorder logs a message a little after its stamp (USB transfer, driver): the bag's receive time.
RECORD_LATENCY_NS = 2_000_000


def topic_name(namespace: str, camera: str, kind: str) -> str:
    parts = [p.strip("/") for p in (namespace, camera, TOPIC_KINDS[kind][0]) if p.strip("/")]
    return "/" + "/".join(parts)


@dataclass
class CameraFrame:
    """One camera's frame: raw depth (H, W) uint16, colour (H, W, 3) uint8, its stamp."""

    camera: CameraPose
    stamp_ns: int
    depth_raw: np.ndarray
    color: np.ndarray


@dataclass
class BagContents:
    namespace: str
    intrinsics: D405Intrinsics
    frames: Iterable[CameraFrame]
    with_points: bool = False


def _header(frame_id: str, stamp_ns: int):
    time = TYPESTORE.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                          nanosec=stamp_ns % 1_000_000_000)
    return TYPESTORE.types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)


def image_message(array: np.ndarray, encoding: str, frame_id: str, stamp_ns: int):
    array = np.ascontiguousarray(array)
    height, width = array.shape[:2]
    return TYPESTORE.types["sensor_msgs/msg/Image"](
        header=_header(frame_id, stamp_ns), height=height, width=width, encoding=encoding,
        is_bigendian=0, step=array.strides[0], data=array.view(np.uint8).reshape(-1))


def camera_info_message(intrinsics: D405Intrinsics, frame_id: str, stamp_ns: int):
    types = TYPESTORE.types
    k = intrinsics.matrix()
    projection = np.zeros((3, 4))
    projection[:, :3] = k
    return types["sensor_msgs/msg/CameraInfo"](
        header=_header(frame_id, stamp_ns), height=intrinsics.height, width=intrinsics.width,
        distortion_model="plumb_bob", d=np.zeros(5), k=k.reshape(-1), r=np.eye(3).reshape(-1),
        p=projection.reshape(-1), binning_x=0, binning_y=0,
        roi=types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def _frame_messages(frame: CameraFrame, contents: BagContents):
    """(kind, message) of one camera frame."""
    frame_id, stamp = frame.camera.frame_id, frame.stamp_ns
    intrinsics = contents.intrinsics
    yield "depth_info", camera_info_message(intrinsics, frame_id, stamp)  # before its image: a reader can
    yield "depth", image_message(frame.depth_raw, "16UC1", frame_id, stamp)  # deproject the first frame
    yield "color_info", camera_info_message(intrinsics, frame_id, stamp)
    yield "color", image_message(frame.color, "rgb8", frame_id, stamp)
    if contents.with_points:
        pinhole = Intrinsics(intrinsics.width, intrinsics.height, intrinsics.fx, intrinsics.fy, intrinsics.cx,
                             intrinsics.cy)
        xyz, rgb, *_ = depth_to_points(frame.depth_raw, pinhole, intrinsics.depth_unit, color=frame.color)
        yield "points", cloud_to_msg(xyz.astype(np.float32), rgb, frame_id=frame_id, stamp_ns=stamp,
                                     msgtypes=ROSBAGS)


def write_rig_bag(out_dir: str | Path, contents: BagContents, extra_files: dict[str, str],
                  overwrite: bool = False) -> Path:
    """Write the bag directory whole or not at all (built beside the target, then renamed into place).

    extra_files: file name -> text, written inside the bag directory (ground truth, rig configuration).
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not overwrite:
        raise FileExistsError(f"{out_dir} exists; choose another output directory or pass --overwrite")
    with staged_directory(out_dir, created_by_writer=True) as bag_path:
        writer = Writer(bag_path, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)  # zstd mcap chunks
        connections = {}
        with writer:
            for frame in contents.frames:
                for kind, message in _frame_messages(frame, contents):
                    topic = topic_name(contents.namespace, frame.camera.name, kind)
                    msgtype = TOPIC_KINDS[kind][1]
                    if topic not in connections:
                        connections[topic] = writer.add_connection(topic, msgtype, typestore=TYPESTORE)
                    writer.write(connections[topic], frame.stamp_ns + RECORD_LATENCY_NS,
                                 TYPESTORE.serialize_cdr(message, msgtype))
        for name, text in extra_files.items():
            (bag_path / name).write_text(text)
    return out_dir
