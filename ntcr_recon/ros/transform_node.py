"""transform_node: republish a PointCloud2 moved into a target frame by a configured rigid transform.

Subscribes `points_in` (sensor-data QoS), publishes `points_out` (reliable, depth 1); remap both.
Parameters: `translation` [x, y, z] and `rotation` [x, y, z, w] (pose of the input frame in the target
frame, p_target = R p_in + t), `target_frame`, and `source_frame` (when set, a cloud in another frame is
refused: a transform applied to the wrong frame would silently give a wrong cloud).
"""

from __future__ import annotations

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2

from ntcr_recon.core.base.transforms import rigid_transform, transform_points
from ntcr_recon.io.pointcloud import cloud_from_msg, cloud_to_msg, stamp_to_ns
from ntcr_recon.ros.messages import RCLPY
from ntcr_recon.ros.node_support import (
    SENSOR_QOS,
    STAGE_QOS,
    ParameterError,
    describe,
    finite_vector,
    guarded,
    run_node,
    validate_on_change,
)

PARAMETERS = {
    "translation": ([0.0, 0.0, 0.0], "translation [x, y, z] in metres of the input frame in the target frame"),
    "rotation": ([0.0, 0.0, 0.0, 1.0], "unit quaternion [x, y, z, w] of the input frame in the target frame"),
    "target_frame": ("ntcr_base", "frame_id of the published cloud"),
    "source_frame": ("", "frame_id the input must carry; empty accepts any"),
}


def transform_from_parameters(values: dict) -> np.ndarray:
    """The 4x4 transform the parameters describe; ParameterError naming a bad one."""
    translation = finite_vector("translation", values["translation"], 3)
    rotation = finite_vector("rotation", values["rotation"], 4)
    if not values["target_frame"]:
        raise ParameterError("parameter 'target_frame' must not be empty")
    try:
        return rigid_transform(translation, rotation)
    except ValueError as error:
        raise ParameterError(f"parameter 'rotation': {error}") from error


class TransformNode(Node):
    def __init__(self) -> None:
        super().__init__("transform_node")
        for name, (default, description) in PARAMETERS.items():
            self.declare_parameter(name, default, describe(description))
        self._apply(self._current_values())
        validate_on_change(self, list(PARAMETERS), self._apply)
        self._publisher = self.create_publisher(PointCloud2, "points_out", STAGE_QOS)
        self.create_subscription(PointCloud2, "points_in", self._on_cloud, SENSOR_QOS)
        self.get_logger().info(f"moving clouds into '{self._target_frame}'")

    def _current_values(self) -> dict:
        return {name: self.get_parameter(name).value for name in PARAMETERS}

    def _apply(self, values: dict) -> None:
        self._transform = transform_from_parameters(values)
        self._target_frame = values["target_frame"]
        self._source_frame = values["source_frame"]

    @guarded
    def _on_cloud(self, msg: PointCloud2) -> None:
        if self._source_frame and msg.header.frame_id != self._source_frame:
            raise ValueError(f"cloud in frame '{msg.header.frame_id}', expected '{self._source_frame}'")
        xyz, rgb = cloud_from_msg(msg, drop_nan=True)
        moved = transform_points(self._transform, xyz)
        self._publisher.publish(cloud_to_msg(moved, rgb, frame_id=self._target_frame,
                                             stamp_ns=stamp_to_ns(msg.header.stamp), msgtypes=RCLPY))


def main(args: list[str] | None = None) -> int:
    return run_node(TransformNode, args)
