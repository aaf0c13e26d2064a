"""camera_node's bag source as its own process: depth (16UC1 / 32FC1) + colour -> the core's deprojection,
recorded clouds republished as recorded, looping with increasing stamps, /clock, and clear refusals."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from support import tiny_rig
from support.ros_graph import VENV_BIN, RosGraph

from ntcr_recon.core.cloud.deproject import crop_window, depth_to_points
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.core.relocation.limbs import CameraView
from ntcr_recon.io.bag import image_to_array
from ntcr_recon.io.pointcloud import cloud_from_msg, stamp_to_ns
from ntcr_recon.ros.messages import camera_cloud_from_msg, intrinsics_from_camera_info

COLLECT_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)
FRAMES, FPS, START = 6, 30.0, 1_000_000_000
PERIOD = int(round(1e9 / FPS))
# One camera_node per case, its outputs remapped under the case's name so they share one graph.
CASES = {
    "raw16": dict(encoding="16UC1"),
    "float32": dict(encoding="32FC1"),
    "points": dict(points_only=True),
    "raw16_1mm": dict(encoding="16UC1", depth_unit=1e-3),  # as realsense-ros records: too coarse for the tube
}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("camera_node")
    rig = tiny_rig.write_rig(root / "rig.yaml", relocation={"limbs": True})  # the colour windows published too
    bags = {name: tiny_rig.write_bag(root / name, frames=FRAMES, fps=FPS, cameras=("cam_a",), **options)
            for name, options in CASES.items()}
    with RosGraph() as graph:
        received = {name: [] for name in CASES}
        infos, clocks, diagnostics = [], [], []
        for name, bag in bags.items():
            unit = CASES[name].get("depth_unit")
            graph.start("camera_node", "--params-file", str(rig), "-p", f"bag_path:={bag}", "-p", "camera:=cam_a",
                        "-p", "loop:=true", "-r", f"__node:=camera_{name}",
                        *(["-p", f"cam_a.depth_unit:={unit}"] if unit else []),
                        "-r", f"/ntcr/cam_a/depth/color/points:=/{name}/cam_a/depth/color/points",
                        "-r", f"/ntcr/cam_a/depth/camera_info:=/{name}/cam_a/depth/camera_info",
                        "-r", f"/ntcr/cam_a/color/image_rect_raw:=/{name}/cam_a/color/image_rect_raw",
                        "-r", f"/ntcr/cam_a/color/camera_info:=/{name}/cam_a/color/camera_info",
                        *(["-p", "publish_clock:=true"] if name == "raw16" else []))
            graph.node.create_subscription(PointCloud2, f"/{name}/cam_a/depth/color/points", received[name].append,
                                           COLLECT_QOS)
        graph.node.create_subscription(CameraInfo, "/raw16/cam_a/depth/camera_info", infos.append, COLLECT_QOS)
        graph.colour = [], []  # the raw16 node's colour windows and their camera_infos
        graph.node.create_subscription(Image, "/raw16/cam_a/color/image_rect_raw", graph.colour[0].append,
                                       COLLECT_QOS)
        graph.node.create_subscription(CameraInfo, "/raw16/cam_a/color/camera_info", graph.colour[1].append,
                                       COLLECT_QOS)
        graph.node.create_subscription(Clock, "/clock", clocks.append, COLLECT_QOS)
        graph.node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, COLLECT_QOS)
        # Two loops of every bag after discovery, and each node's diagnostics after its first frame.
        assert graph.spin_until(lambda: all(len(r) >= 2 * FRAMES for r in received.values())
                                and set(camera_statuses(diagnostics)) >= {f"camera_{name}" for name in CASES}
                                and all(s.values for s in camera_statuses(diagnostics).values())
                                and all(len(kind) >= FRAMES for kind in graph.colour), 30), \
            graph.all_logs()
        yield graph, received, infos, clocks, load_rig_config(rig), diagnostics


def camera_statuses(diagnostics) -> dict:
    """The newest diagnostic status of each camera node published after its first frame, by node name."""
    newest = {}
    for array in diagnostics:
        for status in array.status:
            values = {v.key: v.value for v in status.values}
            if status.hardware_id.startswith("ntcr_recon/camera_") and int(values.get("frames_published", 0)):
                newest[status.hardware_id.removeprefix("ntcr_recon/")] = status
    return newest


def expected_points(config, frame_index: int, unit_scale: bool):
    depth_m = tiny_rig.render_tube("cam_a")
    depth = np.round(depth_m / tiny_rig.DEPTH_UNIT).astype(np.uint16) if unit_scale else depth_m.astype(np.float32)
    window = crop_window(tiny_rig.INTRINSICS, config.cameras["cam_a"].extrinsic, *config.crop_box())
    return depth_to_points(depth, tiny_rig.INTRINSICS, tiny_rig.DEPTH_UNIT if unit_scale else 1.0,
                           tiny_rig.frame_color("cam_a", frame_index), window)


@pytest.mark.parametrize("case", ["raw16", "float32"])
def test_depth_frames_are_deprojected_by_the_core(setup, case):
    _, received, _, _, config, _ = setup
    for msg in received[case][:FRAMES + 2]:
        stamp = stamp_to_ns(msg.header.stamp)
        index = round((stamp - START) / PERIOD) % FRAMES
        xyz, rgb = cloud_from_msg(msg)
        want_xyz, want_rgb, want_pixel = expected_points(config, index, unit_scale=case == "raw16")
        assert msg.header.frame_id == "cam_a_optical_frame"
        # Each point's pixel travels with it (the filters' image neighbourhoods).
        _, _, pixel, _ = camera_cloud_from_msg(msg, "cam_a_optical_frame")
        np.testing.assert_array_equal(pixel, want_pixel)
        assert len(xyz) == len(want_xyz) > 100
        np.testing.assert_allclose(xyz, want_xyz, atol=1e-7)
        np.testing.assert_array_equal(rgb, want_rgb)  # the colour of the frame with the same stamp


def test_the_colour_window_about_the_robots_pixels_goes_out_with_its_intrinsics(setup):
    """What relocation_node places the axis across the view with: the frame's colour cut about the pixels of the
    cloud it published (core.relocation.limbs.CameraView.around, as the offline command cuts it), its camera_info
    that window's intrinsics, both with the frame's stamp."""
    graph, received, _, _, config, _ = setup
    images, infos = graph.colour
    info_by_stamp = {stamp_to_ns(info.header.stamp): info for info in infos}
    cloud_by_stamp = {stamp_to_ns(cloud.header.stamp): cloud for cloud in received["raw16"]}
    checked = 0
    for msg in images:
        stamp = stamp_to_ns(msg.header.stamp)
        if stamp not in cloud_by_stamp or stamp not in info_by_stamp:
            continue  # a best-effort message the probe missed
        index = round((stamp - START) / PERIOD) % FRAMES
        _, _, pixel, _ = camera_cloud_from_msg(cloud_by_stamp[stamp], "cam_a_optical_frame")
        want = CameraView.aligned(tiny_rig.frame_color("cam_a", index), tiny_rig.INTRINSICS,
                                  config.cameras["cam_a"].extrinsic).around(pixel)
        assert msg.header.frame_id == "cam_a_optical_frame" and msg.encoding == "rgb8"
        assert (msg.width, msg.height) == (want.intrinsics.width, want.intrinsics.height)
        np.testing.assert_array_equal(image_to_array(msg), want.color)
        assert intrinsics_from_camera_info(info_by_stamp[stamp]) == want.intrinsics
        checked += 1
    assert checked >= FRAMES


def test_16bit_depth_is_scaled_by_the_configured_unit(setup):
    _, received, _, _, _, _ = setup
    raw16, metres = (cloud_from_msg(received[case][0])[0] for case in ("raw16", "float32"))
    # Same scene: 16UC1 in 0.1 mm units equals 32FC1 metres to within the quantisation.
    assert np.abs(raw16[:, 2] - metres[:, 2]).max() <= tiny_rig.DEPTH_UNIT / 2 + 1e-7
    assert 0.085 < np.median(raw16[:, 2]) < 0.09


def test_loop_keeps_stamps_increasing_and_publishes_clock(setup):
    _, received, infos, clocks, _, _ = setup
    stamps = [stamp_to_ns(m.header.stamp) for m in received["raw16"]]
    assert np.all(np.diff(stamps) > 0)
    assert stamps[-1] - stamps[0] >= (2 * FRAMES - 1) * PERIOD - 1  # crossed at least one loop boundary
    steps = np.diff(stamps) / PERIOD
    assert np.abs(steps - np.round(steps)).max() < 1e-4  # on the frame grid across the loop seam: no repeat
    clock_stamps = [stamp_to_ns(c.clock) for c in clocks]
    assert len(clock_stamps) >= FRAMES and set(stamps) & set(clock_stamps)
    assert np.all(np.diff(clock_stamps) > 0)
    info_stamps = {stamp_to_ns(i.header.stamp) for i in infos}
    assert info_stamps & set(stamps)  # camera_info carries the frame's own stamp
    assert infos[0].k[0] == tiny_rig.INTRINSICS.fx and infos[0].header.frame_id == "cam_a_optical_frame"


def test_recorded_clouds_are_republished_as_recorded(setup):
    _, received, _, _, _, _ = setup
    msg = received["points"][0]
    index = round((stamp_to_ns(msg.header.stamp) - START) / PERIOD) % FRAMES
    xyz, rgb = cloud_from_msg(msg)
    want_xyz, want_rgb, _ = depth_to_points(tiny_rig.render_tube("cam_a"), tiny_rig.INTRINSICS, 1.0,
                                            tiny_rig.frame_color("cam_a", index))
    np.testing.assert_allclose(xyz, want_xyz.astype(np.float32))  # not cropped, not re-deprojected
    np.testing.assert_array_equal(rgb, want_rgb)


def test_depth_too_coarse_for_the_tube_is_reported_on_diagnostics(setup):
    """A camera whose depth comes in 1 mm steps (realsense-ros's default unit) says so in the graph, as the
    offline command's warnings do; 0.1 mm steps pass, with the step measured."""
    graph, _, _, _, _, diagnostics = setup
    statuses = camera_statuses(diagnostics)
    coarse, fine = statuses["camera_raw16_1mm"], statuses["camera_raw16"]
    assert coarse.level == DiagnosticStatus.WARN
    assert "depth of cam_a is quantised in 1 mm steps" in coarse.message
    assert {v.key: v.value for v in coarse.values}["depth_step_mm"] == "1.0"
    # (its level may still be WARN for frames skipped to keep pace on a busy machine)
    assert "quantised" not in fine.message
    assert {v.key: v.value for v in fine.values}["depth_step_mm"] == "0.1", fine
    assert "quantised in 1 mm steps" in graph.all_logs()


def test_a_truncated_bag_is_refused_by_name(tmp_path):
    rig = tiny_rig.write_rig(tmp_path / "rig.yaml")
    bag = tiny_rig.write_bag(tmp_path / "bag", frames=3, cameras=("cam_a",))
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    result = subprocess.run([str(VENV_BIN / "camera_node"), "--ros-args", "--params-file", str(rig),
                             "-p", f"bag_path:={bag}"], capture_output=True, text=True, timeout=30)
    assert result.returncode != 0
    assert f"cannot read bag {bag}" in result.stderr, result.stderr


@pytest.mark.parametrize("override, expected", [
    (("-p", "bag_path:=/nonexistent/bag"), "/nonexistent/bag does not exist"),
    (("-p", "camera:=cam_z"), "parameter 'camera' is 'cam_z'"),
    (("-p", "cam_a.depth_unit:=-1.0"), "cam_a.depth_unit must be > 0"),
])
def test_bad_start_parameters_are_refused_by_name(setup, tmp_path, override, expected):
    rig = tiny_rig.write_rig(tmp_path / "rig.yaml")
    bag = tiny_rig.write_bag(tmp_path / "bag", frames=1, cameras=("cam_a",))
    result = subprocess.run([str(VENV_BIN / "camera_node"), "--ros-args", "--params-file", str(rig),
                             "-p", f"bag_path:={bag}", *override], capture_output=True, text=True, timeout=30)
    assert result.returncode != 0
    assert expected in result.stderr, result.stderr


@pytest.mark.parametrize("index, value, expected", [(0, float("inf"), "fx is inf"), (2, float("nan"), "cx is nan")])
def test_frames_with_impossible_intrinsics_are_dropped_naming_the_value(tmp_path, monkeypatch, index, value,
                                                                         expected):
    # issue 11: camera_info fx = inf overflowed the crop window (an OverflowError stopped the source), cx = NaN
    # gave "cannot convert float NaN to integer"; now each frame is dropped with the cause named, the node lives.
    recorded_info = tiny_rig.camera_info

    def impossible_info(frame_id: str, stamp_ns: int):
        info = recorded_info(frame_id, stamp_ns)
        info.k[index] = value
        return info

    monkeypatch.setattr(tiny_rig, "camera_info", impossible_info)
    rig = tiny_rig.write_rig(tmp_path / "rig.yaml")
    bag = tiny_rig.write_bag(tmp_path / "bag", frames=3, fps=FPS, cameras=("cam_a",))
    with RosGraph() as graph:
        clouds = []
        graph.node.create_subscription(PointCloud2, "/ntcr/cam_a/depth/color/points", clouds.append, COLLECT_QOS)
        process = graph.start("camera_node", "--params-file", str(rig), "-p", f"bag_path:={bag}", "-p",
                              "camera:=cam_a", "-p", "loop:=true")
        assert graph.spin_until(lambda: expected in graph.log_of(process), 30), graph.log_of(process)
        graph.spin_until(lambda: False, 1.0)  # the loop goes on: more frames, each dropped
        log = graph.log_of(process)
        assert process.poll() is None, log
        assert "Traceback" not in log and "camera source failed" not in log and "Error" not in log, log
        # logged once, then counted: a later line (a log period on) tells how many were held back
        lines = [line for line in log.splitlines() if expected in line]
        assert lines and all("more like it since" in line for line in lines[1:]), log
        assert not clouds


def start_patched_camera_node(graph, tmp_path, patch: str, *ros_args: str):
    """camera_node as its own process with `patch` (Python run after importing the module as `camera_node`)
    applied first: how a fault that real frames cannot provoke is put into the real node."""
    import sys
    import tempfile
    from pathlib import Path

    rig = tiny_rig.write_rig(tmp_path / "rig.yaml")
    bag = tiny_rig.write_bag(tmp_path / "bag", frames=3, fps=FPS, cameras=("cam_a",))
    code = f"import sys\nimport ntcr_recon.ros.camera_node as camera_node\n{patch}\nsys.exit(camera_node.main())"
    log = Path(tempfile.mkstemp(prefix="camera_node-patched-", suffix=".log")[1])
    command = [sys.executable, "-c", code, "--ros-args", "--params-file", str(rig), "-p", f"bag_path:={bag}",
               "-p", "camera:=cam_a", "-p", "loop:=true", "-p", "wait_for_subscriber:=false", *ros_args]
    process = subprocess.Popen(command, env=graph.env, stdout=log.open("w"), stderr=subprocess.STDOUT)
    graph.processes.append((process, log))
    return process


def test_a_frame_whose_crop_window_overflows_is_dropped_and_the_node_goes_on(tmp_path):
    # review: only ValueError was caught per frame; an OverflowError from crop_window ended the producer thread
    patch = ("def overflowing(*args, **kwargs):\n    raise OverflowError('cannot convert float infinity to integer')\n"
             "import ntcr_recon.core.cloud.fusion as fusion\nfusion.crop_window = overflowing")
    with RosGraph() as graph:
        process = start_patched_camera_node(graph, tmp_path, patch)
        expected = "dropped a message (arithmetic): camera 'cam_a' frame: OverflowError"
        assert graph.spin_until(lambda: expected in graph.log_of(process), 30), graph.log_of(process)
        graph.spin_until(lambda: False, 1.0)  # the loop goes on, each frame dropped
        log = graph.log_of(process)
        assert process.poll() is None, log
        assert "camera source failed" not in log, log


def test_a_producer_thread_that_dies_ends_the_process_non_zero(tmp_path):
    # review: the producer thread ended for good while the process lived on, publishing nothing; a dead
    # producer now ends the process (exit 1) so that `ntcr-recon run` / launch respawns it
    patch = ("def broken(self, frame):\n    raise RuntimeError('a bug in the producer')\n"
             "camera_node.CameraNode._publish = broken")
    with RosGraph() as graph:
        process = start_patched_camera_node(graph, tmp_path, patch)
        assert graph.spin_until(lambda: process.poll() is not None, 30), graph.log_of(process)
        log = graph.log_of(process)
        assert process.returncode == 1, log
        assert "camera source failed: RuntimeError: a bug in the producer" in log, log


def test_destroy_node_closes_a_device_the_producer_opened_while_the_node_stopped(monkeypatch):
    # review: destroy_node closed the source before joining the producer thread, so a device opened in between
    # (a camera waited for that appears just then) was never closed
    import threading

    from rclpy.node import Node

    from ntcr_recon.ros import camera_node

    class Device:
        closed = False

        def close(self) -> None:
            self.closed = True

    monkeypatch.setattr(Node, "destroy_node", lambda self: None)  # no rclpy node behind this one
    node = camera_node.CameraNode.__new__(camera_node.CameraNode)
    node._stop, node._source, device = threading.Event(), None, Device()

    def producer() -> None:  # _wait_for_device, the device found as the stop comes
        node._stop.wait()
        node._source = device

    node._thread = threading.Thread(target=producer)
    node._thread.start()
    node.destroy_node()
    assert device.closed
