"""fusion_node: the cameras' clouds, paired by stamp -> `<ns>/fused/points` in the base frame (paper Eq. 9).

Subscribes every configured camera's `<ns>/<cam>/depth/color/points` (reliable; `camera_reliability:=best_effort`
for a driver publishing sensor-data QoS; the cloud must carry the camera's configured frame_id) and
`<ns>/<cam>/depth/camera_info` (its focal length gives the pixel footprint the later stages scale with, its size
bounds the clouds' pixel fields). When a buffered frame is released, and alone or not, is the core's
`core.cloud.pairing.FramePairer` (pairs within `fusion.slop`, a camera silent past `fusion.camera_timeout` of the
cameras' own stamps, `queue_size` frames per camera, superseded pairs, a jump back of the stamps); the fusion is
`core.cloud.fusion.fuse` with each camera's extrinsics. This node converts, calls them and publishes; a silent
camera is logged and named on `/diagnostics` (WARN) until it returns (OK).

Every input is bounded before anything is allocated for it: a cloud of more than `max_points` points, or
whose pixel_u/pixel_v lie outside the camera's image (camera_info, else the configured width/height), and a
camera_info with a non-finite or non-positive focal length, centre or size are dropped with a log line naming
what was wrong, and counted (`/diagnostics`: dropped.<reason>). An empty cloud is a camera that saw nothing in
its crop box (camera_node publishes only the points inside it): a frame of that camera with no points, paired
as any other; a pair in which no camera saw anything is not published (counted: dropped.empty).
"""

from __future__ import annotations

import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import CameraInfo, PointCloud2

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import FramePair, fuse
from ntcr_recon.core.cloud.pairing import FramePairer, InForce, Release
from ntcr_recon.io.pointcloud import stamp_to_ns
from ntcr_recon.ros.messages import (
    RefusedInputError,
    camera_cloud_from_msg,
    camera_frame,
    check_pixels,
    decode_cloud,
    intrinsics_from_camera_info,
    stage_cloud_to_msg,
)
from ntcr_recon.ros.node_stats import NodeStats
from ntcr_recon.ros.node_support import (
    CAMERA_QOS,
    SENSOR_QOS,
    STAGE_QOS,
    ParameterError,
    RigNode,
    describe,
    guarded,
    max_points_parameter,
    run_node,
)
from ntcr_recon.ros.topics import stage_topic

PARAMETERS = {
    "queue_size": (0, describe("frames buffered per camera while waiting for a partner; 0: what the rig needs, "
                               "ceil((fusion.camera_timeout + fusion.slop) * fps) + 2", minimum=0, maximum=300,
                               integer=True)),
    "publish_unpaired": (False, describe("publish a frame whose partner was lost (the other camera is alive but "
                                         "its frame never came) alone, as the offline command fuses it; false: "
                                         "drop it and count it")),
    "diagnostics_period": (1.0, describe("seconds between /diagnostics messages (read at start)", minimum=0.05,
                                         maximum=60.0, read_only=True)),
    "max_points": max_points_parameter(),
    "camera_reliability": ("reliable", describe(
        "how the camera clouds and camera_infos are subscribed: reliable (camera_node, realsense-ros's default) | "
        "best_effort (a driver publishing sensor-data QoS, e.g. realsense-ros with pointcloud.pointcloud_qos:="
        "SENSOR_DATA: a reliable subscription never hears it)", read_only=True)),
}
CAMERA_RELIABILITY = {"reliable": CAMERA_QOS, "best_effort": SENSOR_QOS}
DIAGNOSTIC_NAME = "ntcr_recon: fusion"


def rig_queue_size(rig) -> int:
    """Frames per camera a pairer must hold: all a camera sends while the other may still be heard from (the
    camera timeout plus the slop, at the fastest camera's rate), and two to spare. A fixed 10 was less than a
    0.5 s timeout at 30 Hz (15): frames were superseded before their partner was given up on."""
    fps = max(rig.cameras[name].fps for name in rig.camera_names)
    return min(math.ceil((rig.fusion.camera_timeout + rig.fusion.slop) * fps) + 2, 300)


class FusionNode(RigNode):
    def __init__(self, node_name: str = "fusion_node") -> None:
        self._pairer: FramePairer | None = None
        super().__init__(node_name, PARAMETERS)
        # each camera's camera_infos by stamp: a cloud takes the one in force at its own stamp, whichever came first
        self._intrinsics: dict[str, InForce] = {name: InForce() for name in self.rig.camera_names}
        self._publisher = self.create_publisher(PointCloud2, stage_topic(self.rig.topics, "fused/points"), STAGE_QOS)
        self.stats = NodeStats(self, DIAGNOSTIC_NAME, diagnostics_period=self._params["diagnostics_period"],
                               status=self._status)
        camera_qos = CAMERA_RELIABILITY[self._params["camera_reliability"]]
        for name in self.rig.camera_names:
            # serialized: a cloud's size is read from its header before it is decoded (a 5-million-point one
            # decoded by rclpy took 75-150 MB the process kept)
            self.create_subscription(PointCloud2, self.rig.topics.camera_topic(name, "points"),
                                     lambda raw, name=name: self._on_cloud((name, raw)), camera_qos, raw=True)
            self.create_subscription(CameraInfo, self.rig.topics.camera_topic(name, "depth_info"),
                                     lambda msg, name=name: self._on_info((name, msg)), camera_qos)
        self.get_logger().info(f"fusing {', '.join(self.rig.camera_names)} within {self.rig.fusion.slop * 1e3:.1f} ms "
                               f"into '{self.rig.base_frame}'")

    @property
    def counts(self) -> dict[str, int]:
        return self._pairer.counts

    def configure(self, rig, params: dict) -> None:
        if params["camera_reliability"] not in CAMERA_RELIABILITY:
            raise ParameterError(f"parameter 'camera_reliability' must be one of {tuple(CAMERA_RELIABILITY)}, "
                                 f"got '{params['camera_reliability']}'")
        self.rig, self._params = rig, params
        slop_ns, timeout_ns = int(rig.fusion.slop * 1e9), int(rig.fusion.camera_timeout * 1e9)
        queue_size = int(params["queue_size"]) or rig_queue_size(rig)
        pairer = self._pairer
        if pairer is None or pairer.cameras != tuple(rig.camera_names):
            self._pairer = FramePairer(rig.camera_names, slop_ns, timeout_ns, queue_size,
                                       bool(params["publish_unpaired"]))
        else:  # keep what is buffered and counted
            pairer.slop_ns, pairer.timeout_ns = slop_ns, timeout_ns
            pairer.publish_unpaired = bool(params["publish_unpaired"])
            pairer.resize(queue_size)

    @guarded
    def _on_info(self, item) -> None:
        name, msg = item
        try:
            intrinsics = intrinsics_from_camera_info(msg)
            self._intrinsics.setdefault(name, InForce()).add(stamp_to_ns(msg.header.stamp), intrinsics)
        except RefusedInputError as error:
            raise RefusedInputError(f"camera_info of {name}: {error}", error.reason) from error

    @guarded
    def _on_cloud(self, item) -> None:
        name, raw = item
        self.stats.received()
        started = time.perf_counter()
        msg = decode_cloud(raw, self._params["max_points"])  # refused when oversized before decoding
        xyz, rgb, pixel, organised_width = camera_cloud_from_msg(msg, self.rig.cameras[name].frame_id)
        stamp = stamp_to_ns(msg.header.stamp)
        if pixel is not None:  # before camera_frame lays them out on a grid of their span
            camera = self.rig.cameras[name]
            size = self._intrinsics_at(name, stamp) or Intrinsics(camera.width, camera.height, 1.0, 1.0, 0.0, 0.0)
            check_pixels(pixel, size.width, size.height, f"camera {name}")
        step = self._pairer.add(name, stamp, (xyz, rgb, pixel, organised_width))
        if step.restarted_after_jump_s is not None:
            self.get_logger().warning(f"camera '{name}' stamps jumped back by {step.restarted_after_jump_s:.3f} s: "
                                      "pairing starts afresh")
        for silent in step.newly_silent:
            heard = sorted(set(self.rig.camera_names) - self._pairer.silent)
            self.get_logger().warning(f"camera '{silent}' silent for more than {self.rig.fusion.camera_timeout} s "
                                      f"of the other cameras' stamps: publishing {', '.join(heard) or 'nothing'} "
                                      "alone")
        for back in step.back:
            self.get_logger().info(f"camera '{back}' is back: pairing again")
        if step.newly_silent or step.back:
            self.stats.publish_diagnostics()
        if step.release is not None:
            self._publish(step.release, started)

    def _publish(self, release: Release, started: float) -> None:
        # with camera_info known, the core gives the fused cloud its pixel footprint (0 until then)
        frames = {name: camera_frame(name, release.stamp_ns, xyz, rgb, pixel, width,
                                     self._intrinsics_at(name, release.stamp_ns))
                  for name, (xyz, rgb, pixel, width) in release.items.items()}
        cloud = fuse(FramePair(release.stamp_ns, frames), self.rig)
        if not len(cloud):  # no camera saw anything in the crop box: nothing for the stages (counted, not logged)
            self.stats.drops["empty"] += 1
            return
        self._publisher.publish(stage_cloud_to_msg(cloud, self.rig.base_frame))
        self.stats.published(release.stamp_ns, started)

    def _intrinsics_at(self, name: str, stamp_ns: int) -> Intrinsics | None:
        """The camera's intrinsics in force at stamp_ns (core.cloud.pairing.InForce); None before any camera_info."""
        entry = self._intrinsics.get(name, InForce()).at(stamp_ns)
        return None if entry is None else entry[1]

    def _status(self) -> tuple[bytes | None, str, dict[str, object]]:
        pairer = self._pairer
        if pairer.silent:
            heard = [n for n in self.rig.camera_names if n not in pairer.silent]
            level = DiagnosticStatus.WARN if heard else DiagnosticStatus.ERROR
            message = (f"missing camera(s): {', '.join(sorted(pairer.silent))}; publishing "
                       f"{', '.join(heard) or 'nothing'} alone")
        elif all(pairer.newest(name) is None for name in self.rig.camera_names):
            level, message = DiagnosticStatus.WARN, "no camera has sent a cloud yet"
        else:
            level, message = None, f"pairing {', '.join(self.rig.camera_names)}"
        values: dict[str, object] = {"missing": ",".join(sorted(pairer.silent)), **pairer.counts}
        for name in self.rig.camera_names:
            lag = pairer.lag_s(name)
            values[f"{name}.lag_s"] = "never" if lag is None else f"{lag:.3f}"
        return level, message, values


def main(args: list[str] | None = None) -> int:
    return run_node(FusionNode, args)


if __name__ == "__main__":
    sys.exit(main())
