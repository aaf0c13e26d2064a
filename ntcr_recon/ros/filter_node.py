"""filter_node: `<ns>/fused/points` -> `<ns>/filtered/points`, the core's filter chain (crop box, colour
condition, statistical outlier removal Eq. 5, moving least squares Eq. 6, voxel grid) as the rig
configuration's `filters` section sets it. Clouds must be in the configured base frame.
"""

from __future__ import annotations

import sys

from sensor_msgs.msg import PointCloud2

from ntcr_recon.core.pipeline import Reconstructor
from ntcr_recon.ros.messages import stage_cloud_from_msg, stage_cloud_to_msg
from ntcr_recon.ros.node_support import STAGE_QOS, RigNode, guarded, run_node
from ntcr_recon.ros.topics import stage_topic


class FilterNode(RigNode):
    def __init__(self) -> None:
        super().__init__("filter_node", {})
        self._publisher = self.create_publisher(PointCloud2, stage_topic(self.rig.topics, "filtered/points"),
                                                STAGE_QOS)
        self.create_subscription(PointCloud2, stage_topic(self.rig.topics, "fused/points"), self._on_cloud, STAGE_QOS)
        self.get_logger().info("filtering fused clouds")

    def configure(self, rig, params: dict) -> None:
        self.rig, self._reconstructor = rig, Reconstructor(rig)

    @guarded
    def _on_cloud(self, msg: PointCloud2) -> None:
        cloud = self._reconstructor.filter(stage_cloud_from_msg(msg, self.rig.base_frame))
        self._publisher.publish(stage_cloud_to_msg(cloud, self.rig.base_frame))


def main(args: list[str] | None = None) -> int:
    return run_node(FilterNode, args)


if __name__ == "__main__":
    sys.exit(main())
