"""Reading rig bags: image decoding (encodings, row padding, byte order) and reading a sample bag's frames."""

from __future__ import annotations

import dataclasses
import itertools
from types import SimpleNamespace

import numpy as np
import pytest
from support.bag_edit import DEPTH_FIRST, INFO_FIRST, rewrite_bag

from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.io.bag import INFO_WAIT, BagError, DepthFrameMatcher, camera_topics, image_to_array, read_camera_frames


def _image(array: np.ndarray, encoding: str, big_endian: bool = False, pad: int = 0):
    height, width = array.shape[:2]
    data = array.astype(array.dtype.newbyteorder(">" if big_endian else "<")).tobytes()
    row = len(data) // height
    padded = b"".join(data[r * row:(r + 1) * row] + b"\0" * pad for r in range(height))
    return SimpleNamespace(encoding=encoding, is_bigendian=int(big_endian), height=height, width=width,
                           step=row + pad, data=np.frombuffer(padded, np.uint8))


def test_depth_and_colour_encodings_decode_exactly():
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    assert np.array_equal(image_to_array(_image(depth, "16UC1", pad=6)), depth)
    assert np.array_equal(image_to_array(_image(depth, "16UC1", big_endian=True)), depth)
    metres = depth.astype(np.float32) / 1e4
    assert np.array_equal(image_to_array(_image(metres, "32FC1", pad=4)), metres)
    rgb = np.random.default_rng(0).integers(0, 255, (3, 4, 3), dtype=np.uint8)
    assert np.array_equal(image_to_array(_image(rgb, "rgb8")), rgb)
    assert np.array_equal(image_to_array(_image(rgb[:, :, ::-1].copy(), "bgr8")), rgb)
    with pytest.raises(BagError, match="not supported"):
        image_to_array(_image(depth, "yuv422"))
    truncated = _image(depth, "16UC1")
    truncated.data = truncated.data[:10]
    with pytest.raises(BagError, match="truncated"):
        image_to_array(truncated)


def test_sample_bag_frames_and_topic_remapping(bags_dir):
    bag = bags_dir / "straight"
    config = load_rig_config(bag / "rig.yaml")
    frames = read_camera_frames(bag, config, max_frames=2)
    assert set(frames) == {"cam_a", "cam_b"}
    for camera, camera_frames in frames.items():
        assert len(camera_frames) == 2
        frame = camera_frames[0]
        assert frame.camera == camera and frame.depth.dtype == np.uint16
        assert frame.depth.shape == (frame.intrinsics.height, frame.intrinsics.width)
        assert frame.color.shape == frame.depth.shape + (3,)
    assert camera_topics(config, "cam_a")["depth"] == "/ntcr/cam_a/depth/image_rect_raw"
    remapped = read_camera_frames(bag, config, topic_overrides={"cam_a.depth": "/nowhere"})
    assert frames["cam_b"] and not remapped["cam_a"]
    with pytest.raises(BagError, match="no PointCloud2|none of the configured camera topics"):
        read_camera_frames(bag, config, source="points")
    with pytest.raises(BagError, match="does not exist"):
        read_camera_frames(bags_dir / "no_such_bag", config)


def _instant_messages(bag) -> list[tuple[str, str, object]]:
    """cam_a's messages of the sample bag (camera, kind, message), as the bag holds them."""
    from rosbags.highlevel import AnyReader

    kinds = {"depth/image_rect_raw": "depth", "depth/camera_info": "depth_info", "color/image_rect_raw": "color"}
    messages = []
    with AnyReader([bag]) as reader:
        for connection, _, raw in reader.messages():
            kind = next((k for end, k in kinds.items() if connection.topic.endswith("/cam_a/" + end)), None)
            if kind is not None:
                messages.append((kind, reader.deserialize(raw, connection.msgtype)))
    return messages


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


@pytest.mark.parametrize("order", list(itertools.permutations(["depth", "depth_info", "color"])),
                         ids=lambda order: "-".join(order))
def test_depth_info_and_colour_of_an_instant_pair_in_any_order(bags_dir, order):
    # issue 65: a depth image written before its camera_info at the same stamp was dropped ("depth images came
    # before any camera_info and were skipped"), one frame in four of such a recording
    messages = _instant_messages(bags_dir / "bend45")
    by_stamp: dict[int, dict[str, object]] = {}
    for kind, msg in messages:
        by_stamp.setdefault(_stamp(msg), {})[kind] = msg
    matcher = DepthFrameMatcher(has_color=True)
    frames = []
    for stamp in sorted(by_stamp):
        for kind in order:
            frames += matcher.add(kind, by_stamp[stamp][kind])
    frames += matcher.finish()
    assert [f.stamp_ns for f in frames] == sorted(by_stamp)  # every frame, in order, none skipped
    assert matcher.frames_without_info == 0
    for frame in frames:  # each with its own instant's camera_info and colour
        assert frame.info is by_stamp[frame.stamp_ns]["depth_info"]
        assert frame.color is by_stamp[frame.stamp_ns]["color"]


def test_matcher_waits_a_bounded_time_for_what_never_comes(bags_dir):
    messages = _instant_messages(bags_dir / "bend45")
    depths = [m for k, m in messages if k == "depth"]
    infos = [m for k, m in messages if k == "depth_info"]
    # no colour ever: each frame goes without once the next depth image has come
    matcher = DepthFrameMatcher(has_color=True)
    assert matcher.add("depth_info", infos[0]) == []
    assert matcher.add("depth", depths[0]) == []
    released = matcher.add("depth", depths[1])
    assert [(f.stamp_ns, f.color) for f in released] == [(_stamp(depths[0]), None)]
    # the camera_info comes only after several depth images: they wait for it and take it (none is skipped)
    matcher = DepthFrameMatcher(has_color=False)
    assert all(matcher.add("depth", msg) == [] for msg in depths[:3])
    released = matcher.add("depth_info", infos[2])
    assert [f.stamp_ns for f in released] == [_stamp(m) for m in depths[:3]]
    assert matcher.frames_without_info == 0
    # no camera_info at all: given up after INFO_WAIT later depth images (bounded memory), and counted
    matcher = DepthFrameMatcher(has_color=False)
    for index in range(INFO_WAIT + 2):
        assert matcher.add("depth", dataclasses.replace(depths[0], header=dataclasses.replace(
            depths[0].header, stamp=dataclasses.replace(depths[0].header.stamp, nanosec=index)))) == []
    assert matcher.frames_without_info == 2 and len(matcher._pending) == INFO_WAIT
    assert matcher.finish() == [] and matcher.frames_without_info == INFO_WAIT + 2


@pytest.mark.parametrize("order", [INFO_FIRST, DEPTH_FIRST], ids=["info_first", "depth_first"])
def test_bags_written_either_way_give_every_frame(bags_dir, tmp_path, order):
    # the offline command's reader and camera_node's bag source, on bags whose instants are written in either
    # order: the same four frames per camera, each with its camera_info and colour, and no warning for it
    from ntcr_recon.core.config.rig import TopicConfig
    from ntcr_recon.io.bag import iter_camera_frames
    from ntcr_recon.io.camera_sources import BagSource

    bag = rewrite_bag(bags_dir / "bend45", tmp_path / "bag", instant_order=order)
    written = [kind for kind, _ in _instant_messages(bag)][:3]
    assert written == [{"depth/camera_info": "depth_info", "depth/image_rect_raw": "depth",
                        "color/image_rect_raw": "color"}[end] for end in order if end != "color/camera_info"]
    config = load_rig_config(bag / "rig.yaml")
    reference = read_camera_frames(bags_dir / "bend45", config)
    facts = {}
    frames = list(iter_camera_frames(bag, config, facts=facts))
    assert sorted((f.camera, f.stamp_ns) for f in frames) == sorted(
        (f.camera, f.stamp_ns) for camera_frames in reference.values() for f in camera_frames)
    assert len(frames) == 8 and all(fact.frames_without_info == 0 for fact in facts.values())
    expected = {(f.camera, f.stamp_ns): f for camera_frames in reference.values() for f in camera_frames}
    for frame in frames:
        twin = expected[(frame.camera, frame.stamp_ns)]
        assert np.array_equal(frame.depth, twin.depth) and np.array_equal(frame.color, twin.color)
        assert frame.intrinsics == twin.intrinsics
    source = list(BagSource(bag, "cam_a", TopicConfig()))
    assert [f.stamp_ns for f in source] == [f.stamp_ns for f in reference["cam_a"]]
    assert all(f.color is not None and _stamp(f.camera_info) == f.stamp_ns for f in source)


def test_a_replays_pacing_starts_afresh_where_its_stamps_jump():
    from ntcr_recon.io.camera_sources import Pacer

    period = 33_333_333
    pacer = Pacer(rate=0.5, start_wall=100.0, jump_s=0.5)
    assert pacer.due(10 * period, now=100.0) == 100.0
    assert pacer.due(11 * period, now=100.0) == pytest.approx(100.0 + 2 * period * 1e-9)  # half speed
    assert pacer.due(11 * period, now=101.0) == pytest.approx(100.0 + 2 * period * 1e-9) and pacer.jumped is None
    # a camera reset: its stamps start again from 0. Due now, not 0.7 s before the replay began (every later frame
    # would have been skipped as late)
    assert pacer.due(0, now=105.0) == 105.0 and pacer.jumped == pytest.approx(-11 * period * 1e-9)
    assert pacer.due(period, now=105.0) == pytest.approx(105.0 + 2 * period * 1e-9) and pacer.jumped is None
    # an hour's gap in the recording: due now, not an hour on (the replay stalled for it)
    hour = 3600 * 10**9
    assert pacer.due(period + hour, now=106.0) == 106.0 and pacer.jumped == pytest.approx(3600.0)
    # a gap within the jump bound is waited for, as recorded
    assert pacer.due(period + hour + 10 * period, now=106.0) == pytest.approx(106.0 + 20 * period * 1e-9)
