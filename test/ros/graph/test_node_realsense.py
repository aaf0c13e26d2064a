"""camera_node (its own process) on the pyrealsense2 sources: a librealsense recording made here from a software
D405 replays as the same clouds the core deprojects from its frames; a live source without its camera waits for
it (log line, diagnostics ERROR), or with wait_for_device:=false is refused by name."""

from __future__ import annotations

import subprocess
import time

import numpy as np
import pyrealsense2 as rs
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, PointCloud2
from support import tiny_rig
from support.ros_graph import VENV_BIN, RosGraph
from support.software_d405 import SoftwareD405

from ntcr_recon.core.cloud.deproject import crop_window, depth_to_points
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.io.pointcloud import cloud_from_msg, stamp_to_ns
from ntcr_recon.io.realsense import NO_DEVICE
from ntcr_recon.ros.camera_node import WAITING_LOG_PERIOD_S

COLLECT_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)
COLLECT_RELIABLE_DIAGNOSTICS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
ABSENT = "no-such-camera"  # a serial no device has (and not all digits: ROS would read that as an integer)
FRAMES, START_MS, PERIOD_MS = 4, 1_700_000_000_000.0, 1000.0 / 30


def recorded_frame(index: int):
    """Raw 0.1 mm depth (the tube moved 1 mm further away per frame), colour and timestamp of frame `index`."""
    depth_m = tiny_rig.render_tube("cam_a")
    depth_m = np.where(depth_m > 0, depth_m + index * 1e-3, 0.0)
    return (np.round(depth_m / tiny_rig.DEPTH_UNIT).astype(np.uint16), tiny_rig.frame_color("cam_a", index),
            START_MS + index * PERIOD_MS)


@pytest.fixture(scope="module")
def replay(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera_node_file")
    rig = tiny_rig.write_rig(root / "rig.yaml")
    recording = SoftwareD405(tiny_rig.INTRINSICS).record(root / "cam_a.db3",
                                                         [recorded_frame(i) for i in range(FRAMES)])
    with RosGraph() as graph:
        clouds, infos = [], []
        graph.node.create_subscription(PointCloud2, "/ntcr/cam_a/depth/color/points", clouds.append, COLLECT_QOS)
        graph.node.create_subscription(CameraInfo, "/ntcr/cam_a/depth/camera_info", infos.append, COLLECT_QOS)
        graph.start("camera_node", "--params-file", str(rig), "-p", "camera:=cam_a", "-p", "source:=file",
                    "-p", f"file_path:={recording}")
        assert graph.spin_until(lambda: len(clouds) >= FRAMES and len(infos) >= FRAMES, 30), graph.all_logs()
        yield clouds, infos, load_rig_config(rig)


def test_file_source_publishes_the_recorded_frames_deprojected_by_the_core(replay):
    clouds, _, config = replay
    window = crop_window(tiny_rig.INTRINSICS, config.cameras["cam_a"].extrinsic, *config.crop_box())
    assert [stamp_to_ns(c.header.stamp) for c in clouds] == [round(recorded_frame(i)[2] * 1e6)
                                                             for i in range(FRAMES)]
    for index, msg in enumerate(clouds):
        depth, color, _ = recorded_frame(index)
        want_xyz, want_rgb, _ = depth_to_points(depth, tiny_rig.INTRINSICS, tiny_rig.DEPTH_UNIT, color, window)
        xyz, rgb = cloud_from_msg(msg, drop_nan=True)
        assert msg.header.frame_id == "cam_a_optical_frame"
        assert len(xyz) == len(want_xyz) > 100
        np.testing.assert_allclose(xyz, want_xyz, atol=1e-7)  # 0.1 mm units kept through the recording
        np.testing.assert_array_equal(rgb, want_rgb)


def test_file_source_publishes_camera_info_from_the_stream_intrinsics(replay):
    clouds, infos, _ = replay
    i = tiny_rig.INTRINSICS
    info = infos[0]
    assert (info.width, info.height) == (i.width, i.height)
    np.testing.assert_allclose(info.k, [i.fx, 0, i.cx, 0, i.fy, i.cy, 0, 0, 1], rtol=1e-6)
    assert stamp_to_ns(info.header.stamp) == stamp_to_ns(clouds[0].header.stamp)


def test_realsense_source_without_its_camera_is_refused_by_name(tmp_path):
    rig = tiny_rig.write_rig(tmp_path / "rig.yaml")
    result = subprocess.run([str(VENV_BIN / "camera_node"), "--ros-args", "--params-file", str(rig),
                             "-p", "camera:=cam_a", "-p", "source:=realsense", "-p", f"cam_a.serial_number:={ABSENT}",
                             "-p", "wait_for_device:=false"],
                            capture_output=True, text=True, timeout=30)
    assert result.returncode != 0
    # On a machine with cameras attached, none of them is the one asked for.
    expected = NO_DEVICE if len(rs.context().query_devices()) == 0 else f"with serial number '{ABSENT}'"
    assert f"source 'realsense': {expected}" in result.stderr, result.stderr


def test_realsense_source_without_its_camera_waits_for_it(tmp_path):
    # issue 11: a camera unplugged at start behaves as one unplugged later: the node waits, says so every few
    # seconds and on /diagnostics (ERROR), instead of exiting and leaving the rig without that camera for good.
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus

    rig = tiny_rig.write_rig(tmp_path / "rig.yaml")
    with RosGraph() as graph:
        statuses = []
        graph.node.create_subscription(DiagnosticArray, "/diagnostics",
                                       lambda m: statuses.extend(m.status), COLLECT_RELIABLE_DIAGNOSTICS)
        started = time.monotonic()
        process = graph.start("camera_node", "--params-file", str(rig), "-p", "camera:=cam_a", "-p",
                              "source:=realsense", "-p", f"cam_a.serial_number:={ABSENT}", "-p",
                              "reconnect_period:=0.2")
        expected = NO_DEVICE if len(rs.context().query_devices()) == 0 else f"with serial number '{ABSENT}'"
        assert graph.spin_until(lambda: any(s.level == DiagnosticStatus.ERROR and expected in s.message
                                            and "waiting for the camera" in s.message for s in statuses), 30), \
            graph.log_of(process)
        graph.spin_until(lambda: False, 1.0)
        assert process.poll() is None, graph.log_of(process)  # still waiting, not exited
        log = graph.log_of(process)
        assert "camera 'cam_a': waiting for the device" in log and expected in log, log
        # a line every WAITING_LOG_PERIOD_S, not one per attempt (every 0.2 s): bounded by the time it has run
        elapsed = time.monotonic() - started
        assert log.count("waiting for the device") <= elapsed / WAITING_LOG_PERIOD_S + 1, (elapsed, log)
