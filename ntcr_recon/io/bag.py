"""Reading a rig's rosbag2 bag (mcap or sqlite3) with `rosbags`, streamed: one pass, one message at a time.

The one place where a camera's depth image, the camera_info in force at its stamp and the colour image of
the same stamp are put together (`DepthFrameMatcher`); camera_node's `BagSource` and the offline command's
`iter_camera_frames` both read through `BagStream`, so both pair them the same way and hold only the few
messages still waiting for a partner, whatever the bag's length.

Public API:
    BagError(ValueError)                                  missing topics, truncated or unreadable bag
    camera_topics(config, camera, overrides=None) -> dict[kind, topic]
    image_to_array(msg) -> np.ndarray                     16UC1/mono16 -> uint16, 32FC1 -> float32, colour -> RGB
    DepthMessages, DepthFrameMatcher                       depth + camera_info (+ colour) of one frame, matched by
                                                          stamp in whatever order the bag holds them
    BagStream(bag, topics_by_camera, mode)                 iterate: (camera, DepthMessages | PointCloud2 message)
    iter_camera_frames(bag, config, source="auto", topic_overrides=None, max_frames=0, facts=None)
        -> iterator of core.cloud.fusion.CameraFrame, in the bag's order
    read_camera_frames(...) -> dict[camera, list[CameraFrame]]   the same, collected (small bags, tests)
"""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import CameraFrame
from ntcr_recon.core.cloud.pairing import InForce
from ntcr_recon.core.config.rig import RigConfig
from ntcr_recon.core.quality.inputs import CameraInput
from ntcr_recon.io.pointcloud import cloud_from_msg, stamp_to_ns

_KINDS = ("depth", "depth_info", "color", "points")
DEPTH_KINDS = ("depth", "depth_info", "color")
# camera_info messages remembered to find the one in force at a depth frame's stamp (a driver publishes it
# with every image; a few cover any interleaving of the topics in the bag)
INFO_HISTORY = 8
# depth images that may come after one still without any camera_info before it is given up (bounded memory)
INFO_WAIT = 8
# colour images kept waiting for the depth frame of their stamp; older ones are dropped (bounded memory)
COLOR_WAIT = 4


class BagError(ValueError):
    """A bag that cannot feed the reconstruction; the message names the bag and the cause."""


def camera_topics(config: RigConfig, camera: str, overrides: dict[str, str] | None = None) -> dict[str, str]:
    """kind -> topic for one camera, from the configuration's `topics` section, then remapped by overrides
    (keys `<camera>.<kind>` or plain topic -> topic)."""
    topics = {kind: config.topics.camera_topic(camera, kind) for kind in _KINDS}
    for kind, topic in list(topics.items()):
        if overrides:
            topics[kind] = overrides.get(f"{camera}.{kind}", overrides.get(topic, topic))
    return topics


def image_to_array(msg) -> np.ndarray:
    """An Image message as an array: depth as uint16 (16UC1, mono16) or float32 metres (32FC1), colour as
    (H, W, 3) uint8 RGB (rgb8, bgr8, rgba8, bgra8, mono8). Row padding and big-endian data are handled."""
    encoding = msg.encoding.lower()
    layouts = {"16uc1": ("u2", 1), "mono16": ("u2", 1), "32fc1": ("f4", 1), "rgb8": ("u1", 3), "bgr8": ("u1", 3),
               "rgba8": ("u1", 4), "bgra8": ("u1", 4), "mono8": ("u1", 1), "8uc1": ("u1", 1), "8uc3": ("u1", 3)}
    if encoding not in layouts:
        raise BagError(f"image encoding {msg.encoding!r} is not supported (16UC1, 32FC1, rgb8, bgr8, rgba8, bgra8)")
    kind, channels = layouts[encoding]
    dtype = np.dtype(kind).newbyteorder(">" if msg.is_bigendian else "<")
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data, dtype=np.uint8)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes or data.size < step * height:
        raise BagError(f"image of {width}x{height} {msg.encoding} has {data.size} bytes (step {step}): truncated")
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    array = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels).astype(dtype.newbyteorder("="))
    if encoding in ("bgr8", "bgra8"):
        array = array[:, :, [2, 1, 0]]
    elif channels == 4:
        array = array[:, :, :3]
    elif channels == 1 and kind == "u1":
        array = np.repeat(array, 3, axis=2)
    return array[:, :, 0] if channels == 1 and kind != "u1" else array


@dataclass(frozen=True)
class DepthMessages:
    """One depth frame's messages, matched and not yet decoded: the depth image, the camera_info in force at
    its stamp (with its intrinsics, computed once per camera_info) and the colour image of the same stamp."""

    stamp_ns: int
    depth: Any
    info: Any
    intrinsics: Intrinsics
    color: Any = None

    def decode(self) -> tuple[np.ndarray, float | None, np.ndarray | None]:
        """(depth array, depth unit: 1.0 for 32FC1 metres, None = the configured unit for raw 16UC1, RGB)."""
        depth = image_to_array(self.depth)
        unit = 1.0 if depth.dtype.kind == "f" else None
        return depth, unit, None if self.color is None else image_to_array(self.color)


class DepthFrameMatcher:
    """Puts one camera's depth, camera_info and colour messages together by stamp, whatever their order in
    the bag: `ros2 bag record` gives none among the messages of one instant, so a depth image may come before
    or after its camera_info and its colour.

    A depth image waits (bounded) for what belongs to it: it is released once it has the camera_info of its
    own stamp (or one stamped later has come by) and, when the bag has colour, its colour image; or, at the
    latest, when the next depth image of the camera comes, with the camera_info in force at its stamp (the
    newest stamped at or before it, else the nearest later) and without colour if none came. Only a depth
    image for which no camera_info at all has come by the time `INFO_WAIT` later depth images have (or the bag
    ends) cannot be deprojected: it is counted in `frames_without_info`. Frames come out in the order of their
    depth images; colour images waiting for their depth image are kept up to `COLOR_WAIT`."""

    def __init__(self, has_color: bool) -> None:
        self.has_color = has_color
        self.frames_without_info = 0
        self._infos = InForce(INFO_HISTORY)  # (camera_info, its Intrinsics) by stamp
        self._colors: dict[int, Any] = {}
        self._pending: deque[_PendingDepth] = deque()  # depth images not yet released, in their order

    def add(self, kind: str, msg) -> list[DepthMessages]:
        """Take one message; returns the frames it completes (in the order of their depth images)."""
        stamp = stamp_to_ns(msg.header.stamp)
        if kind == "depth_info":
            self._infos.add(stamp, (msg, Intrinsics.from_camera_info(msg)))
        elif kind == "color":
            waiting = next((p for p in self._pending if p.stamp_ns == stamp and p.color is None), None)
            if waiting is not None:
                waiting.color = msg
            else:
                self._colors[stamp] = msg
                for old in sorted(self._colors)[:-COLOR_WAIT]:
                    del self._colors[old]
        else:
            for pending in self._pending:  # the next depth image: nothing more is waited for but a camera_info
                pending.superseded += 1
            self._pending.append(_PendingDepth(stamp, msg, self._colors.pop(stamp, None)))
        return self._release()

    def finish(self) -> list[DepthMessages]:
        """The frames still waiting when the bag ends, with what they have."""
        for pending in self._pending:
            pending.superseded = INFO_WAIT
        return self._release()

    def _release(self) -> list[DepthMessages]:
        done = []
        while self._pending:
            pending = self._pending[0]
            info = self._info_at(pending.stamp_ns)
            own_info = info is not None and (info[0] == pending.stamp_ns
                                             or self._infos.any_after(pending.stamp_ns))
            complete = own_info and (pending.color is not None or not self.has_color)
            if not (complete or pending.superseded and info is not None):
                if pending.superseded < INFO_WAIT:
                    break
                self._pending.popleft()  # no camera_info at all came for it: it cannot be deprojected
                self.frames_without_info += 1
                continue
            self._pending.popleft()
            done.append(DepthMessages(pending.stamp_ns, pending.depth, info[1], info[2], pending.color))
        return done

    def _info_at(self, stamp: int) -> tuple[int, Any, Intrinsics] | None:
        entry = self._infos.at(stamp)
        return None if entry is None else (entry[0], *entry[1])


@dataclass
class _PendingDepth:
    stamp_ns: int
    depth: Any
    color: Any = None
    superseded: int = 0  # depth images of the camera that came after it


@contextlib.contextmanager
def open_bag(bag: Path):
    """An open rosbags AnyReader (Jazzy message types for bags that carry no definitions); BagError when the
    bag cannot be opened."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    problem = bag_problem(Path(bag))
    if problem:
        raise BagError(problem)
    try:
        reader = AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as error:  # rosbags raises several types for a damaged or foreign file  # noqa: BLE001
        raise BagError(_unreadable(bag, error)) from error
    try:
        yield reader
    finally:
        reader.close()


# Files rosbags reads as a bag by themselves: rosbag2's storage files, and ROS 1 bags.
BAG_FILE_SUFFIXES = (".mcap", ".db3", ".bag")


def bag_problem(bag: Path) -> str | None:
    """Why `bag` cannot be a bag at all (missing, a directory without metadata.yaml, another kind of file), or
    None: said before reading starts, in the user's terms rather than the reader's."""
    if not bag.exists():
        return f"bag {bag} does not exist"
    if bag.is_dir() and not (bag / "metadata.yaml").is_file():
        return (f"bag {bag} is a directory without metadata.yaml, so no rosbag2 bag (a recording that was "
                "interrupted gets one from `ros2 bag reindex`)")
    if not bag.is_dir() and bag.suffix not in BAG_FILE_SUFFIXES:
        return (f"{bag} is not a bag: give a rosbag2 directory (with metadata.yaml) or a "
                f"{'/'.join(BAG_FILE_SUFFIXES)} file")
    return None


def _unreadable(bag: Path, error: Exception) -> str:
    return f"cannot read bag {bag}: it is truncated or corrupt ({type(error).__name__}: {error})"


class BagStream:
    """One pass over a bag: for each camera (name -> kind -> topic), in the bag's order, its depth frames
    matched by a DepthFrameMatcher (mode "depth") or its PointCloud2 messages as recorded (mode "points").
    Iterating yields (camera, DepthMessages | PointCloud2 message); nothing is decoded beyond the message, and
    only the messages waiting for a partner are held. A bag that breaks off midway raises BagError."""

    def __init__(self, bag: str | Path, topics_by_camera: dict[str, dict[str, str]], mode: str) -> None:
        self.bag = Path(bag)
        self.topics_by_camera = topics_by_camera
        self.mode = mode
        self.matchers: dict[str, DepthFrameMatcher] = {}

    def __iter__(self) -> Iterator[tuple[str, Any]]:
        kinds = DEPTH_KINDS if self.mode == "depth" else ("points",)
        route = {topics[kind]: (camera, kind) for camera, topics in self.topics_by_camera.items() for kind in kinds}
        with open_bag(self.bag) as reader:
            connections = [c for c in reader.connections if c.topic in route]
            present = {c.topic for c in connections}
            self.matchers = {camera: DepthFrameMatcher(topics["color"] in present)
                             for camera, topics in self.topics_by_camera.items()}
            messages = reader.messages(connections=connections)
            while True:
                try:
                    connection, _, raw = next(messages)
                    msg = reader.deserialize(raw, connection.msgtype)
                except StopIteration:
                    break
                except Exception as error:  # a chunk cut off or damaged midway  # noqa: BLE001
                    raise BagError(_unreadable(self.bag, error)) from error
                camera, kind = route[connection.topic]
                if self.mode == "points":
                    yield camera, msg
                    continue
                for frame in self.matchers[camera].add(kind, msg):
                    yield camera, frame
            for camera, matcher in self.matchers.items():
                for frame in matcher.finish():
                    yield camera, frame


def iter_camera_frames(bag: str | Path, config: RigConfig, source: str = "auto",
                       topic_overrides: dict[str, str] | None = None, max_frames: int = 0,
                       facts: dict[str, CameraInput] | None = None) -> Iterator[CameraFrame]:
    """Every configured camera's frames in the bag, decoded one at a time in the bag's order, from depth
    images or PointCloud2.

    source: "depth", "points" or "auto" (depth when the bag has the depth topics, else points).
    max_frames > 0 keeps only the first frames of each camera (the rest is not decoded).
    facts: camera -> CameraInput, filled in while reading (frames, byte order, raw depth quantisation).
    """
    bag = Path(bag)
    wanted = {name: camera_topics(config, name, topic_overrides) for name in config.camera_names}
    with open_bag(bag) as reader:
        available = {c.topic for c in reader.connections}
    source = _choose_source(bag, wanted, available, source)
    facts = facts if facts is not None else {}
    for name in wanted:
        facts[name] = CameraInput()
    stream = BagStream(bag, wanted, source)
    taken = dict.fromkeys(wanted, 0)
    for name, item in stream:
        if max_frames and taken[name] >= max_frames:
            if all(count >= max_frames for count in taken.values()):
                break  # every camera has its frames: the rest of the bag is not read
            continue
        taken[name] += 1
        if source == "points":
            facts[name].frames += 1
            yield _point_frame(name, item)
            continue
        depth, unit, colour = item.decode()
        facts[name].observe_depth(depth, bool(item.depth.is_bigendian))
        yield CameraFrame(name, item.stamp_ns, depth=depth, intrinsics=item.intrinsics, color=colour, depth_unit=unit)
    for name, matcher in stream.matchers.items():
        facts[name].frames_without_info = matcher.frames_without_info
    if not any(taken.values()):
        raise BagError(f"bag {bag} has the configured topics but no {source} frame in them")


def read_camera_frames(bag: str | Path, config: RigConfig, source: str = "auto",
                       topic_overrides: dict[str, str] | None = None, max_frames: int = 0,
                       ) -> dict[str, list[CameraFrame]]:
    """iter_camera_frames collected per camera, sorted by stamp: for small bags (tests, benchmarks)."""
    frames: dict[str, list[CameraFrame]] = {name: [] for name in config.camera_names}
    for frame in iter_camera_frames(bag, config, source, topic_overrides, max_frames):
        frames[frame.camera].append(frame)
    return {name: sorted(camera_frames, key=lambda f: f.stamp_ns) for name, camera_frames in frames.items()}


def _choose_source(bag: Path, wanted: dict[str, dict[str, str]], available: set[str], source: str) -> str:
    has_depth = [n for n, t in wanted.items() if t["depth"] in available and t["depth_info"] in available]
    has_points = [n for n, t in wanted.items() if t["points"] in available]
    if source == "auto":
        source = "depth" if has_depth else "points" if has_points else ""
    if source == "depth" and has_depth or source == "points" and has_points:
        return source
    expected = sorted(t[k] for t in wanted.values() for k in (("depth", "depth_info") if source != "points"
                                                               else ("points",)))
    if source in ("", "depth"):
        expected += sorted(t["points"] for t in wanted.values())
    raise BagError(f"bag {bag} has none of the configured camera topics (expected e.g. {', '.join(expected[:4])}; "
                   f"the bag has: {', '.join(sorted(available)) or 'no topics'}); remap them with --topic")


def _point_frame(name: str, msg) -> CameraFrame:
    xyz, rgb = cloud_from_msg(msg)
    organised = int(msg.width) if int(msg.height) > 1 else 0
    return CameraFrame(name, stamp_to_ns(msg.header.stamp), points=xyz.astype(np.float64), rgb=rgb,
                       organised_width=organised)
