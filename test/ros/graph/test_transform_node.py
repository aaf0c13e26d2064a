"""transform_node as its own process: transforms clouds correctly, survives malformed ones, refuses bad parameters."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointCloud2
from support.ros_graph import VENV_BIN, RosGraph

from ntcr_recon.core.cloud.points import pack_rgb
from ntcr_recon.io.pointcloud import cloud_from_msg, cloud_to_msg, stamp_to_ns
from ntcr_recon.ros.messages import RCLPY
from ntcr_recon.ros.node_support import SENSOR_QOS, STAGE_QOS

TRANSLATION = [0.01, -0.02, 0.09]
ROTATION = Rotation.from_euler("xyz", [90, 0, 30], degrees=True).as_quat().tolist()


@pytest.fixture(scope="module")
def graph():
    with RosGraph() as graph:
        graph.start("transform_node", "-r", "points_in:=/ntcr/cam_a/depth/color/points",
                    "-r", "points_out:=/ntcr/cam_a/points_base",
                    "-p", f"translation:={TRANSLATION}", "-p", f"rotation:={ROTATION}",
                    "-p", "target_frame:=ntcr_base", "-p", "source_frame:=cam_a_optical_frame")
        received: list[PointCloud2] = []
        graph.node.create_subscription(PointCloud2, "/ntcr/cam_a/points_base", received.append, STAGE_QOS)
        publisher = graph.node.create_publisher(PointCloud2, "/ntcr/cam_a/depth/color/points", SENSOR_QOS)
        graph.wait_for_subscribers(publisher)
        graph.received, graph.publisher = received, publisher
        yield graph


def send_and_wait(graph, msg, expected_count: int, timeout: float = 10.0) -> bool:
    """Publish until the node's output count reaches `expected_count` (best-effort input may drop one)."""
    for _ in range(int(timeout / 0.5)):
        graph.publisher.publish(msg)
        if graph.spin_until(lambda: len(graph.received) >= expected_count, 0.5):
            return True
    return False


def good_cloud(stamp_ns: int):
    rng = np.random.default_rng(stamp_ns)
    xyz = rng.uniform(-0.05, 0.05, size=(200, 3)).astype(np.float32)
    rgb = pack_rgb(rng.integers(0, 256, size=(200, 3), dtype=np.uint8))
    return xyz, rgb, cloud_to_msg(xyz, rgb, msgtypes=RCLPY, frame_id="cam_a_optical_frame", stamp_ns=stamp_ns)


def test_cloud_is_transformed_into_the_target_frame(graph):
    xyz, rgb, msg = good_cloud(stamp_ns=1_000_000_007)
    count = len(graph.received)
    assert send_and_wait(graph, msg, count + 1), graph.all_logs()
    out = graph.received[-1]
    assert out.header.frame_id == "ntcr_base"
    assert stamp_to_ns(out.header.stamp) == 1_000_000_007  # the source's stamp, not the wall clock
    moved, rgb_out = cloud_from_msg(out)
    expected = xyz.astype(float) @ Rotation.from_quat(ROTATION).as_matrix().T + TRANSLATION
    np.testing.assert_allclose(moved, expected, atol=1e-6)
    np.testing.assert_array_equal(rgb_out, rgb)


@pytest.mark.parametrize("defect", ["short_data", "no_z_field", "wrong_frame", "nan_only"])
def test_malformed_cloud_is_logged_and_the_node_goes_on(graph, defect):
    xyz, _, bad = good_cloud(stamp_ns=2_000)
    if defect == "short_data":
        bad.data = bytes(bad.data)[:100]
    elif defect == "no_z_field":
        bad.fields = [f for f in bad.fields if f.name != "z"]
    elif defect == "wrong_frame":
        bad.header.frame_id = "cam_b_optical_frame"
    elif defect == "nan_only":
        bad = cloud_to_msg(np.full_like(xyz, np.nan), msgtypes=RCLPY, frame_id="cam_a_optical_frame", stamp_ns=2_000)
    count = len(graph.received)
    for _ in range(3):
        graph.publisher.publish(bad)
        graph.spin_until(lambda: False, 0.2)
    process = graph.processes[0][0]
    assert process.poll() is None, graph.all_logs()
    if defect == "nan_only":  # valid, just empty after dropping NaNs: published as an empty cloud
        assert graph.spin_until(lambda: len(graph.received) > count, 5.0)
        assert graph.received[-1].width == 0
        count = len(graph.received)
    else:
        expected_log = {"short_data": "width*height*point_step", "no_z_field": "no field z",
                        "wrong_frame": "expected 'cam_a_optical_frame'"}[defect]
        assert graph.spin_until(lambda: expected_log in graph.log_of(process), 5.0), graph.log_of(process)
        assert len(graph.received) == count
    # ... and the next good cloud still comes through.
    xyz, _, good = good_cloud(stamp_ns=3_000 + count)
    assert send_and_wait(graph, good, count + 1), graph.all_logs()
    assert stamp_to_ns(graph.received[-1].header.stamp) == 3_000 + count


def test_bad_parameter_at_start_is_refused_with_its_name():
    result = subprocess.run([str(VENV_BIN / "transform_node"), "--ros-args", "-p", "rotation:=[0.0, 0.0, 0.0, 2.0]"],
                            capture_output=True, text=True, timeout=30)
    assert result.returncode != 0
    assert "rotation" in result.stderr and "norm" in result.stderr


def test_bad_parameter_change_is_refused_and_the_old_value_kept(graph):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    request = SetParameters.Request(parameters=[Parameter(
        name="translation", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                                 double_array_value=[0.0, float("nan"), 0.0]))])
    result = graph.call(SetParameters, "/transform_node/set_parameters", request).results[0]
    assert not result.successful and "translation" in result.reason
    # The node still applies the configured transform.
    xyz, _, msg = good_cloud(stamp_ns=9_000)
    count = len(graph.received)
    assert send_and_wait(graph, msg, count + 1)
    expected = xyz.astype(float) @ Rotation.from_quat(ROTATION).as_matrix().T + TRANSLATION
    np.testing.assert_allclose(cloud_from_msg(graph.received[-1])[0], expected, atol=1e-6)
