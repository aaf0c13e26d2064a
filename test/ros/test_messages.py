"""Messages the nodes build from arrays: the serialized Path, mesh Marker and Mesh decode to the message rclpy
serializes from the same message built field by field (one Python object per point, as before; compared decoded,
not byte for byte: rclpy leaves alignment padding bytes unset), and the input checks refuse what would otherwise
allocate or fail later."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geometry_msgs.msg import Point, PoseStamped
from nav_msgs.msg import Path
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CameraInfo, PointCloud2
from shape_msgs.msg import Mesh, MeshTriangle
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from ntcr_recon.core.base.transforms import matrix_to_quaternion
from ntcr_recon.ros import cdr, messages, result_messages

RNG = np.random.default_rng(7)


def random_rotations(count: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.random(count, random_state=3).as_matrix()


@pytest.mark.parametrize("frame_id", ["", "b", "ntcr_base", "a_frame_of_8"])
@pytest.mark.parametrize("count", [0, 1, 2, 7])
def test_path_bytes_decode_as_the_pose_by_pose_path(frame_id, count):
    points, rotations = RNG.normal(size=(count, 3)), random_rotations(max(count, 1))[:count]
    stamp = 1_700_000_123_456_789_012
    head = messages.header(frame_id, stamp)
    poses = []
    for point, rotation in zip(points, rotations, strict=True):
        pose = PoseStamped(header=head)
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in point)
        q = matrix_to_quaternion(rotation)
        o = pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in q)
        poses.append(pose)
    assert deserialize_message(result_messages.path_bytes(points, rotations, frame_id, stamp), Path) == \
        Path(header=head, poses=poses)
    decoded = result_messages.path_msg(points, rotations, frame_id, stamp)
    assert decoded.header == head and len(decoded.poses) == count
    for pose, point, rotation in zip(decoded.poses, points, rotations, strict=True):
        assert pose.header == head
        np.testing.assert_array_equal([pose.pose.position.x, pose.pose.position.y, pose.pose.position.z], point)
        q = pose.pose.orientation
        np.testing.assert_allclose([q.x, q.y, q.z, q.w], matrix_to_quaternion(rotation), atol=1e-12)


@pytest.mark.parametrize("frame_id", ["", "ntcr_base", "abc"])
@pytest.mark.parametrize("triangles", [0, 1, 5])
def test_mesh_marker_and_mesh_bytes_decode_as_the_point_by_point_messages(frame_id, triangles):
    vertices = RNG.normal(size=(triangles + 2, 3))
    faces = np.array([[i, i + 1, i + 2] for i in range(triangles)], dtype=np.int64).reshape(-1, 3)
    marker = Marker(header=messages.header(frame_id, 42), ns="mesh", id=0, type=Marker.TRIANGLE_LIST,
                    action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 1.0
    marker.color = ColorRGBA(r=0.7, g=0.75, b=0.8, a=1.0)
    marker.points = [Point(x=x, y=y, z=z) for x, y, z in vertices[faces.reshape(-1)].tolist()]
    # float32 fields (the colour) compare as they travel: both through a deserialization
    assert deserialize_message(result_messages.mesh_marker_bytes(vertices, faces, frame_id, 42), Marker) == \
        deserialize_message(serialize_message(marker), Marker)
    mesh = Mesh(vertices=[Point(x=x, y=y, z=z) for x, y, z in vertices.tolist()],
                triangles=[MeshTriangle(vertex_indices=t) for t in faces.astype(np.uint32).tolist()])
    assert deserialize_message(result_messages.mesh_msg_bytes(vertices, faces), Mesh) == mesh
    got_vertices, got_triangles = result_messages.mesh_from_msg(result_messages.mesh_msg(vertices, faces))
    np.testing.assert_array_equal(got_vertices, vertices)
    np.testing.assert_array_equal(got_triangles, faces)


@pytest.mark.parametrize("triangles", [1, 2, 3])
def test_points_spliced_after_a_count_that_needs_padding_decode_as_rclpy_writes_them(triangles):
    # The vertices' count of a Mesh with an odd number of triangles ends on an 8-byte boundary minus 4: the
    # points then follow 4 bytes of padding (cdr._points_count_offset's second case, which no Marker reaches).
    faces = [MeshTriangle(vertex_indices=[0, 1, 2]) for _ in range(triangles)]
    vertices = RNG.normal(size=(5, 3))
    built = Mesh(triangles=faces, vertices=[Point(x=x, y=y, z=z) for x, y, z in vertices.tolist()])
    spliced = cdr.with_points(Mesh(triangles=faces), "vertices", vertices)
    reference = serialize_message(built)
    assert len(spliced) == len(reference)
    assert deserialize_message(spliced, Mesh) == built


def test_an_oversized_cloud_is_refused_from_its_header():
    msg = PointCloud2(width=10_000_000, height=1)  # no data: the header alone decides
    with pytest.raises(messages.RefusedInputError, match="10000000 points exceeds max_points 1000") as error:
        messages.check_point_count(msg, 1000)
    assert error.value.reason == "oversized"
    messages.check_point_count(PointCloud2(width=1000, height=1), 1000)
    # still serialized: the same rule read from the CDR header, whatever the frame_id's length pads it to
    raw = serialize_message(PointCloud2(header=Header(frame_id="ntcr_base"), width=5_000, height=2))
    with pytest.raises(messages.RefusedInputError, match="5000x2 = 10000 points exceeds max_points 1000"):
        messages.check_point_count(raw, 1000)
    messages.check_point_count(raw, 10_000)
    messages.check_point_count(raw[:20], 1000)  # no header to read: decoding refuses it by its fault


def test_pixels_outside_the_camera_image_are_refused():
    pixels = np.array([[0, 0], [16000, 5]], dtype=np.int32)
    with pytest.raises(messages.RefusedInputError, match=r"outside the 848x480 image of camera cam_a") as error:
        messages.check_pixels(pixels, 848, 480, "camera cam_a")
    assert error.value.reason == "inconsistent"
    with pytest.raises(messages.RefusedInputError):
        messages.check_pixels(np.array([[-1, 3]], np.int32), 848, 480, "camera cam_a")
    messages.check_pixels(np.array([[847, 479], [0, 0]], np.int32), 848, 480, "camera cam_a")


@pytest.mark.parametrize("field, value, expected", [
    ("fx", math.inf, "fx is inf"), ("cx", math.nan, "cx is nan"), ("fy", 0.0, "fy is 0.0"),
    ("fx", -300.0, "fx is -300.0"), ("fy", 1e12, "fy is 1000000000000.0"), ("cx", 1e9, "cx is 1000000000.0"),
    ("cy", -5000.0, "cy is -5000.0"),
])
def test_camera_info_with_an_impossible_value_is_refused_naming_it(field, value, expected):
    k = {"fx": 0, "cx": 2, "fy": 4, "cy": 5}
    info = CameraInfo(width=848, height=480)
    values = [430.0, 0.0, 424.0, 0.0, 430.0, 240.0, 0.0, 0.0, 1.0]
    values[k[field]] = value
    info.k = values
    with pytest.raises(messages.RefusedInputError, match=expected):
        messages.intrinsics_from_camera_info(info)
    values[k[field]] = 400.0
    info.k = values
    assert messages.intrinsics_from_camera_info(info).width == 848


def test_notch_markers_are_oriented_by_the_centreline_frames():
    rotations = random_rotations(3)
    notches = [{"index": i, "width": 1.5e-3} for i in range(3)]
    markers = result_messages.NotchMarkers(1.75e-3).array(notches, RNG.normal(size=(3, 3)), rotations, "ntcr_base",
                                                           5).markers
    discs = [m for m in markers if m.ns == "notches" and m.action == Marker.ADD]
    assert len(discs) == 3
    for disc, rotation in zip(discs, rotations, strict=True):
        q = disc.pose.orientation
        np.testing.assert_allclose([q.x, q.y, q.z, q.w], matrix_to_quaternion(rotation), atol=1e-12)


def test_notch_markers_kept_between_frames_show_only_the_current_notches():
    """The markers' objects are reused frame to frame: the second frame's array holds its own notches, stamp and
    widths, nothing left over from the first."""
    markers = result_messages.NotchMarkers(1.75e-3)
    first = [{"index": i, "width": 1.5e-3} for i in range(4)]
    markers.array(first, RNG.normal(size=(4, 3)), random_rotations(4), "ntcr_base", 5)
    second = [{"index": 2, "width": 1.2e-3}, {"index": 7, "width": 1.4e-3}]
    positions = RNG.normal(size=(2, 3))
    array = markers.array(second, positions, random_rotations(2), "ntcr_base", 9).markers
    assert array[0].action == Marker.DELETEALL
    assert [(m.ns, m.id) for m in array[1:]] == [("notches", 4), ("notch_labels", 5), ("notches", 14),
                                                 ("notch_labels", 15)]
    assert all(m.header.stamp.nanosec == 9 for m in array)
    assert [m.scale.z for m in array[1::2]] == [1.2e-3, 1.4e-3]
    assert [m.text for m in array[2::2]] == ["2: 1.20 mm", "7: 1.40 mm"]
    np.testing.assert_allclose([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in array[1::2]],
                               positions)
    # a published message is serialized: both notches' markers are distinct objects in it
    assert len({id(m) for m in array}) == len(array)


def stage_cloud(pixels, camera, footprint=1e-4) -> PointCloud2:
    """A stage cloud of len(pixels) points in ntcr_base with the given pixels, camera index and footprint."""
    from ntcr_recon.core.cloud.points import Cloud

    pixels = np.asarray(pixels, dtype=np.int32)
    cloud = Cloud(RNG.normal(size=(len(pixels), 3)) * 1e-3, None, np.full(len(pixels), camera, np.int8), 5,
                  footprint, pixels)
    return messages.stage_cloud_to_msg(cloud, "ntcr_base")


@pytest.fixture(scope="module")
def rig():
    from support import tiny_rig

    from ntcr_recon.core.config.rig import rig_config_from_mapping

    return rig_config_from_mapping(tiny_rig.rig_parameters())


def test_a_stage_cloud_with_pixels_or_a_camera_the_rig_cannot_have_is_refused(rig):
    # review: a 2-point cloud spanning 16000 px made the filters allocate a 2 GB pixel grid
    width, height = rig.cameras[rig.camera_names[0]].width, rig.cameras[rig.camera_names[0]].height
    with pytest.raises(messages.RefusedInputError, match="outside the") as error:
        messages.stage_cloud_from_msg(stage_cloud([[0, 0], [16000, 16000]], 0), "ntcr_base", rig)
    assert error.value.reason == "inconsistent"
    with pytest.raises(messages.RefusedInputError, match="camera index 2 but the rig has 2 cameras"):
        messages.stage_cloud_from_msg(stage_cloud([[0, 0], [1, 1]], len(rig.camera_names)), "ntcr_base", rig)
    cloud = messages.stage_cloud_from_msg(stage_cloud([[0, 0], [width - 1, height - 1]], 1), "ntcr_base", rig)
    assert cloud.pixel.max() == width - 1 and list(cloud.camera) == [1, 1]


@pytest.mark.parametrize("footprint", [1e-12, math.inf, 0.5, -1e-4])
def test_a_stage_cloud_with_an_impossible_pixel_footprint_is_refused(footprint):
    # review: a footprint of 1e-12 m made the notch search cut the tube in 4e11 cells
    with pytest.raises(messages.RefusedInputError, match="pixel_footprint") as error:
        messages.stage_cloud_from_msg(stage_cloud([[0, 0], [1, 1]], 0, footprint), "ntcr_base")
    assert error.value.reason == "inconsistent"
    for usable in (0.0, 1e-4):  # 0: unknown
        assert messages.stage_cloud_from_msg(stage_cloud([[0, 0], [1, 1]], 0, usable), "ntcr_base").pixel_footprint \
            == pytest.approx(usable)


def test_fusion_buffers_what_the_rig_needs_by_default(rig):
    # review: the default queue of 10 frames was less than a 0.5 s camera timeout at 30 Hz (15 frames)
    from dataclasses import replace

    from ntcr_recon.ros.fusion_node import PARAMETERS, rig_queue_size

    assert PARAMETERS["queue_size"][0] == 0  # 0: from the rig
    slow = replace(rig, fusion=replace(rig.fusion, camera_timeout=0.5, slop=0.01))
    assert rig_queue_size(slow) == math.ceil(0.51 * 30) + 2 == 18


def test_every_node_reading_clouds_declares_the_same_max_points():
    # review: the max_points parameter was declared four times (four texts)
    from ntcr_recon.ros import filter_node, fusion_node, mesh_node, relocation_node
    from ntcr_recon.ros.node_support import max_points_parameter

    declared = [module.PARAMETERS["max_points"] for module in (fusion_node, filter_node, relocation_node, mesh_node)]
    assert all(parameter == max_points_parameter() for parameter in declared)
