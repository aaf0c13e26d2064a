"""Reading rig bags: image decoding (encodings, row padding, byte order) and reading a sample bag's frames."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ntcr_recon.core.config import load_rig_config
from ntcr_recon.io.bag import BagError, camera_topics, image_to_array, read_camera_frames


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
