"""Bags made from a sample bag's rendered frames for the offline command's tests: repeated with shifted stamps
(a long recording of the still robot), joined one after the other (a robot that moved), cropped to the pixels
that see the crop box (small enough for CI), or with one camera's depth images altered (units, byte order,
quantisation)."""

from __future__ import annotations

import dataclasses
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ntcr_recon.core.cloud.fusion import FramePair, fuse
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.io.bag import read_camera_frames
from ntcr_recon.io.pointcloud import stamp_to_ns

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
CROP_MARGIN_PX = 24  # kept around the robot's pixels (the filters look at pixel neighbourhoods)


def _with_stamp(msg, stamp_ns: int):
    time = TYPESTORE.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 1_000_000_000,
                                                          nanosec=stamp_ns % 1_000_000_000)
    return dataclasses.replace(msg, header=dataclasses.replace(msg.header, stamp=time))


def _crop_image(msg, window: tuple[int, int, int, int]):
    u0, u1, v0, v1 = window
    channels_bytes = int(msg.step) // int(msg.width)
    rows = np.asarray(msg.data, np.uint8).reshape(int(msg.height), int(msg.step))
    data = np.ascontiguousarray(rows[v0:v1, u0 * channels_bytes:u1 * channels_bytes]).reshape(-1)
    return dataclasses.replace(msg, width=u1 - u0, height=v1 - v0, step=(u1 - u0) * channels_bytes, data=data)


def _crop_info(msg, window: tuple[int, int, int, int]):
    u0, u1, v0, v1 = window
    k = np.array(msg.k, float)
    k[2] -= u0
    k[5] -= v0
    p = np.array(msg.p, float)
    p[2] -= u0
    p[6] -= v0
    return dataclasses.replace(msg, width=u1 - u0, height=v1 - v0, k=k, p=p)


def crop_windows(bag: Path) -> dict[str, tuple[int, int, int, int]]:
    """Per camera the pixel window (u0, u1, v0, v1) of the points fused from its first frame, with a margin."""
    config = load_rig_config(bag / "rig.yaml")
    frames = read_camera_frames(bag, config, max_frames=1)
    windows = {}
    for name, (frame,) in frames.items():
        pixel = fuse(FramePair(frame.stamp_ns, {name: frame}), config).pixel
        u0, v0 = pixel.min(axis=0) - CROP_MARGIN_PX
        u1, v1 = pixel.max(axis=0) + CROP_MARGIN_PX + 1
        height, width = frame.depth.shape
        windows[name] = (max(int(u0), 0), min(int(u1), width), max(int(v0), 0), min(int(v1), height))
    return windows


def _recording(source: Path) -> tuple[list, int]:
    """A bag's messages (topic, type, log time, message) and its span: its frames' stamps' range and one period."""
    with AnyReader([source]) as reader:
        messages = [(c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype))
                    for c, t, raw in reader.messages()]
    stamps = sorted({stamp_to_ns(m.header.stamp) for topic, _, _, m in messages if topic.endswith("image_rect_raw")})
    period = round((stamps[-1] - stamps[0]) / max(len(stamps) // 2 - 1, 1))  # two cameras' frames
    return messages, stamps[-1] - stamps[0] + period


# The messages of one instant in two orders `ros2 bag record` may write them in (it gives none among them).
INFO_FIRST = ("depth/camera_info", "depth/image_rect_raw", "color/camera_info", "color/image_rect_raw")
DEPTH_FIRST = ("depth/image_rect_raw", "color/image_rect_raw", "color/camera_info", "depth/camera_info")


def rewrite_bag(source: Path | list[Path], out: Path, repeat: int = 1, crop: bool = False,
                edit: Callable[[str, object], object] | None = None, instant_order: tuple[str, ...] | None = None,
                ) -> Path:
    """A copy of the rig bag `source` (rig.yaml and ground_truth.json alike) in `out`: its frames `repeat`
    times, each repetition stamped one recording later; images cropped to the crop box's pixels when `crop`;
    `edit(topic, msg) -> msg` applied to every message last. Several sources (of one rig) are recorded one after
    the other, with the last one's rig.yaml and ground_truth.json (e.g. a robot that moved between them).
    `instant_order` (topic endings, e.g. DEPTH_FIRST): the messages of one camera's instant are logged in that
    order (1 ns apart), so a reader meets them so."""
    sources = [source] if isinstance(source, Path) else list(source)
    windows = {}
    for path in sources if crop else []:  # each camera's window: the union of the sources'
        for name, (u0, u1, v0, v1) in crop_windows(path).items():
            a0, a1, b0, b1 = windows.get(name, (u0, u1, v0, v1))
            windows[name] = (min(a0, u0), max(a1, u1), min(b0, v0), max(b1, v1))
    recordings = [_recording(path) for path in sources]
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)  # makes `out`, which must not exist
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    connections = {}
    shift = 0
    with writer:
        for _ in range(repeat):
            for messages, span in recordings:
                for topic, msgtype, log_time, msg in messages:
                    camera = topic.split("/")[2] if topic.count("/") >= 3 else None
                    if camera in windows:
                        if msgtype == "sensor_msgs/msg/Image":
                            msg = _crop_image(msg, windows[camera])
                        elif msgtype == "sensor_msgs/msg/CameraInfo":
                            msg = _crop_info(msg, windows[camera])
                    msg = _with_stamp(msg, stamp_to_ns(msg.header.stamp) + shift)
                    if edit is not None:
                        msg = edit(topic, msg)
                    if topic not in connections:
                        connections[topic] = writer.add_connection(topic, msgtype, typestore=TYPESTORE)
                    rank = next((i for i, end in enumerate(instant_order or ()) if topic.endswith(end)), 0)
                    writer.write(connections[topic], log_time + shift + rank,
                                 TYPESTORE.serialize_cdr(msg, msgtype))
                shift += span
    for name in ("rig.yaml", "ground_truth.json"):
        shutil.copy(sources[-1] / name, out / name)
    return out


def depth_edit(camera: str, change: Callable[[object], object]) -> Callable[[str, object], object]:
    """An `edit` for rewrite_bag that changes one camera's depth images."""
    def edit(topic: str, msg):
        return change(msg) if topic.endswith(f"/{camera}/depth/image_rect_raw") else msg
    return edit


def depth_values(msg) -> np.ndarray:
    return np.frombuffer(bytes(np.asarray(msg.data, np.uint8)), "<u2")


def with_depth_values(msg, values: np.ndarray, big_endian: bool = False):
    data = np.asarray(values, ">u2" if big_endian else "<u2").tobytes()
    return dataclasses.replace(msg, data=np.frombuffer(data, np.uint8), is_bigendian=int(big_endian))
