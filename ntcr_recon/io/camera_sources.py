"""Where camera_node's frames come from: a rosbag2 bag, a live D405 or a librealsense recording.

Every source yields `SourceFrame`s: one camera's depth image (+ colour, + intrinsics) at one stamp, or, for a
bag that holds only recorded clouds, the cloud message as recorded. camera_node turns them into the same
PointCloud2 whatever the source. No rclpy import here: the sources are tested without a ROS graph.

Public API:
    SourceFrame
    BagSource(path, camera, topics, loop=False)  # iterate it for SourceFrames, stamps shifted on each loop
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.pairing import stamp_jump
from ntcr_recon.core.config.rig import TopicConfig
from ntcr_recon.io.bag import BagError, BagStream, open_bag
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

    Depth + camera_info (+ colour paired by stamp, as io.bag.DepthFrameMatcher pairs them for the offline
    command too) when the bag has the camera's depth topic; otherwise the recorded `.../depth/color/points`
    clouds. With `loop`, the bag repeats with stamps shifted by its
    duration plus one frame period, so time keeps moving forward for the graph. `skip` (stamp -> bool), when
    set, drops a frame before its images are decoded (a replay that has fallen behind catches up).
    """

    def __init__(self, path: str | Path, camera: str, topics: TopicConfig, loop: bool = False) -> None:
        self.path = Path(path)
        self.loop = loop
        self.skip: Callable[[int], bool] | None = None  # stamp -> True to skip the frame without decoding it
        if not self.path.exists():
            raise SourceError(f"bag {self.path} does not exist")
        self.camera = camera
        self.topics = {kind: topics.camera_topic(camera, kind) for kind in ("depth", "depth_info", "color", "points")}
        try:
            with open_bag(self.path) as reader:
                present = {c.topic for c in reader.connections}
                self.duration_ns = int(reader.duration)
                counts = {c.topic: c.msgcount for c in reader.connections}
        except BagError as error:
            raise SourceError(str(error)) from error
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

    @property
    def frame_count(self) -> int:
        """The camera's frames in one pass of the bag."""
        return self._frame_count

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
        try:
            for _, item in BagStream(self.path, {self.camera: self.topics}, self.mode):
                if self.mode == "points":
                    stamp = stamp_to_ns(item.header.stamp)
                    if self._wanted(stamp, offset_ns):
                        yield SourceFrame(stamp_ns=stamp + offset_ns, cloud=item)
                    continue
                if not self._wanted(item.stamp_ns, offset_ns):
                    continue
                depth, unit, color = item.decode()
                yield SourceFrame(stamp_ns=item.stamp_ns + offset_ns, depth=depth, depth_unit=unit,
                                  intrinsics=item.intrinsics, color=color, camera_info=item.info)
        except BagError as error:
            raise SourceError(str(error)) from error


class Pacer:
    """When each frame of a replay is due on the wall clock (s), at `rate` times the recorded speed, from the first
    frame's stamp and `start_wall`. Its stamps jumping back, or ahead by more than `jump_s` (a recording with a gap
    or a camera reset, stamps of another clock), would make every later frame due long ago (all skipped as late)
    or far ahead (the replay stalled for the gap): pacing starts afresh there, due now, and `jumped` says by how
    far (s; None: no jump at the last frame)."""

    def __init__(self, rate: float, start_wall: float, jump_s: float) -> None:
        self.rate, self.start_wall, self.jump_s = rate, start_wall, jump_s
        self._origin: tuple[float, int] | None = None
        self._last: int | None = None
        self.jumped: float | None = None

    def due(self, stamp_ns: int, now: float) -> float:
        """The wall time the frame of stamp_ns is due (the same frame asked again: the same answer)."""
        self.jumped = None
        if self._origin is None:
            self._origin = (self.start_wall, stamp_ns)
        elif stamp_ns != self._last and (jump := stamp_jump(self._last, stamp_ns, self.jump_s)) is not None:
            self._origin, self.jumped = (now, stamp_ns), jump
        self._last = stamp_ns
        start_wall, start_stamp = self._origin
        return start_wall + (stamp_ns - start_stamp) * 1e-9 / self.rate

