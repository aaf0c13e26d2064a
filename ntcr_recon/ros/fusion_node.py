"""fusion_node: the cameras' clouds, paired by stamp -> `<ns>/fused/points` in the base frame (paper Eq. 9).

Subscribes every configured camera's `<ns>/<cam>/depth/color/points` (sensor-data QoS; the cloud must carry
the camera's configured frame_id) and `<ns>/<cam>/depth/camera_info` (its focal length gives the pixel
footprint the later stages scale with). Pairing and fusion are the core's (`core.fusion.pair_frames` with
`fusion.slop`, `core.fusion.fuse` with each camera's extrinsics); this node decides only when a buffered
frame is released:
  - as soon as every camera has a frame within the slop (a pair);
  - once no partner can come any more (the other camera has already sent a later frame: the partner was
    dropped on the way): counted and dropped, or with `publish_unpaired` published alone as the offline
    command fuses an unpaired frame;
  - alone, when the other camera is silent: its newest stamp lags the newest of all by more than
    `fusion.camera_timeout`. Stamps, not the wall clock, measure the silence, so a bag replayed at any rate
    (and `use_sim_time`) behaves like the live rig. The change is logged, and `/diagnostics` says which
    camera is missing (WARN) until it returns (OK).
Stamps that jump back by more than the timeout (a bag played again) restart the pairing.
Of several pairs ready at once only the newest is fused (the others are counted as superseded).
Each camera's buffer holds at most `queue_size` frames (the oldest goes first): the node never blocks and
never grows a queue without bound.
"""

from __future__ import annotations

import sys
from collections import deque

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import CameraInfo, PointCloud2

from ntcr_recon.core.deproject import Intrinsics
from ntcr_recon.core.fusion import CameraFrame, FramePair, fuse, pair_frames
from ntcr_recon.io.pointcloud import stamp_to_ns
from ntcr_recon.ros.messages import camera_cloud_from_msg, camera_frame, diagnostics, stage_cloud_to_msg
from ntcr_recon.ros.node_support import SENSOR_QOS, STAGE_QOS, RigNode, describe, guarded, run_node
from ntcr_recon.ros.topics import stage_topic

PARAMETERS = {
    "queue_size": (10, describe("frames buffered per camera while waiting for a partner", minimum=1, maximum=300,
                                integer=True)),
    "publish_unpaired": (False, describe("publish a frame whose partner was lost (the other camera is alive but "
                                         "its frame never came) alone, as the offline command fuses it; false: "
                                         "drop it and count it")),
    "diagnostics_period": (1.0, describe("seconds between /diagnostics messages", minimum=0.05, maximum=60.0)),
}
DIAGNOSTIC_NAME = "ntcr_recon: fusion"


class FusionNode(RigNode):
    def __init__(self) -> None:
        self._buffers: dict[str, deque] = {}
        self._pixels: dict[int, np.ndarray] = {}  # id of a buffered frame -> its points' pixels (see camera_frame)
        super().__init__("fusion_node", PARAMETERS)
        self._newest: dict[str, int] = {}     # newest stamp received per camera
        self._first_stamp: int | None = None  # the first stamp of any camera: a camera never heard of is
        self._silent: set[str] = set()        # silent from then on
        self._intrinsics: dict[str, Intrinsics] = {}
        self.counts = {"pairs": 0, "alone": 0, "unpaired": 0, "superseded": 0, "dropped": 0}
        self._publisher = self.create_publisher(PointCloud2, stage_topic(self.rig.topics, "fused/points"), STAGE_QOS)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        for name in self.rig.camera_names:
            self.create_subscription(PointCloud2, self.rig.topics.camera_topic(name, "points"),
                                     lambda msg, name=name: self._on_cloud((name, msg)), SENSOR_QOS)
            self.create_subscription(CameraInfo, self.rig.topics.camera_topic(name, "depth_info"),
                                     lambda msg, name=name: self._on_info((name, msg)), SENSOR_QOS)
        self.create_timer(self._params["diagnostics_period"], self._publish_diagnostics)
        self.get_logger().info(f"fusing {', '.join(self.rig.camera_names)} within {self.rig.fusion.slop * 1e3:.1f} ms "
                               f"into '{self.rig.base_frame}'")

    def configure(self, rig, params: dict) -> None:
        self.rig, self._params = rig, params
        self._slop_ns = int(rig.fusion.slop * 1e9)
        self._timeout_ns = int(rig.fusion.camera_timeout * 1e9)
        for name in rig.camera_names:
            size = int(params["queue_size"])
            old = list(self._buffers.get(name, ()))
            for frame in old[:-size]:
                self._pixels.pop(id(frame), None)
            self._buffers[name] = deque(old[-size:], maxlen=size)

    @guarded
    def _on_info(self, item) -> None:
        name, msg = item
        try:
            self._intrinsics[name] = Intrinsics.from_camera_info(msg)
        except ValueError as error:
            raise ValueError(f"camera_info of {name}: {error}") from error

    @guarded
    def _on_cloud(self, item) -> None:
        name, msg = item
        xyz, rgb, pixel, organised_width = camera_cloud_from_msg(msg, self.rig.cameras[name].frame_id)
        stamp = stamp_to_ns(msg.header.stamp)
        if stamp < self._newest.get(name, stamp) - self._timeout_ns:
            # Time went back (a bag played again, `ros2 bag play --loop`): what is buffered belongs to another
            # run of the clock, so pairing starts afresh.
            back_s = (self._newest[name] - stamp) * 1e-9
            self.get_logger().warning(f"camera '{name}' stamps jumped back by {back_s:.3f} s: pairing starts afresh")
            self._newest, self._first_stamp, self._silent = {}, None, set()
            for buffer in self._buffers.values():
                buffer.clear()
            self._pixels.clear()
        buffer = self._buffers[name]
        if len(buffer) == buffer.maxlen:  # the oldest goes first
            self._pixels.pop(id(buffer.popleft()), None)
            self.counts["dropped"] += 1
        frame = CameraFrame(camera=name, stamp_ns=stamp, points=xyz, rgb=rgb, organised_width=organised_width)
        buffer.append(frame)
        if pixel is not None:
            self._pixels[id(frame)] = pixel
        self._newest[name] = max(stamp, self._newest.get(name, stamp))
        self._first_stamp = stamp if self._first_stamp is None else self._first_stamp
        self._update_silence()
        self._release()

    def _update_silence(self) -> None:
        newest = max(self._newest.values())
        silent = {name for name in self.rig.camera_names
                  if newest - self._newest.get(name, self._first_stamp) > self._timeout_ns}
        for name in sorted(silent - self._silent):
            heard = sorted(set(self.rig.camera_names) - silent)
            self.get_logger().warning(f"camera '{name}' silent for more than {self.rig.fusion.camera_timeout} s: "
                                      f"publishing {', '.join(heard)} alone")
        for name in sorted(self._silent - silent):
            self.get_logger().info(f"camera '{name}' is back: pairing again")
        changed = silent != self._silent
        self._silent = silent
        if changed:
            self._publish_diagnostics()

    def _release(self) -> None:
        """Take, in stamp order, every buffered pair that is complete or can no longer be completed; publish
        the newest of them (an older one is superseded: the stages keep only the newest anyway, and fusing it
        would only make the node fall behind)."""
        streams = {name: list(buffer) for name, buffer in self._buffers.items()}
        ready: list[tuple[FramePair, bool, dict]] = []
        for pair in pair_frames(streams, self._slop_ns):
            missing = [name for name in self.rig.camera_names if name not in pair.frames]
            # A missing camera that is alive and has not yet sent anything later than this pair may still do so.
            if any(name not in self._silent and self._newest.get(name, -1) < pair.stamp_ns + self._slop_ns
                   for name in missing):
                break
            pixels = self._take(pair)
            if missing and not self._params["publish_unpaired"] and not set(missing) <= self._silent:
                self.counts["unpaired"] += 1  # its partner was lost on the way: half a robot is worse than none
            else:
                ready.append((pair, bool(missing), pixels))
        self.counts["superseded"] += max(len(ready) - 1, 0)
        if ready:
            self._publish(*ready[-1])

    def _take(self, pair: FramePair) -> dict[str, np.ndarray | None]:
        """Remove the pair's frames from the buffers (by identity: frames hold arrays, == is no use); their
        pixels by camera."""
        for name, frame in pair.frames.items():
            buffer = self._buffers[name]
            kept = [f for f in buffer if f is not frame]
            buffer.clear()
            buffer.extend(kept)
        return {name: self._pixels.pop(id(frame), None) for name, frame in pair.frames.items()}

    def _publish(self, pair: FramePair, alone: bool, pixels: dict[str, np.ndarray | None]) -> None:
        # with camera_info known, the core gives the fused cloud its pixel footprint (0 until then)
        frames = {name: camera_frame(name, f.stamp_ns, f.points, f.rgb, pixels[name], f.organised_width,
                                     self._intrinsics.get(name))
                  for name, f in pair.frames.items()}
        cloud = fuse(FramePair(pair.stamp_ns, frames), self.rig)
        self._publisher.publish(stage_cloud_to_msg(cloud, self.rig.base_frame))
        self.counts["alone" if alone else "pairs"] += 1

    def _publish_diagnostics(self) -> None:
        if self._silent:
            heard = [n for n in self.rig.camera_names if n not in self._silent]
            level = DiagnosticStatus.WARN if heard else DiagnosticStatus.ERROR
            message = (f"missing camera(s): {', '.join(sorted(self._silent))}; publishing "
                       f"{', '.join(heard) or 'nothing'} alone")
        elif not self._newest:
            level, message = DiagnosticStatus.WARN, "no camera has sent a cloud yet"
        else:
            level, message = DiagnosticStatus.OK, f"pairing {', '.join(self.rig.camera_names)}"
        newest = max(self._newest.values(), default=0)
        values = {"missing": ",".join(sorted(self._silent)), **self.counts}
        values.update({f"{name}.lag_s": f"{(newest - self._newest[name]) * 1e-9:.3f}" if name in self._newest
                       else "never" for name in self.rig.camera_names})
        self._diagnostics.publish(diagnostics(DIAGNOSTIC_NAME, "ntcr_recon/fusion_node", level, message, values,
                                              self.get_clock().now().nanoseconds))


def main(args: list[str] | None = None) -> int:
    return run_node(FusionNode, args)


if __name__ == "__main__":
    sys.exit(main())
