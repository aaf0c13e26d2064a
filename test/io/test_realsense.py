"""camera_node's `realsense` and `file` sources without hardware: a pyrealsense2 software device (the D405's
layout) fed with synthetic frames through the real librealsense machinery, and recordings made from it."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pyrealsense2 as rs
import pytest
from support import tiny_rig
from support.software_d405 import SoftwareD405

from ntcr_recon.core.cloud.deproject import Intrinsics, depth_to_points
from ntcr_recon.core.config.rig import CameraConfig
from ntcr_recon.core.robot.geometry import TubeGeometry
from ntcr_recon.core.robot.kinematics import TubeShape
from ntcr_recon.io.camera_sources import SourceError
from ntcr_recon.io.realsense import NO_DEVICE, RealSenseSource, RecordingSource
from ntcr_recon.sim.simulate import Simulation
from ntcr_recon.sim.stereo import StereoEmulation, emulate_depth

INTRINSICS = tiny_rig.INTRINSICS
UNIT = tiny_rig.DEPTH_UNIT
SERIAL = "230322270001"
START_MS, PERIOD_MS = 1_700_000_000_000.0, 1000.0 / 30


class ListLog:
    """Collects what a source logs (it takes any object with info/warning, like rclpy's logger)."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def info(self, text: str) -> None:
        self.lines.append(text)

    warning = error = info


def camera(serial: str = SERIAL, **overrides) -> CameraConfig:
    return CameraConfig(name="cam_a", serial_number=serial, width=INTRINSICS.width, height=INTRINSICS.height,
                        fps=30.0, depth_unit=UNIT, **overrides)


def scene_frame(index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(depth in metres, raw 0.1 mm depth, colour, timestamp in ms) of frame `index` of the tiny rig's tube."""
    depth_m = tiny_rig.render_tube("cam_a") + index * 1e-3 * (tiny_rig.render_tube("cam_a") > 0)
    return depth_m, np.round(depth_m / UNIT).astype(np.uint16), tiny_rig.frame_color("cam_a", index), \
        START_MS + index * PERIOD_MS


def collect(iterator, count: int, timeout: float = 5.0) -> list:
    """The next `count` frames of a source iterated in a thread (a live source blocks between frames)."""
    frames: list = []

    def pump():
        for frame in iterator:
            frames.append(frame)
            if len(frames) == count:
                return

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    thread.join(timeout)
    return frames


def test_fed_frames_come_out_as_source_frames():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL)
    source = RealSenseSource(camera(), devices=lambda: [d405.device])
    frames = iter(source)
    try:
        for index in range(3):
            depth_m, raw, color, stamp_ms = scene_frame(index)
            d405.feed(raw, color, stamp_ms, index)
            frame = next(frames)
            assert frame.stamp_ns == round(stamp_ms * 1e6)  # the frame's own timestamp
            assert frame.depth_unit == UNIT  # 0.1 mm kept
            np.testing.assert_array_equal(frame.depth, raw)
            valid = depth_m > 0
            assert valid.sum() > 100
            assert np.abs(frame.depth[valid] * frame.depth_unit - depth_m[valid]).max() <= UNIT / 2 + 1e-12
            assert frame.intrinsics == INTRINSICS  # from the stream profile
            np.testing.assert_array_equal(frame.color, color)  # the colour of the same timestamp
    finally:
        source.close()


def test_colour_of_another_resolution_is_aligned_to_depth():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL, color_scale=2)
    depth_m, raw, _, stamp_ms = scene_frame(0)
    color = np.zeros((2 * INTRINSICS.height, 2 * INTRINSICS.width, 3), np.uint8)
    color[..., 0] = np.arange(2 * INTRINSICS.width)[None, :]  # red = colour column, green = colour row
    color[..., 1] = np.arange(2 * INTRINSICS.height)[:, None]
    source = RealSenseSource(camera(), devices=lambda: [d405.device])
    try:
        d405.feed(raw, color, stamp_ms, 0)
        frame = next(iter(source))
    finally:
        source.close()
    assert frame.color.shape == (INTRINSICS.height, INTRINSICS.width, 3)  # on the depth grid
    v, u = np.nonzero(depth_m > 0)
    # rs.align maps depth pixel (u, v) to colour pixel ~(2u, 2v): same viewpoint, twice the focal length.
    assert np.abs(frame.color[v, u, 0].astype(int) - 2 * u).max() <= 1
    assert np.abs(frame.color[v, u, 1].astype(int) - 2 * v).max() <= 1


def test_librealsense_post_processing_filters_run():
    rng = np.random.default_rng(3)
    raw = np.full((INTRINSICS.height, INTRINSICS.width), 900, np.uint16) + rng.integers(-20, 21, (72, 96)).astype(
        np.uint16)
    raw[30:34, 40:44] = 0  # a hole
    outputs = {}
    for name, options in {"none": {}, "all": dict(spatial=True, temporal=True, hole_filling=True)}.items():
        d405 = SoftwareD405(INTRINSICS, serial=SERIAL, color=False)
        source = RealSenseSource(camera(), devices=lambda d=d405: [d.device], **options)
        try:
            d405.feed(raw, None, START_MS, 0)
            outputs[name] = next(iter(source)).depth
        finally:
            source.close()
    np.testing.assert_array_equal(outputs["none"], raw)
    assert np.all(outputs["all"][30:34, 40:44] > 0)  # hole filled
    inside = (slice(5, 25), slice(5, 35))
    assert outputs["all"][inside].std() < 0.7 * raw[inside].astype(float).std()  # edge-preserving smoothing


def test_depth_unit_is_set_to_the_configured_tenth_of_a_millimetre():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL, depth_unit=1e-3, writable_unit=True)
    source = RealSenseSource(camera(), devices=lambda: [d405.device])
    source.close()
    assert d405.sensor.get_option(rs.option.depth_units) == pytest.approx(1e-4, rel=1e-6)


def test_a_device_that_refuses_the_unit_keeps_its_own_and_says_so():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL, depth_unit=1e-3)  # read-only 1 mm
    log = ListLog()
    source = RealSenseSource(camera(), devices=lambda: [d405.device], log=log)
    try:
        _, raw, color, stamp_ms = scene_frame(0)
        d405.feed(raw, color, stamp_ms, 0)
        assert next(iter(source)).depth_unit == 1e-3  # the frames carry the unit the depth really has
    finally:
        source.close()
    assert any("depth unit is 0.001 m, not the configured 0.0001" in line for line in log.lines)


def test_no_device_is_a_clear_error():
    with pytest.raises(SourceError, match=NO_DEVICE):
        RealSenseSource(camera(), devices=lambda: list(rs.context().query_devices(rs.product_line.sw_only)))
    with pytest.raises(SourceError, match=NO_DEVICE):
        RealSenseSource(camera(), devices=list)


def test_wrong_serial_names_the_wanted_and_the_present_ones():
    devices = [SoftwareD405(INTRINSICS, serial=s).device for s in ("111", "222")]
    with pytest.raises(SourceError, match=r"serial number '999' for camera 'cam_a' \(connected: 111, 222\)"):
        RealSenseSource(camera("999"), devices=lambda: devices)
    with pytest.raises(SourceError, match=r"2 RealSense devices connected \(111, 222\): set cam_a.serial_number"):
        RealSenseSource(camera(""), devices=lambda: devices)


def test_missing_depth_profile_lists_what_the_device_offers():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL)
    with pytest.raises(SourceError, match=r"no z16 depth profile 848x480@30 \(depth profiles: 96x72@30 z16\)"):
        RealSenseSource(CameraConfig(name="cam_a", serial_number=SERIAL), devices=lambda: [d405.device])


def test_a_dropped_device_is_reopened_with_backoff():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL)
    connected = [d405.device]
    log = ListLog()
    source = RealSenseSource(camera(), devices=lambda: list(connected), frame_timeout=0.3, reconnect_period=0.05,
                             log=log)
    received: list = []
    thread = threading.Thread(target=lambda: received.extend(source), daemon=True)
    thread.start()
    try:
        _, raw, color, stamp_ms = scene_frame(0)
        d405.feed(raw, color, stamp_ms, 0)
        deadline = time.monotonic() + 5
        while not received and time.monotonic() < deadline:
            time.sleep(0.01)
        connected.clear()  # unplugged: frames stop, the device is gone
        while not any(NO_DEVICE in line for line in log.lines) and time.monotonic() < deadline:
            time.sleep(0.01)
        connected.append(d405.device)  # plugged back in
        while source.reconnects == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        _, raw, color, stamp_ms = scene_frame(1)
        d405.feed(raw, color, stamp_ms, 1)
        while len(received) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        source.close()
        thread.join(2)
    assert not thread.is_alive()  # close() ends the iteration
    assert [f.stamp_ns for f in received] == [round(scene_frame(i)[3] * 1e6) for i in range(2)]
    assert source.reconnects == 1
    text = "\n".join(log.lines)
    assert "no depth frame for 0.3 s; closing the device and re-opening it" in text
    assert f"{NO_DEVICE}; retrying in 0.1 s" in text  # the second failed attempt waited twice as long
    assert "re-opened (reconnect 1)" in text


def test_hardware_clock_stamps_keep_the_device_intervals_on_the_host_clock():
    d405 = SoftwareD405(INTRINSICS, serial=SERIAL, color=False)
    source = RealSenseSource(camera(), devices=lambda: [d405.device])
    try:
        frames = iter(source)
        stamps = []
        for index, device_ms in enumerate((5.0, 38.5, 105.0)):
            d405.feed(scene_frame(0)[1], None, device_ms, index, domain=rs.timestamp_domain.hardware_clock)
            stamps.append(next(frames).stamp_ns)
    finally:
        source.close()
    assert np.diff(stamps).tolist() == [33_500_000, 66_500_000]
    assert abs(stamps[0] - time.time_ns()) < 10e9


def test_simulated_d405_frames_at_the_default_848x480_profile():
    # The synthetic rig's cam_a (exact rendering + the D405's stereo artefacts) through a software device with
    # the D405's real intrinsics; the source asks for the configuration's default profile, 848x480 at 30 fps.
    shape = TubeShape.from_bend_angle(TubeGeometry(), math.radians(45))
    sim = Simulation(shape, frame_count=1)
    exact = sim.scene.render_exact(sim.cameras[0])
    intrinsics = sim.intrinsics
    d405 = SoftwareD405(intrinsics, serial=SERIAL)
    source = RealSenseSource(CameraConfig(name="cam_a", serial_number=SERIAL), devices=lambda: [d405.device])
    frames = iter(source)
    try:
        for index in range(2):
            raw = emulate_depth(exact.depth, exact.normal, intrinsics, StereoEmulation(),
                                np.random.default_rng(index))
            stamp_ns = 1_767_225_600_000_000_000 + index * 33_333_333
            d405.feed(raw, exact.color, stamp_ns / 1e6, index)
            frame = next(frames)
            np.testing.assert_array_equal(frame.depth, raw)
            np.testing.assert_array_equal(frame.color, exact.color)
            # librealsense stamps are float64 milliseconds: ~0.2 us resolution at today's epoch times.
            assert abs(frame.stamp_ns - stamp_ns) < 1_000
            # librealsense keeps intrinsics in float32, as a real D405 reports them (realsense-ros's K too).
            pinhole = np.float32([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy]).tolist()
            assert frame.intrinsics == Intrinsics(848, 480, *pinhole)
            xyz, _, _ = depth_to_points(frame.depth, frame.intrinsics, frame.depth_unit)
            want, _, _ = depth_to_points(raw, frame.intrinsics, intrinsics.depth_unit)
            assert len(xyz) == (raw > 0).sum() > 10_000
            np.testing.assert_array_equal(xyz, want)  # metres through the 0.1 mm unit, as from a bag
    finally:
        source.close()


# ---- the file source --------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    frames = [scene_frame(i) for i in range(4)]
    path = tmp_path_factory.mktemp("recording") / "d405.db3"
    SoftwareD405(INTRINSICS, serial=SERIAL).record(path, [(raw, color, stamp) for _, raw, color, stamp in frames],
                                                   paced=True)
    return path, frames


def test_recording_plays_back_the_recorded_frames(recording):
    path, frames = recording
    played = list(RecordingSource(path))
    assert len(played) == len(frames)
    for frame, (_, raw, color, stamp_ms) in zip(played, frames, strict=True):
        assert frame.stamp_ns == round(stamp_ms * 1e6)
        np.testing.assert_array_equal(frame.depth, raw)
        np.testing.assert_array_equal(frame.color, color)
        assert frame.depth_unit == UNIT and frame.intrinsics == INTRINSICS


def test_recording_loops_with_stamps_moving_forward(recording):
    path, frames = recording
    source = RecordingSource(path, loop=True)
    played = collect(iter(source), 2 * len(frames) + 1, timeout=10)
    source.close()
    stamps = np.array([f.stamp_ns for f in played])
    first_pass = np.array([round(f[3] * 1e6) for f in frames])
    length = first_pass[-1] - first_pass[0] + round(PERIOD_MS * 1e6)
    np.testing.assert_array_equal(stamps[:8], np.concatenate([first_pass, first_pass + length]))
    np.testing.assert_array_equal(played[5].depth, frames[1][1])


def test_real_time_playback_keeps_the_recorded_pace(recording):
    path, frames = recording
    arrivals = {}
    for real_time in (True, False):
        arrivals[real_time] = [(time.monotonic(), f.stamp_ns) for f in RecordingSource(path, real_time=real_time)]
        assert [stamp for _, stamp in arrivals[real_time]] == [round(f[3] * 1e6) for f in frames]
    span = (len(frames) - 1) * PERIOD_MS / 1000
    paced, fast = (arrivals[flag][-1][0] - arrivals[flag][0][0] for flag in (True, False))
    assert paced > 0.7 * span  # the recording was made at 30 fps: played back over its length
    assert fast < 0.5 * span  # otherwise as fast as it is taken


@pytest.mark.parametrize("name, expected", [("missing.db3", "does not exist"),
                                            ("frames.txt", "is not a librealsense recording")])
def test_bad_recording_paths_are_refused(tmp_path, name, expected):
    if name.endswith(".txt"):
        (tmp_path / name).write_text("not a recording")
    with pytest.raises(SourceError, match=expected):
        RecordingSource(tmp_path / name)


def test_a_corrupt_recording_is_refused(tmp_path):
    (tmp_path / "broken.db3").write_bytes(b"SQLite format 3\x00" + bytes(100))
    with pytest.raises(SourceError, match="cannot play recording"):
        RecordingSource(tmp_path / "broken.db3")


def test_legacy_bag_recording_plays_back(repo_root):
    # Made by pyrealsense2 2.54 (test/data/make_legacy_bag.py): the recorder here writes .db3 only.
    data = repo_root / "test" / "data"
    recorded = np.load(data / "legacy_d405_frames.npz")
    played = list(RecordingSource(data / "legacy_d405.bag"))
    assert [f.stamp_ns for f in played] == [round(t * 1e6) for t in recorded["timestamp_ms"]]
    for frame, depth, color in zip(played, recorded["depth"], recorded["color"], strict=True):
        np.testing.assert_array_equal(frame.depth, depth)
        np.testing.assert_array_equal(frame.color, color)
        assert frame.depth_unit == UNIT
        assert frame.intrinsics.width == 48 and frame.intrinsics.fx == 150.0
