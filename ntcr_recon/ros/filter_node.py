"""filter_node: `<ns>/fused/points` -> `<ns>/filtered/points`, the core's filter chain (crop box, colour
condition, statistical outlier removal Eq. 5, moving least squares Eq. 6, voxel grid) as the rig
configuration's `filters` section sets it. Clouds must be in the configured base frame; a cloud of more than
`max_points` points is dropped before it is decoded (logged, counted on /diagnostics): the subscription takes
the serialized bytes, whose header gives the size, and decodes only what it keeps. The filtering is the
offline command's own stage function, `core.cloud.filters.filter_cloud`.
"""

from __future__ import annotations

import sys
import time

from sensor_msgs.msg import PointCloud2

from ntcr_recon.core.cloud.filters import filter_cloud
from ntcr_recon.ros.messages import decode_cloud, stage_cloud_from_msg, stage_cloud_to_msg
from ntcr_recon.ros.node_stats import NodeStats
from ntcr_recon.ros.node_support import STAGE_INPUT_QOS, STAGE_QOS, RigNode, guarded, max_points_parameter, run_node
from ntcr_recon.ros.topics import stage_topic

PARAMETERS = {
    "max_points": max_points_parameter(),
}


class FilterNode(RigNode):
    def __init__(self, node_name: str = "filter_node") -> None:
        super().__init__(node_name, PARAMETERS)
        self.stats = NodeStats(self, "ntcr_recon: filter")
        self._publisher = self.create_publisher(PointCloud2, stage_topic(self.rig.topics, "filtered/points"),
                                                STAGE_QOS)
        self.create_subscription(PointCloud2, stage_topic(self.rig.topics, "fused/points"), self._on_cloud,
                                 STAGE_INPUT_QOS,
                                 raw=True)
        self.get_logger().info("filtering fused clouds")

    def configure(self, rig, params: dict) -> None:
        self.rig, self._params = rig, params

    @guarded
    def _on_cloud(self, raw: bytes) -> None:
        self.stats.received()
        started = time.perf_counter()
        msg = decode_cloud(raw, self._params["max_points"])  # refused when oversized before decoding
        cloud = filter_cloud(stage_cloud_from_msg(msg, self.rig.base_frame, self.rig), self.rig)
        self._publisher.publish(stage_cloud_to_msg(cloud, self.rig.base_frame))
        self.stats.published(cloud.stamp_ns, started)


def main(args: list[str] | None = None) -> int:
    return run_node(FilterNode, args)


if __name__ == "__main__":
    sys.exit(main())
