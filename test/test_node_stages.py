"""filter_node and relocation_node, each alone as its own process: the output equals the core's on the same
input (a simulated 45-degree frame pair), a malformed cloud is logged by its defect and the node goes on."""

from __future__ import annotations

import numpy as np
import pytest
import tiny_rig
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from ros_graph import RosGraph
from stage_probe import COLLECT_RELIABLE, StageProbe
from std_msgs.msg import Float64MultiArray
from visualization_msgs.msg import MarkerArray

from ntcr_recon.core.config import load_rig_config
from ntcr_recon.core.pipeline import Reconstructor
from ntcr_recon.ros.messages import (
    notches_from_array,
    stage_cloud_and_normals,
    stage_cloud_from_msg,
    stage_cloud_to_msg,
)
from ntcr_recon.ros.pointcloud import stamp_to_ns


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """Fused and filtered stage messages of the simulated bag's frame pairs, as the nodes receive them."""
    bag = tiny_rig.simulated_bag(tmp_path_factory)
    config = load_rig_config(bag / "rig.yaml")
    reconstructor = Reconstructor(config)
    fused = [stage_cloud_to_msg(reconstructor.fuse(pair), config.base_frame)
             for pair in tiny_rig.bag_frame_pairs(bag, config)]
    filtered = [stage_cloud_to_msg(reconstructor.filter(stage_cloud_from_msg(m, config.base_frame)),
                                   config.base_frame) for m in fused]
    return bag, config, fused, filtered


@pytest.fixture(scope="module")
def filter_probe(scene):
    bag, *_ = scene
    with RosGraph() as graph:
        process = graph.start("filter_node", "--params-file", str(bag / "rig.yaml"))
        yield StageProbe(graph, process, "/ntcr/fused/points", "/ntcr/filtered/points")


@pytest.fixture(scope="module")
def relocation_probe(scene):
    bag, *_ = scene
    with RosGraph() as graph:
        process = graph.start("relocation_node", "--params-file", str(bag / "rig.yaml"))
        probe = StageProbe(graph, process, "/ntcr/filtered/points", "/ntcr/relocated/points")
        probe.extra = {name: [] for name in ("centerline", "tip", "notches", "notches/markers")}
        for name, kind in (("centerline", Path), ("tip", PoseStamped), ("notches", Float64MultiArray),
                           ("notches/markers", MarkerArray)):
            graph.node.create_subscription(kind, f"/ntcr/{name}", probe.extra[name].append, COLLECT_RELIABLE)
        yield probe


def test_filter_node_filters_as_the_core(scene, filter_probe):
    _, config, fused, _ = scene
    out = filter_probe.send_and_wait(fused[0])
    expected = Reconstructor(config).filter(stage_cloud_from_msg(fused[0], config.base_frame))
    cloud = stage_cloud_from_msg(out, config.base_frame)
    assert stamp_to_ns(out.header.stamp) == expected.stamp_ns
    assert 1000 < len(cloud) == len(expected) < len(stage_cloud_from_msg(fused[0], config.base_frame))
    np.testing.assert_allclose(cloud.xyz, expected.xyz, atol=1e-6)
    np.testing.assert_array_equal(cloud.camera, expected.camera)
    assert cloud.pixel_footprint == pytest.approx(expected.pixel_footprint, rel=1e-6)


def test_relocation_node_relocates_as_the_core(scene, relocation_probe):
    _, config, _, filtered = scene
    probe = relocation_probe
    out = probe.send_and_wait(filtered[0])
    assert probe.graph.spin_until(lambda: all(probe.extra.values()), 10)
    expected = Reconstructor(config).relocate(stage_cloud_from_msg(filtered[0], config.base_frame))
    cloud, normals = stage_cloud_and_normals(out, config.base_frame)
    np.testing.assert_allclose(cloud.xyz, expected.relocated.xyz, atol=1e-6)
    np.testing.assert_allclose(normals, expected.normals, atol=1e-6)
    notches = notches_from_array(probe.extra["notches"][-1])
    assert len(notches) == len(expected.notches) == config.robot.notch_count
    for got, want in zip(notches, expected.notches, strict=True):
        assert got["index"] == want.index
        assert got["center_s"] == pytest.approx(want.center_s, abs=1e-9)
        assert got["width"] == pytest.approx(want.width, abs=1e-9)
    path = probe.extra["centerline"][-1]
    points = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path.poses])
    np.testing.assert_allclose(points, expected.centerline.points, atol=1e-9)
    tip = probe.extra["tip"][-1].pose.position
    np.testing.assert_allclose([tip.x, tip.y, tip.z], expected.tip, atol=1e-9)
    # The tip pose's z axis is the centreline's end tangent (x to the notch side).
    q = probe.extra["tip"][-1].pose.orientation
    from scipy.spatial.transform import Rotation
    np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()[:, 2],
                               expected.centerline.tangents[-1], atol=1e-6)
    markers = probe.extra["notches/markers"][-1].markers
    assert sum(m.ns == "notches" and m.action == m.ADD for m in markers) == len(expected.notches)


@pytest.mark.parametrize("defect", tiny_rig.MALFORMED)
def test_filter_node_survives_malformed_clouds(scene, filter_probe, defect):
    filter_probe.assert_refuses(defect, "ntcr_base")
    assert stamp_to_ns(filter_probe.send_and_wait(scene[2][1]).header.stamp) == stamp_to_ns(scene[2][1].header.stamp)


@pytest.mark.parametrize("defect", tiny_rig.MALFORMED)
def test_relocation_node_survives_malformed_clouds(scene, relocation_probe, defect):
    relocation_probe.assert_refuses(defect, "ntcr_base")
    good = scene[3][1]
    assert stamp_to_ns(relocation_probe.send_and_wait(good).header.stamp) == stamp_to_ns(good.header.stamp)


def test_relocation_node_logs_a_cloud_without_a_robot_and_goes_on(scene, relocation_probe):
    probe = relocation_probe
    stray = stage_cloud_to_msg(stage_cloud_from_msg(scene[3][0], "ntcr_base").subset(np.arange(10)), "ntcr_base")
    log_before = len(probe.graph.log_of(probe.process))
    count = len(probe.received)
    probe.publisher.publish(stray)
    assert probe.graph.spin_until(lambda: "cannot reconstruct the cloud of 10 points" in
                                  probe.graph.log_of(probe.process)[log_before:], 10)
    assert len(probe.received) == count
    assert probe.send_and_wait(scene[3][0]) is not None
