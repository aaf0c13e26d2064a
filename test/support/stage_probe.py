"""Test-side helpers for one stage node: publish its input, collect its output, check it survives bad input."""

from __future__ import annotations

from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from ntcr_recon.ros.node_support import STAGE_QOS
from support import tiny_rig

# Reliable like the stages' publishers, but deep enough that a slow test spin loses nothing.
COLLECT_RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


def set_parameter(graph, node: str, name: str, value):
    """SetParameters on `node` (a str, float or bool value); returns the result (successful, reason)."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return graph.call(SetParameters, f"/{node}/set_parameters", request).results[0]


def ply_face_count(path) -> int:
    """The face count a PLY header declares (the file is written whole or not at all)."""
    header = path.read_bytes().split(b"end_header", 1)[0].decode("ascii")
    return int(next(line.split()[2] for line in header.splitlines() if line.startswith("element face")))


class StageProbe:
    """Publishes clouds on `input_topic` and collects what the node under test publishes on `output_topic`."""

    def __init__(self, graph, process, input_topic: str, output_topic: str, output_type=PointCloud2,
                 input_qos=STAGE_QOS, output_qos=COLLECT_RELIABLE) -> None:
        self.graph, self.process = graph, process
        self.received: list = []
        graph.node.create_subscription(output_type, output_topic, self.received.append, output_qos)
        self.publisher = graph.node.create_publisher(PointCloud2, input_topic, input_qos)
        graph.wait_for_subscribers(self.publisher)

    def send_and_wait(self, msg, timeout: float = 20.0) -> object:
        """Publish `msg` until an output arrives: once on a reliable input (a node that keeps state, like the
        relocation's warm start, must see it once), again every second on a best-effort one."""
        count = len(self.received)
        reliable = self.publisher.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        for attempt in range(int(timeout)):
            if attempt == 0 or not reliable:
                self.publisher.publish(msg)
            if self.graph.spin_until(lambda: len(self.received) > count, 1.0):
                return self.received[-1]
        raise AssertionError(f"no output within {timeout} s; logs:\n{self.graph.all_logs()}")

    def assert_refuses(self, defect: str, frame_id: str, stamp_ns: int = 5_000) -> None:
        """The malformed cloud is logged with its defect named, nothing is published, the node lives on."""
        count = len(self.received)
        log_before = len(self.graph.log_of(self.process))
        self.publisher.publish(tiny_rig.malformed_cloud(defect, frame_id, stamp_ns))
        expected = tiny_rig.MALFORMED_LOG[defect]
        assert self.graph.spin_until(lambda: expected in self.graph.log_of(self.process)[log_before:], 10.0), \
            self.graph.log_of(self.process)
        assert self.process.poll() is None
        assert len(self.received) == count
