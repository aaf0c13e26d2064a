"""NodeStats' drop log: limited by kind (reason, text without its numbers), so a stream of bad frames whose texts
differ only in their numbers cannot flood the log."""

from __future__ import annotations

from types import SimpleNamespace

from ntcr_recon.ros import node_stats


class RecordingNode:
    """The part of an rclpy Node that NodeStats uses, recording the error lines."""

    def __init__(self) -> None:
        self.errors: list[str] = []

    def create_publisher(self, *args):
        return SimpleNamespace(publish=lambda msg: None)

    def create_timer(self, *args, **kwargs):
        return None

    def get_logger(self):
        return SimpleNamespace(error=self.errors.append, info=lambda text: None)

    def get_name(self) -> str:
        return "recording_node"


def test_drops_are_logged_once_per_reason_and_period_however_their_texts_differ(monkeypatch):
    # review: keyed by the exact text, "cloud of N points" with N changing every frame logged an ERROR per frame
    now = [100.0]
    monkeypatch.setattr(node_stats.time, "monotonic", lambda: now[0])
    node = RecordingNode()
    stats = node_stats.NodeStats(node, "test", log_period=5.0)
    for count in range(30):
        stats.dropped("oversized", f"cloud of {1000 + count} points exceeds max_points 999")
    stats.dropped("oversized", "cloud of 1e+06 points, 2.5 MB, exceeds max_points 999")
    stats.dropped("oversized", "another defect of the same reason")  # a different kind: told too
    stats.dropped("inconsistent", "pixel_u/pixel_v outside the image")
    assert node.errors == ["dropped a message (oversized): cloud of 1000 points exceeds max_points 999",
                           "dropped a message (oversized): cloud of 1e+06 points, 2.5 MB, exceeds max_points 999",
                           "dropped a message (oversized): another defect of the same reason",
                           "dropped a message (inconsistent): pixel_u/pixel_v outside the image"]
    assert stats.drops == {"oversized": 32, "inconsistent": 1}
    now[0] += 5.0  # a log period later the next one is logged with the number held back
    stats.dropped("oversized", "cloud of 2000 points exceeds max_points 999")
    assert node.errors[-1] == ("dropped a message (oversized): cloud of 2000 points exceeds max_points 999 "
                               "(29 more like it since)")
