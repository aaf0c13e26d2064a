"""fusion_node as its own process: pairs by stamp and fuses as the core does, survives malformed clouds,
publishes one camera alone when the other falls silent (saying which on /diagnostics) and pairs again when it
returns."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import CameraInfo, PointCloud2
from support import tiny_rig
from support.ros_graph import VENV_BIN, RosGraph
from support.stage_probe import COLLECT_RELIABLE, StageProbe, set_parameter

from ntcr_recon.core.cloud.deproject import depth_to_points
from ntcr_recon.core.cloud.fusion import CameraFrame, FramePair, fuse
from ntcr_recon.core.config.rig import load_rig_config
from ntcr_recon.io.pointcloud import cloud_to_msg, stamp_to_ns
from ntcr_recon.ros.messages import RCLPY, camera_cloud_to_msg, header, stage_cloud_from_msg
from ntcr_recon.ros.node_support import CAMERA_QOS, SENSOR_QOS

PERIOD = 33_333_333


def camera_points(camera: str, index: int):
    return depth_to_points(tiny_rig.render_tube(camera), tiny_rig.INTRINSICS, 1.0,
                           tiny_rig.frame_color(camera, index))[:2]


def camera_msg(camera: str, stamp_ns: int, index: int = 0):
    xyz, rgb = camera_points(camera, index)
    return cloud_to_msg(xyz, rgb, msgtypes=RCLPY, frame_id=f"{camera}_optical_frame", stamp_ns=stamp_ns)


@pytest.fixture(scope="module")
def fusion(tmp_path_factory):
    rig_path = tiny_rig.write_rig(tmp_path_factory.mktemp("fusion") / "rig.yaml",
                                  fusion={"slop": 0.010, "camera_timeout": 0.3})
    with RosGraph() as graph:
        process = graph.start("fusion_node", "--params-file", str(rig_path))
        probe = StageProbe(graph, process, "/ntcr/cam_a/depth/color/points", "/ntcr/fused/points",
                           input_qos=CAMERA_QOS)
        probe.publisher_b = graph.node.create_publisher(PointCloud2, "/ntcr/cam_b/depth/color/points", CAMERA_QOS)
        infos = {c: graph.node.create_publisher(CameraInfo, f"/ntcr/{c}/depth/camera_info", CAMERA_QOS)
                 for c in tiny_rig.CAMERAS}
        probe.diagnostics = []
        graph.node.create_subscription(DiagnosticArray, "/diagnostics", probe.diagnostics.append, COLLECT_RELIABLE)
        graph.wait_for_subscribers(probe.publisher_b)
        for camera, publisher in infos.items():
            graph.wait_for_subscribers(publisher)
            info = CameraInfo(header=header(f"{camera}_optical_frame", 0), width=tiny_rig.INTRINSICS.width,
                              height=tiny_rig.INTRINSICS.height)
            info.k = np.array([tiny_rig.INTRINSICS.fx, 0, tiny_rig.INTRINSICS.cx, 0, tiny_rig.INTRINSICS.fy,
                               tiny_rig.INTRINSICS.cy, 0, 0, 1], float)
            for _ in range(3):
                publisher.publish(info)
                graph.spin_until(lambda: False, 0.1)
        probe.config = load_rig_config(rig_path)
        yield probe


def send_pair(probe, stamp_a: int | None, stamp_b: int | None, index: int = 0) -> None:
    if stamp_a is not None:
        probe.publisher.publish(camera_msg("cam_a", stamp_a, index))
    if stamp_b is not None:
        probe.publisher_b.publish(camera_msg("cam_b", stamp_b, index))
    probe.graph.spin_until(lambda: False, 0.02)


def test_a_pair_is_fused_as_the_core_fuses_it(fusion):
    stamp_a, stamp_b = 10 * PERIOD, 10 * PERIOD + 4_000_000  # 4 ms apart: within the 10 ms slop
    count = len(fusion.received)
    for _ in range(20):
        send_pair(fusion, stamp_a, stamp_b)
        if fusion.graph.spin_until(lambda: any(stamp_to_ns(m.header.stamp) == stamp_a
                                               for m in fusion.received[count:]), 0.5):
            break
    out = next(m for m in fusion.received[count:] if stamp_to_ns(m.header.stamp) == stamp_a)
    frames = {}
    for camera, stamp in (("cam_a", stamp_a), ("cam_b", stamp_b)):
        xyz, rgb = camera_points(camera, 0)
        frames[camera] = CameraFrame(camera, stamp, points=xyz.astype(np.float32), rgb=rgb)
    expected = fuse(FramePair(stamp_a, frames), fusion.config)
    cloud = stage_cloud_from_msg(out, "ntcr_base")
    assert out.header.frame_id == "ntcr_base"
    np.testing.assert_allclose(cloud.xyz, expected.xyz, atol=1e-6)
    np.testing.assert_array_equal(cloud.rgb, expected.rgb)
    np.testing.assert_array_equal(cloud.camera, expected.camera)
    assert set(cloud.camera) == {0, 1}
    # Pixel footprint (median depth / fx): what the core derives from the same frames as depth images.
    depth_frames = {camera: CameraFrame(camera, stamp, depth=tiny_rig.render_tube(camera),
                                        intrinsics=tiny_rig.INTRINSICS, depth_unit=1.0)
                    for camera, stamp in (("cam_a", stamp_a), ("cam_b", stamp_b))}
    from_depth = fuse(FramePair(stamp_a, depth_frames), fusion.config)
    assert from_depth.pixel_footprint > 0
    assert cloud.pixel_footprint == pytest.approx(from_depth.pixel_footprint, rel=1e-5)


# An empty camera cloud is a camera that saw nothing, not a defect (test_an_empty_camera_cloud_is_a_frame_...).
@pytest.mark.parametrize("defect", [d for d in tiny_rig.MALFORMED if d != "empty"])
def test_malformed_cloud_is_logged_and_fusion_goes_on(fusion, defect):
    fusion.assert_refuses(defect, "cam_a_optical_frame")
    test_a_pair_is_fused_as_the_core_fuses_it(fusion)

def test_an_empty_camera_cloud_is_a_frame_with_no_points_and_still_pairs(fusion):
    # review: camera_node publishes only the points inside the crop box, so a camera that sees nothing sends an
    # empty cloud; fusion refused it and never fed the pairer, so the live camera was reported silent
    stamp = 11 * PERIOD  # just after the other tests' pair (10 periods): no lag that would read as a silence
    empty_b = camera_cloud_to_msg(np.empty((0, 3)), None, np.empty((0, 2), np.int32), "cam_b_optical_frame", stamp)
    xyz, rgb, pixel = depth_to_points(tiny_rig.render_tube("cam_a"), tiny_rig.INTRINSICS, 1.0,
                                      tiny_rig.frame_color("cam_a", 0))
    cloud_a = camera_cloud_to_msg(xyz, rgb, pixel, "cam_a_optical_frame", stamp)  # as camera_node publishes it
    count, log_before = len(fusion.received), len(fusion.graph.log_of(fusion.process))
    for _ in range(20):
        fusion.publisher.publish(cloud_a)
        fusion.publisher_b.publish(empty_b)
        if fusion.graph.spin_until(lambda: any(stamp_to_ns(m.header.stamp) == stamp
                                               for m in fusion.received[count:]), 0.5):
            break
    out = next(m for m in fusion.received[count:] if stamp_to_ns(m.header.stamp) == stamp)
    cloud = stage_cloud_from_msg(out, "ntcr_base")
    assert len(cloud) > 100 and set(np.unique(cloud.camera)) == {0}
    assert cloud.pixel is not None  # cam_a's pixels kept: the filters still find neighbours in the image
    log = fusion.graph.log_of(fusion.process)[log_before:]
    assert "empty cloud" not in log and "silent" not in log, log


def test_one_camera_stopped_mid_stream_then_back(fusion):
    graph, timeout_frames = fusion.graph, int(0.3 / (PERIOD * 1e-9)) + 1
    start = 1000 * PERIOD
    phases = [("both", 15), ("a_only", 3 * timeout_frames), ("both", 20)]
    outputs_by_phase, stamp, index = {}, start, 0
    for phase_number, (phase, frames) in enumerate(phases):
        count, diag_count = len(fusion.received), len(fusion.diagnostics)
        for _ in range(frames):
            send_pair(fusion, stamp, stamp if phase == "both" else None, index)
            stamp += PERIOD
            index += 1
        graph.spin_until(lambda: False, 0.3)
        outputs_by_phase[phase_number] = ([stage_cloud_from_msg(m, "ntcr_base") for m in fusion.received[count:]],
                                          fusion.diagnostics[diag_count:])
    # While cam_b is silent, cam_a's clouds keep coming, alone (camera index 0 only).
    alone, diagnostics = outputs_by_phase[1]
    alone_clouds = [c for c in alone if set(np.unique(c.camera)) == {0}]
    assert len(alone_clouds) >= timeout_frames, [set(np.unique(c.camera)) for c in alone]
    statuses = [s for d in diagnostics for s in d.status]
    warnings = [s for s in statuses if s.level == DiagnosticStatus.WARN]
    assert warnings and "cam_b" in warnings[0].message and "cam_a" in warnings[0].message
    assert any(kv.key == "missing" and kv.value == "cam_b" for kv in warnings[0].values)
    assert "camera 'cam_b' silent" in graph.log_of(fusion.process)
    # Back: pairs again, diagnostics OK, and the log says so.
    back, diagnostics = outputs_by_phase[2]
    assert sum(set(np.unique(c.camera)) == {0, 1} for c in back) >= 10
    assert any(s.level == DiagnosticStatus.OK for d in diagnostics for s in d.status)
    assert "camera 'cam_b' is back" in graph.log_of(fusion.process)


def test_diagnostics_period_is_read_only(fusion):
    # review: a change was accepted but never applied (the timer is made once)
    refused = set_parameter(fusion.graph, "fusion_node", "diagnostics_period", 5.0)
    assert not refused.successful and "read-only" in refused.reason.lower(), refused.reason


def test_a_bad_rig_parameter_change_is_refused_by_its_key_and_fusion_goes_on(fusion):
    # Runs after the stop-and-return test, whose stamps were later: the jump back restarts the pairing.
    refused = set_parameter(fusion.graph, "fusion_node", "fusion.slop", -0.01)
    assert not refused.successful and "fusion.slop must be > 0" in refused.reason
    assert set_parameter(fusion.graph, "fusion_node", "fusion.slop", 0.012).successful
    test_a_pair_is_fused_as_the_core_fuses_it(fusion)
    assert "stamps jumped back" in fusion.graph.log_of(fusion.process)


# ---- bounded inputs (issue 11): dropped before anything is allocated for them, logged by cause, counted --------

def fusion_drops(probe, reason: str) -> int:
    """The newest count of drops for `reason` fusion_node reported on /diagnostics (0 before any)."""
    for msg in reversed(probe.diagnostics):
        for status in msg.status:
            if status.name == "ntcr_recon: fusion":
                return int({kv.key: kv.value for kv in status.values}.get(f"dropped.{reason}", 0))
    return 0


def assert_dropped_and_counted(probe, msg, publisher, expected_log: str, reason: str) -> None:
    drops_before, count = fusion_drops(probe, reason), len(probe.received)

    def counted() -> bool:
        publisher.publish(msg)  # best effort: again until one arrives and is counted
        return fusion_drops(probe, reason) > drops_before

    assert probe.graph.spin_until(counted, 10), probe.graph.log_of(probe.process)
    # logged once per kind of drop and log period: the same defect met by an earlier test is counted, not logged
    assert probe.graph.spin_until(lambda: expected_log in probe.graph.log_of(probe.process), 5), \
        probe.graph.log_of(probe.process)
    assert probe.process.poll() is None and len(probe.received) == count


def test_an_oversized_camera_cloud_is_dropped_before_it_is_read_and_counted(fusion):
    xyz, rgb = camera_points("cam_a", 0)
    assert set_parameter(fusion.graph, "fusion_node", "max_points", len(xyz) - 1).successful
    try:
        msg = cloud_to_msg(xyz, rgb, msgtypes=RCLPY, frame_id="cam_a_optical_frame", stamp_ns=3_000 * PERIOD)
        assert_dropped_and_counted(fusion, msg, fusion.publisher,
                                   f"cloud of {len(xyz)}x1 = {len(xyz)} points exceeds max_points {len(xyz) - 1}",
                                   "oversized")
    finally:
        assert set_parameter(fusion.graph, "fusion_node", "max_points", 10_000_000).successful
    test_a_pair_is_fused_as_the_core_fuses_it(fusion)


@pytest.mark.parametrize("span", [4000, 16000])
def test_pixels_outside_the_camera_image_are_dropped_before_a_grid_is_allocated(fusion, span):
    # Two points whose pixels span `span` columns: laid out as they came, span^2 cells (GBs) would be allocated.
    xyz = np.array([[0.0, 0.0, 0.09], [1e-4, 0.0, 0.09]])
    msg = cloud_to_msg(xyz, msgtypes=RCLPY, frame_id="cam_a_optical_frame", stamp_ns=3_100 * PERIOD,
                       columns={"pixel_u": np.array([0, span], np.float32),
                                "pixel_v": np.array([0, span], np.float32)})
    width, height = tiny_rig.INTRINSICS.width, tiny_rig.INTRINSICS.height
    assert_dropped_and_counted(fusion, msg, fusion.publisher,
                               f"outside the {width}x{height} image of camera cam_a", "inconsistent")
    test_a_pair_is_fused_as_the_core_fuses_it(fusion)


@pytest.mark.parametrize("field, index, value, expected", [
    ("fx", 0, float("inf"), "camera_info of cam_a: fx is inf"),
    ("cx", 2, float("nan"), "camera_info of cam_a: cx is nan"),
])
def test_camera_info_with_an_impossible_value_is_dropped_naming_it(fusion, field, index, value, expected):
    publisher = fusion.graph.node.create_publisher(CameraInfo, "/ntcr/cam_a/depth/camera_info", CAMERA_QOS)
    fusion.graph.wait_for_subscribers(publisher)
    info = CameraInfo(header=header("cam_a_optical_frame", 0), width=tiny_rig.INTRINSICS.width,
                      height=tiny_rig.INTRINSICS.height)
    k = [tiny_rig.INTRINSICS.fx, 0, tiny_rig.INTRINSICS.cx, 0, tiny_rig.INTRINSICS.fy, tiny_rig.INTRINSICS.cy, 0, 0, 1]
    k[index] = value
    info.k = np.array(k, float)
    assert_dropped_and_counted(fusion, info, publisher, expected, "inconsistent")
    assert "Traceback" not in fusion.graph.log_of(fusion.process)
    fusion.graph.node.destroy_publisher(publisher)
    test_a_pair_is_fused_as_the_core_fuses_it(fusion)  # the last good camera_info still serves


def test_each_cloud_takes_the_camera_info_in_force_at_its_own_stamp(fusion):
    # issue 65: a camera_info stamped later that came first (recordings give no order within an instant, a replay
    # may deliver it ahead) is not the one in force for an earlier cloud; the newest received was taken before
    publishers = {c: fusion.graph.node.create_publisher(CameraInfo, f"/ntcr/{c}/depth/camera_info", CAMERA_QOS)
                  for c in tiny_rig.CAMERAS}
    later, earlier = 5_000 * PERIOD, 4_990 * PERIOD
    for camera, publisher in publishers.items():
        fusion.graph.wait_for_subscribers(publisher)
        info = CameraInfo(header=header(f"{camera}_optical_frame", later), width=tiny_rig.INTRINSICS.width,
                          height=tiny_rig.INTRINSICS.height)
        info.k = np.array([2 * tiny_rig.INTRINSICS.fx, 0, tiny_rig.INTRINSICS.cx, 0, 2 * tiny_rig.INTRINSICS.fy,
                           tiny_rig.INTRINSICS.cy, 0, 0, 1], float)  # a focal length twice as long from `later` on
        for _ in range(3):
            publisher.publish(info)
            fusion.graph.spin_until(lambda: False, 0.1)

    def footprint_at(stamp: int) -> float:
        count = len(fusion.received)
        for _ in range(20):
            send_pair(fusion, stamp, stamp + 1_000_000)
            if fusion.graph.spin_until(lambda: any(stamp_to_ns(m.header.stamp) == stamp
                                                   for m in fusion.received[count:]), 0.5):
                break
        out = next(m for m in fusion.received[count:] if stamp_to_ns(m.header.stamp) == stamp)
        return stage_cloud_from_msg(out, "ntcr_base").pixel_footprint

    before, after = footprint_at(earlier), footprint_at(later)
    assert before > 0 and after == pytest.approx(before / 2, rel=1e-5)


def test_a_best_effort_camera_is_heard_with_camera_reliability_best_effort(tmp_path):
    # a driver set to sensor-data QoS (realsense-ros with pointcloud.pointcloud_qos:=SENSOR_DATA) offers best
    # effort, which the default reliable subscription never hears
    rig_path = tiny_rig.write_rig(tmp_path / "rig.yaml", fusion={"slop": 0.010, "camera_timeout": 0.3})
    with RosGraph() as graph:
        process = graph.start("fusion_node", "--params-file", str(rig_path), "-p", "camera_reliability:=best_effort")
        probe = StageProbe(graph, process, "/ntcr/cam_a/depth/color/points", "/ntcr/fused/points",
                           input_qos=SENSOR_QOS)
        probe.publisher_b = graph.node.create_publisher(PointCloud2, "/ntcr/cam_b/depth/color/points", SENSOR_QOS)
        graph.wait_for_subscribers(probe.publisher_b)
        stamp = 10 * PERIOD
        for _ in range(20):
            send_pair(probe, stamp, stamp + 4_000_000)
            if graph.spin_until(lambda: any(stamp_to_ns(m.header.stamp) == stamp for m in probe.received), 0.5):
                break
        fused = [m for m in probe.received if stamp_to_ns(m.header.stamp) == stamp]
        assert fused, graph.all_logs()
        assert set(stage_cloud_from_msg(fused[0], "ntcr_base").camera) == {0, 1}


def test_an_unknown_camera_reliability_is_refused_by_name(tmp_path):
    rig_path = tiny_rig.write_rig(tmp_path / "rig.yaml")
    result = subprocess.run([str(VENV_BIN / "fusion_node"), "--ros-args", "--params-file", str(rig_path),
                             "-p", "camera_reliability:=sometimes"], capture_output=True, text=True, timeout=30)
    assert result.returncode == 2, result.stderr
    assert "parameter 'camera_reliability' must be one of ('reliable', 'best_effort'), got 'sometimes'" \
        in result.stderr, result.stderr
