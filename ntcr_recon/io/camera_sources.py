"""Where camera_node's frames come from: a rosbag2 bag, a live D405 or a librealsense recording.

Every source yields `SourceFrame`s: one camera's depth image (+ colour, + intrinsics) at one stamp, or, for a
bag that holds only recorded clouds, the cloud message as recorded. camera_node turns them into the same
PointCloud2 whatever the source. No rclpy import here: the sources are tested without a ROS graph.

Public API:
    SourceFrame
    BagSource(path, camera, topics, loop=False)  # iterate it for SourceFrames, stamps shifted on each loop
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_typestore

from ntcr_recon.core.config import TopicConfig
from ntcr_recon.core.deproject import Intrinsics
from ntcr_recon.io.bag import image_to_array
from ntcr_recon.io.pointcloud import stamp_to_ns

CACHE_BYTES = 256 * 2**20  # a looping bag up to this size is decoded once and replayed from memory


class SourceError(RuntimeError):
    """A camera source that cannot deliver frames (no device, wrong serial, missing topics...)."""


@dataclass
class SourceFrame:
    """One camera frame. Depth frames: `depth` (16UC1 raw units, `depth_unit` None = the configured unit;
    32FC1 metres, `depth_unit` 1.0), `intrinsics`, optional RGB `color`, and `camera_info` (the recorded
    message, or None to build one from the intrinsics). Recorded-cloud frames: `cloud` (the message)."""

    stamp_ns: int
    depth: np.ndarray | None = None
    depth_unit: float | None = None
    intrinsics: Intrinsics | None = None
    color: np.ndarray | None = None
    camera_info: Any = None
    cloud: Any = None


class BagSource:
    """One camera's frames from a rosbag2 bag (mcap or sqlite3), in recorded order.

    Depth + camera_info (+ colour paired by stamp) when the bag has the camera's depth topic; otherwise the
    recorded `.../depth/color/points` clouds. With `loop`, the bag repeats with stamps shifted by its
    duration plus one frame period, so time keeps moving forward for the graph. `skip` (stamp -> bool), when
    set, drops a frame before its images are decoded (a replay that has fallen behind catches up).
    """

    def __init__(self, path: str | Path, camera: str, topics: TopicConfig, loop: bool = False) -> None:
        from rosbags.highlevel import AnyReader

        self.path = Path(path)
        self.loop = loop
        self.skip: Callable[[int], bool] | None = None  # stamp -> True to skip the frame without decoding it
        if not self.path.exists():
            raise SourceError(f"bag {self.path} does not exist")
        self._reader_class = AnyReader
        self.topics = {kind: topics.camera_topic(camera, kind) for kind in ("depth", "depth_info", "color", "points")}
        with self._open() as reader:
            present = {c.topic for c in reader.connections}
            self.duration_ns = int(reader.duration)
            counts = {c.topic: c.msgcount for c in reader.connections}
        if self.topics["depth"] in present:
            self.mode = "depth"
            if self.topics["depth_info"] not in present:
                raise SourceError(f"bag {self.path} has {self.topics['depth']} but no {self.topics['depth_info']}")
            self.has_color = self.topics["color"] in present
        elif self.topics["points"] in present:
            self.mode, self.has_color = "points", False
        else:
            raise SourceError(f"bag {self.path} has neither {self.topics['depth']} nor {self.topics['points']} "
                              f"(topics: {', '.join(sorted(present)) or 'none'})")
        self._frame_count = counts[self.topics[self.mode]]

    @contextlib.contextmanager
    def _open(self):
        reader = self._reader_class([self.path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        try:
            reader.open()
        except Exception as error:  # rosbags raises its own types for truncated / foreign files
            raise SourceError(f"cannot read bag {self.path}: {error}") from error
        try:
            yield reader
        finally:
            reader.close()

    @property
    def loop_shift_ns(self) -> int:
        """How much later each loop's stamps are: the bag's duration plus its mean frame period, the same for
        every camera of the bag, so cameras replayed by separate nodes stay paired loop after loop."""
        return self.duration_ns + max(self.duration_ns // max(self._frame_count - 1, 1), 1)

    def __iter__(self) -> Iterator[SourceFrame]:
        loop_shift = self.loop_shift_ns
        bag_bytes = sum(f.stat().st_size for f in self.path.rglob("*") if f.is_file()) if self.path.is_dir() \
            else self.path.stat().st_size
        if self.loop and bag_bytes <= CACHE_BYTES:
            # A small looping bag is decoded once and kept: every later loop costs no reading or decoding.
            skip, self.skip = self.skip, None
            cached = list(self._one_pass(0))
            self.skip = skip
            offset_ns = 0
            while cached:
                for frame in cached:
                    if self.skip is None or not self.skip(frame.stamp_ns + offset_ns):
                        yield dataclasses.replace(frame, stamp_ns=frame.stamp_ns + offset_ns)
                offset_ns += loop_shift
            return
        offset_ns = 0
        while True:
            yield from self._one_pass(offset_ns)
            if not self.loop or not self._frame_count:
                return
            offset_ns += loop_shift

    def _wanted(self, stamp: int, offset_ns: int) -> bool:
        """False when the consumer asked to skip this frame (decoding it would be wasted)."""
        return self.skip is None or not self.skip(stamp + offset_ns)

    def _one_pass(self, offset_ns: int) -> Iterator[SourceFrame]:
        wanted = ("depth", "depth_info", "color") if self.mode == "depth" else ("points",)
        topics = {self.topics[kind]: kind for kind in wanted}
        with self._open() as reader:
            connections = [c for c in reader.connections if c.topic in topics]
            if self.mode == "points":
                for connection, _, raw in reader.messages(connections=connections):
                    msg = reader.deserialize(raw, connection.msgtype)
                    if self._wanted(stamp_to_ns(msg.header.stamp), offset_ns):
                        yield SourceFrame(stamp_ns=stamp_to_ns(msg.header.stamp) + offset_ns, cloud=msg)
                return
            info, intrinsics = None, None
            colors: dict[int, np.ndarray] = {}
            waiting: SourceFrame | None = None  # a depth frame whose colour has not come yet
            for connection, _, raw in reader.messages(connections=connections):
                kind = topics[connection.topic]
                msg = reader.deserialize(raw, connection.msgtype)
                if kind == "depth_info":
                    info, intrinsics = msg, Intrinsics.from_camera_info(msg)
                    continue
                stamp = stamp_to_ns(msg.header.stamp)
                if kind == "color":
                    if waiting is not None and waiting.stamp_ns == stamp + offset_ns:
                        waiting.color = image_to_array(msg)
                        yield waiting
                        waiting = None
                    else:
                        colors[stamp] = msg
                        for old in sorted(colors)[:-4]:  # bounded: only the last few wait for their depth
                            del colors[old]
                    continue
                if waiting is not None:  # its colour never came: it goes without
                    yield waiting
                    waiting = None
                if intrinsics is None or not self._wanted(stamp, offset_ns):
                    continue  # no camera_info yet (cannot be deprojected), or skipped
                depth = image_to_array(msg)
                frame = SourceFrame(stamp_ns=stamp + offset_ns, depth=depth, intrinsics=intrinsics, camera_info=info,
                                    depth_unit=1.0 if depth.dtype == np.float32 else None)
                color = colors.pop(stamp, None)
                if color is not None or not self.has_color:
                    frame.color = None if color is None else image_to_array(color)
                    yield frame
                else:
                    waiting = frame
            if waiting is not None:
                yield waiting
