"""Topic names of the graph, from the rig configuration's `topics` section (no rclpy import).

Camera topics follow realsense-ros (`TopicConfig.camera_topic`): `<ns>/<cam>/depth/image_rect_raw`,
`.../depth/camera_info`, `.../color/image_rect_raw`, `.../depth/color/points`; stage topics sit under `<ns>`
(default `/ntcr`).
"""

from __future__ import annotations

from ntcr_recon.core.config.rig import TopicConfig


def stage_topic(topics: TopicConfig, name: str) -> str:
    """`<ns>/<name>`, e.g. stage_topic(topics, "fused/points") -> "/ntcr/fused/points"."""
    return "/" + "/".join(part.strip("/") for part in (topics.namespace, name) if part.strip("/"))


def edge_band_topic(topics: TopicConfig, camera: str) -> str:
    """`<ns>/<camera>/edge_band`: the band (rad) the camera's stereo matcher spoils at depth edges."""
    return stage_topic(topics, f"{camera}/edge_band")
