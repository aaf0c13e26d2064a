"""The relocation's results <-> ROS messages: centreline (nav_msgs/Path), tip (PoseStamped), notches
(Float64MultiArray and RViz markers), meshes (Marker TRIANGLE_LIST, shape_msgs/Mesh). Clouds: ros/messages.py.

Notches as `std_msgs/Float64MultiArray` (`<ns>/notches`), readable without this package:
    layout.dim[0] = {label: "notch", size: N, stride: 4 * N}
    layout.dim[1] = {label: "index,center_s_m,width_m,bend_rad", size: 4, stride: 4}
    data = [index_0, center_s_0, width_0, bend_0, index_1, ...]   (row-major, metres / radians; bend NaN
           when the shape does not give it)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from geometry_msgs.msg import Pose, PoseStamped
from nav_msgs.msg import Path
from shape_msgs.msg import Mesh
from std_msgs.msg import ColorRGBA, Float64MultiArray, MultiArrayDimension, MultiArrayLayout
from visualization_msgs.msg import Marker, MarkerArray

from ntcr_recon.core.base.transforms import matrix_to_quaternion
from ntcr_recon.ros import cdr
from ntcr_recon.ros.messages import header

NOTCH_LAYOUT_LABEL = "index,center_s_m,width_m,bend_rad"


# ---- centreline, tip and notches ------------------------------------------------------------------------------

def pose(position: Sequence[float], rotation: np.ndarray | None = None) -> Pose:
    """A Pose from a position and an optional 3x3 rotation (identity when None)."""
    result = Pose()
    result.position.x, result.position.y, result.position.z = (float(v) for v in position)
    if rotation is not None:
        q = matrix_to_quaternion(np.asarray(rotation, dtype=float))
        result.orientation.x, result.orientation.y, result.orientation.z, result.orientation.w = (float(v) for v in q)
    return result


def quaternions(rotations: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions (x, y, z, w), w >= 0, of (N, 3, 3) rotations, in one call."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(rotations, dtype=float).reshape(-1, 3, 3)).as_quat()
    return np.where(q[:, 3:4] < 0, -q, q)


def path_bytes(points: np.ndarray, rotations: np.ndarray | None, frame_id: str, stamp_ns: int) -> bytes:
    """nav_msgs/Path through `points` (N, 3), oriented by `rotations` (N, 3, 3) when given, serialized (what a
    publisher takes as it is: no Python object per pose)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(points), 1)) if rotations is None else quaternions(rotations)
    return cdr.path(points, q, frame_id, stamp_ns)


def path_msg(points: np.ndarray, rotations: np.ndarray | None, frame_id: str, stamp_ns: int) -> Path:
    """nav_msgs/Path through `points` (N, 3), oriented by `rotations` (N, 3, 3) when given."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(path_bytes(points, rotations, frame_id, stamp_ns), Path)


def frame_rotations(normals: np.ndarray, binormals: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations whose columns are x = normal (notch side), y = binormal, z = tangent."""
    return np.stack([normals, binormals, tangents], axis=-1)


def centerline_path_bytes(centerline, frame_id: str, stamp_ns: int) -> bytes:
    """A core Centerline as a serialized nav_msgs/Path (see `centerline_path_msg`), for publishing."""
    rotations = frame_rotations(centerline.normals, centerline.binormals, centerline.tangents)
    return path_bytes(centerline.points, rotations, frame_id, stamp_ns)


def centerline_path_msg(centerline, frame_id: str, stamp_ns: int) -> Path:
    """A core Centerline as nav_msgs/Path: poses base to tip, x axis to the notch side, z along the tangent."""
    rotations = frame_rotations(centerline.normals, centerline.binormals, centerline.tangents)
    return path_msg(centerline.points, rotations, frame_id, stamp_ns)


def pose_stamped(position: Sequence[float], rotation: np.ndarray | None, frame_id: str, stamp_ns: int
                 ) -> PoseStamped:
    return PoseStamped(header=header(frame_id, stamp_ns), pose=pose(position, rotation))


def notches_array(notches: Sequence[dict]) -> Float64MultiArray:
    """Notches ({index, center_s, width, bend}) in the documented Float64MultiArray layout (module doc)."""
    rows = [[float(n["index"]), float(n["center_s"]), float(n["width"]),
             math.nan if n.get("bend") is None else float(n["bend"])] for n in notches]
    layout = MultiArrayLayout(dim=[
        MultiArrayDimension(label="notch", size=len(rows), stride=4 * len(rows)),
        MultiArrayDimension(label=NOTCH_LAYOUT_LABEL, size=4, stride=4)])
    return Float64MultiArray(layout=layout, data=[v for row in rows for v in row])


def notches_from_array(msg: Float64MultiArray) -> list[dict]:
    """The inverse of `notches_array` (what a consumer without this package does by hand)."""
    if len(msg.layout.dim) != 2 or msg.layout.dim[1].label != NOTCH_LAYOUT_LABEL:
        raise ValueError(f"not a notch array: layout {[d.label for d in msg.layout.dim]}")
    values = np.asarray(msg.data, dtype=float).reshape(-1, 4)
    return [{"index": int(row[0]), "center_s": row[1], "width": row[2],
             "bend": None if math.isnan(row[3]) else row[3]} for row in values]


class NotchMarkers:
    """The notches for RViz: one flat cylinder per notch at its centre on the centreline (axis along the tube,
    thickness = width) and a text label with the width in mm, after a DELETEALL so vanished notches disappear.

    The Marker objects of each notch index are kept from frame to frame and only their changing fields set: a
    Marker's constructor (with its nested messages) costs ~50 us, and building 33 a frame took 3 ms of
    relocation_node's time, more than all its other messages together. A publisher serializes the message
    during publish(), so reusing the objects for the next frame is safe.
    """

    def __init__(self, radius: float) -> None:
        self._radius = radius
        self._delete_all = Marker(ns="notches", action=Marker.DELETEALL)
        self._by_index: dict[int, tuple[Marker, Marker]] = {}

    def _markers_of(self, index: int) -> tuple[Marker, Marker]:
        if index not in self._by_index:
            disc = Marker(ns="notches", id=2 * index, type=Marker.CYLINDER, action=Marker.ADD,
                          color=ColorRGBA(r=1.0, g=0.5, b=0.0, a=0.6))
            disc.scale.x = disc.scale.y = 2.2 * self._radius
            label = Marker(ns="notch_labels", id=2 * index + 1, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
                           color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0))
            label.scale.z = self._radius
            label.pose.orientation.w = 1.0
            self._by_index[index] = disc, label
        return self._by_index[index]

    def array(self, notches: Sequence[dict], positions: np.ndarray, rotations: np.ndarray, frame_id: str,
              stamp_ns: int) -> MarkerArray:
        """The MarkerArray of `notches` ({index, width}) at `positions` (N, 3) oriented by `rotations`
        (N, 3, 3: x to the notch side, z along the tube)."""
        head = header(frame_id, stamp_ns)
        self._delete_all.header = head
        markers = [self._delete_all]
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        rotations = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
        orientations = quaternions(rotations) if len(rotations) else np.empty((0, 4))  # all notches in one call
        label_positions = positions + rotations[:, :, 0] * 2.0 * self._radius
        for notch, position, label_position, q in zip(notches, positions.tolist(), label_positions.tolist(),
                                                      orientations.tolist(), strict=True):
            disc, label = self._markers_of(int(notch["index"]))
            disc.header = label.header = head
            p, o = disc.pose.position, disc.pose.orientation
            p.x, p.y, p.z = position
            o.x, o.y, o.z, o.w = q
            disc.scale.z = float(notch["width"])
            p = label.pose.position
            p.x, p.y, p.z = label_position
            label.text = f"{notch['index']}: {1e3 * float(notch['width']):.2f} mm"
            markers += [disc, label]
        return MarkerArray(markers=markers)


# ---- meshes ---------------------------------------------------------------------------------------------------

def mesh_marker_bytes(vertices: np.ndarray, triangles: np.ndarray, frame_id: str, stamp_ns: int,
                      color: tuple[float, float, float, float] = (0.7, 0.75, 0.8, 1.0)) -> bytes:
    """visualization_msgs/Marker TRIANGLE_LIST, three points per triangle (RViz draws them flat-shaded),
    serialized: the corners go in as one array, not one Point object each."""
    marker = Marker(header=header(frame_id, stamp_ns), ns="mesh", id=0, type=Marker.TRIANGLE_LIST,
                    action=Marker.ADD)
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = 1.0
    marker.color = ColorRGBA(r=color[0], g=color[1], b=color[2], a=color[3])
    corners = np.asarray(vertices, dtype=float)[np.asarray(triangles, dtype=np.int64).reshape(-1)]
    return cdr.with_points(marker, "points", corners)


def mesh_marker(vertices: np.ndarray, triangles: np.ndarray, frame_id: str, stamp_ns: int,
                color: tuple[float, float, float, float] = (0.7, 0.75, 0.8, 1.0)) -> Marker:
    """`mesh_marker_bytes` as a Marker message."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(mesh_marker_bytes(vertices, triangles, frame_id, stamp_ns, color), Marker)


def mesh_msg_bytes(vertices: np.ndarray, triangles: np.ndarray) -> bytes:
    """shape_msgs/Mesh serialized (no header: it is in the frame of the Marker published beside it)."""
    return cdr.mesh(vertices, triangles)


def mesh_msg(vertices: np.ndarray, triangles: np.ndarray) -> Mesh:
    """shape_msgs/Mesh (no header: it is in the frame of the Marker published beside it, the base frame)."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(mesh_msg_bytes(vertices, triangles), Mesh)


def mesh_from_msg(msg: Mesh) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.array([[p.x, p.y, p.z] for p in msg.vertices], dtype=float).reshape(-1, 3)
    triangles = np.array([list(t.vertex_indices) for t in msg.triangles], dtype=np.int64).reshape(-1, 3)
    return vertices, triangles
