"""Reading a rig's rosbag2 bag (mcap or sqlite3) with `rosbags`: depth + camera_info (+ colour) per camera,
or PointCloud2 per camera, as core.fusion.CameraFrame lists ready for pairing.

Public API:
    BagError(ValueError)                                   missing topics, truncated or unreadable bag
    read_camera_frames(bag, config, source="auto", topics=None, max_frames=0) -> dict[camera, list[CameraFrame]]
    image_to_array(msg) -> np.ndarray                      16UC1/mono16 -> uint16, 32FC1 -> float32, colour -> RGB
    camera_topics(config, camera) -> dict[kind, topic]     the configured topic names of a camera
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ntcr_recon.core.config import RigConfig
from ntcr_recon.core.deproject import Intrinsics
from ntcr_recon.core.fusion import CameraFrame
from ntcr_recon.io.pointcloud import cloud_from_msg, stamp_to_ns

_KINDS = ("depth", "depth_info", "color", "points")


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


def read_camera_frames(bag: str | Path, config: RigConfig, source: str = "auto",
                       topic_overrides: dict[str, str] | None = None, max_frames: int = 0,
                       ) -> dict[str, list[CameraFrame]]:
    """Every configured camera's frames in the bag (sorted by stamp), from depth images or PointCloud2.

    source: "depth", "points" or "auto" (depth when the bag has the depth topics, else points).
    max_frames > 0 keeps only the first frames of each camera.
    """
    from rosbags.highlevel import AnyReader

    bag = Path(bag)
    if not bag.exists():
        raise BagError(f"bag {bag} does not exist")
    wanted = {name: camera_topics(config, name, topic_overrides) for name in config.camera_names}
    try:
        with AnyReader([bag]) as reader:
            available = {c.topic for c in reader.connections}
            source = _choose_source(bag, wanted, available, source)
            kinds = ("depth", "depth_info", "color") if source == "depth" else ("points",)
            by_topic = {wanted[name][kind]: (name, kind) for name in wanted for kind in kinds}
            connections = [c for c in reader.connections if c.topic in by_topic]
            messages: dict[str, dict[str, list]] = {name: {kind: [] for kind in kinds} for name in wanted}
            for connection, _, raw in reader.messages(connections=connections):
                name, kind = by_topic[connection.topic]
                bucket = messages[name][kind]
                if max_frames and kind in ("depth", "points") and len(bucket) >= max_frames:
                    continue
                bucket.append(reader.deserialize(raw, connection.msgtype))
    except BagError:
        raise
    except Exception as error:  # rosbags raises several types for a damaged file  # noqa: BLE001
        cause = f"{type(error).__name__}: {error}"
        raise BagError(f"cannot read bag {bag}: it is truncated or corrupt ({cause})") from error
    frames = {name: (_depth_frames(name, messages[name], config) if source == "depth"
                     else _point_frames(name, messages[name])) for name in wanted}
    if not any(frames.values()):
        raise BagError(f"bag {bag} has the configured topics but no {source} frame in them")
    return frames


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


def _depth_frames(name: str, messages: dict[str, list], config: RigConfig) -> list[CameraFrame]:
    infos = sorted(messages["depth_info"], key=lambda m: stamp_to_ns(m.header.stamp))
    if not infos:
        return []
    info_stamps = np.array([stamp_to_ns(m.header.stamp) for m in infos])
    colours = {stamp_to_ns(m.header.stamp): m for m in messages["color"]}
    frames = []
    for msg in messages["depth"]:
        stamp = stamp_to_ns(msg.header.stamp)
        info = infos[max(int(np.searchsorted(info_stamps, stamp, side="right")) - 1, 0)]
        depth = image_to_array(msg)
        unit = 1.0 if depth.dtype.kind == "f" else None   # 32FC1 is metres; 16UC1 uses the configured unit
        colour_msg = colours.get(stamp)
        colour = image_to_array(colour_msg) if colour_msg is not None else None
        frames.append(CameraFrame(name, stamp, depth=depth, intrinsics=Intrinsics.from_camera_info(info),
                                  color=colour, depth_unit=unit))
    return sorted(frames, key=lambda f: f.stamp_ns)


def _point_frames(name: str, messages: dict[str, list]) -> list[CameraFrame]:
    frames = []
    for msg in messages["points"]:
        xyz, rgb = cloud_from_msg(msg)
        organised = int(msg.width) if int(msg.height) > 1 else 0
        frames.append(CameraFrame(name, stamp_to_ns(msg.header.stamp), points=xyz.astype(np.float64), rgb=rgb,
                                  organised_width=organised))
    return sorted(frames, key=lambda f: f.stamp_ns)
