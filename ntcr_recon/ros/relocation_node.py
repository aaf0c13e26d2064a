"""relocation_node: `<ns>/filtered/points` -> the reconstructed robot (the core's reference-guided relocation).

Publishes (reliable, depth 1; all in the base frame, stamped with the input cloud's stamp):
  `<ns>/relocated/points`   PointCloud2: the accepted points moved onto the reference surface, with the
                            surface's outward normals, parts and tube coordinates for the mesh stage
  `<ns>/centerline`         nav_msgs/Path, base to tip; each pose's x axis points to the notch side, z along
                            the tangent (the robot kinematics' convention)
  `<ns>/tip`                geometry_msgs/PoseStamped, same axes
  `<ns>/notches`            std_msgs/Float64MultiArray, rows [index, center_s_m, width_m, bend_rad] (layout in
                            ntcr_recon.ros.result_messages; readable without this package)
  `<ns>/notches/markers`    visualization_msgs/MarkerArray for RViz (a disc per notch, its width in mm)
  `/diagnostics`            diagnostic_msgs/DiagnosticArray, per frame: its status as the level (ok OK, warn
                            WARN, error ERROR; a cloud without a result ERROR), the frame's stamp and warning
                            codes in the message, and as key-values `status`, `stamp_ns`, `codes`,
                            `uncertainty_mm.<centerline|tip|notch_width>`, `warning.<CODE>` (severity: sentence)
                            and the rest of the self-check (core.quality.checks); codes: core.quality.findings.
                            With `calibration.refine`, each refinement's status too (ros.calibration_refiner)
Serves `~/write_calibration` (std_srvs/Trigger): with `calibration.refine`, the rig file (`rig_file`) written with
the second camera's refined pose to `refined_rig_file`.
The relocation is the offline command's own (core.reconstruction.relocate.Relocator, without the Reconstructor's
frame loop around it: fusion's region of interest is camera_node's crop window here). It warm-starts from the
previous frame's centreline, as the offline command does over a bag. The
tip is placed with each camera's edge band (`<ns>/<cam>/edge_band`, from camera_node, which sees the depth
images), as the offline command places it; until a camera's band arrives (or with a source that publishes none)
by the erosion of the silhouettes, which `tip_refinement` on /diagnostics names. The axis is placed across each
camera's view by the tube's limbs in its colour window (`<ns>/<cam>/color/image_rect_raw` with
`.../color/camera_info`, from camera_node; the one of the frame the cloud was fused from, its stamp within
fusion.slop), as the offline command places it with the frame pair's images. A cloud whose windows have not come
waits for them (WINDOW_WAIT_S at most, or until the next cloud); without one, the view is placed by depth alone
(a log line, and `centerline_limbs` on /diagnostics, say which).
A cloud the core cannot reconstruct (too few points, no tube along the base axis) is logged and skipped; a cloud
of more than `max_points` points is dropped before it is read. The centreline goes out serialized from arrays
(ros/cdr.py): a Path of PoseStamped objects built one by one cost more than the relocation itself.
"""

from __future__ import annotations

import functools
import sys
import time
from pathlib import Path as PathLib

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Float64, Float64MultiArray, Header
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from ntcr_recon.core.cloud.pairing import InForce, stamp_jump
from ntcr_recon.core.reconstruction.relocate import ReconstructionError, Relocator
from ntcr_recon.io.bag import image_to_array
from ntcr_recon.io.pointcloud import stamp_to_ns
from ntcr_recon.ros.cdr import header_stamp_ns
from ntcr_recon.ros.messages import (
    decode,
    decode_cloud,
    intrinsics_from_camera_info,
    relocation_cloud_msg,
    stage_cloud_from_msg,
)
from ntcr_recon.ros.node_stats import NodeStats
from ntcr_recon.ros.node_support import (
    LATCHED_QOS,
    STAGE_QOS,
    WINDOW_QOS,
    ParameterError,
    RigNode,
    describe,
    guarded,
    max_points_parameter,
    run_node,
)
from ntcr_recon.ros.result_messages import (
    NotchMarkers,
    centerline_path_bytes,
    frame_rotations,
    notches_array,
    pose_stamped,
)
from ntcr_recon.ros.topics import edge_band_topic, stage_topic

# How long a cloud waits for its instant's colour windows (s): a window comes before its cloud (camera_node
# publishes it first, and the cloud passes fusion and filter) unless the machine is busy or the graph starting.
WINDOW_WAIT_S = 0.25
# How often a running calibration refinement is checked for its result (s).
REFINE_POLL_S = 1.0

PARAMETERS = {
    "output_dir": ("", describe("when set, the newest relocated cloud is also written to <output_dir>/relocated.ply")),
    "warm_start": (True, describe("start each frame's centreline iteration from the previous frame's (as the "
                                  "offline command does); false: every frame from the base, independently")),
    "max_points": max_points_parameter(),
    "rig_file": ("", describe("the rig file this graph was started with (the launch files and `ntcr-recon run` set "
                              "it): with calibration.refine, ~/write_calibration writes it with the refined pose")),
    "refined_rig_file": ("", describe("where ~/write_calibration writes ('' = <rig_file>.refined.yaml beside it)")),
}


class RelocationNode(RigNode):
    def __init__(self, node_name: str = "relocation_node") -> None:
        self._edge_bands: dict[str, float] = {}  # rad per camera, as received (configure hands them on)
        super().__init__(node_name, PARAMETERS)
        self.stats = NodeStats(self, "ntcr_recon: relocation")
        topic = self.rig.topics
        self._cloud = self.create_publisher(PointCloud2, stage_topic(topic, "relocated/points"), STAGE_QOS)
        self._path = self.create_publisher(Path, stage_topic(topic, "centerline"), STAGE_QOS)
        self._tip = self.create_publisher(PoseStamped, stage_topic(topic, "tip"), STAGE_QOS)
        self._notches = self.create_publisher(Float64MultiArray, stage_topic(topic, "notches"), STAGE_QOS)
        self._markers = self.create_publisher(MarkerArray, stage_topic(topic, "notches/markers"), STAGE_QOS)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # each camera's colour window and its intrinsics (camera_node), kept undecoded until a cloud of their stamp
        # comes; subscribed before the cloud, so that the executor takes an image ready with it first
        self._color: dict[str, InForce] = {camera: InForce() for camera in self.rig.camera_names}
        self._color_info: dict[str, InForce] = {camera: InForce() for camera in self.rig.camera_names}
        self._windows = {camera: self.create_subscription(Image, topic.camera_topic(camera, "color"),
                                                          functools.partial(self._on_color, camera), WINDOW_QOS,
                                                          raw=True)
                         for camera in (self.rig.camera_names if self.rig.relocation.limbs else ())}
        for camera in self._windows:
            self.create_subscription(CameraInfo, topic.camera_topic(camera, "color_info"),
                                     functools.partial(self._on_color_info, camera), WINDOW_QOS)
        # a cloud whose instant's windows have not come yet waits for them, WINDOW_WAIT_S at most (steady time: a
        # replay's /clock may stand still)
        self._held: tuple | None = None
        self._hold_timer = self.create_timer(WINDOW_WAIT_S, self._on_hold_expired,
                                             clock=Clock(clock_type=ClockType.STEADY_TIME), autostart=False)
        # depth 1, unlike the other stages' inputs (STAGE_INPUT_QOS): the slowest stage, it would take the older of two
        # frames whenever it falls behind (camera-to-tip p50 94 ms against 51 at depth 1, bench_graph on this
        # machine); a giant cloud the next frame pushes out before its last fragment came never reaches it
        self.create_subscription(PointCloud2, stage_topic(topic, "filtered/points"), self._on_cloud, STAGE_QOS,
                                 raw=True)
        self._last_stamp_ns: int | None = None  # the previous cloud's, to start afresh after a jump of the stamps
        for camera in self.rig.camera_names:
            self.create_subscription(Float64, edge_band_topic(topic, camera),
                                     functools.partial(self._on_edge_band, camera), LATCHED_QOS)
        # calibration.refine: the refined pose written on request, its status polled from the worker
        self.create_service(Trigger, "~/write_calibration", self._on_write_calibration)
        self.create_timer(REFINE_POLL_S, self._poll_refinement)
        self.get_logger().info("relocating filtered clouds onto the reference robot")

    def configure(self, rig, params: dict) -> None:
        if params["output_dir"] and not PathLib(params["output_dir"]).expanduser().is_dir():
            raise ParameterError(f"parameter 'output_dir': {params['output_dir']!r} is not an existing folder")
        self.rig, self._relocator, self._params = rig, Relocator(rig), params
        if getattr(self, "_refiner", None) is not None:
            self._refiner.close()
        self._refiner = None
        if rig.calibration.refine:  # imported only then: the fit's modules (scipy.optimize) cost the start 0.15 s
            from ntcr_recon.ros.calibration_refiner import OnlineRefiner

            self._refiner = OnlineRefiner(rig, self.get_logger(), self.get_name())
        for camera, band in self._edge_bands.items():  # received before a change of parameters
            if camera in rig.camera_names:
                self._relocator.note_edge_band(camera, band)
        self._notch_markers = NotchMarkers(rig.robot.outer_radius)

    @guarded
    def _on_edge_band(self, camera: str, msg: Float64) -> None:
        self._relocator.note_edge_band(camera, msg.data)
        self._edge_bands[camera] = msg.data
        self.get_logger().info(f"edge band of '{camera}' received: {msg.data * 1e3:.2f} mrad")

    @guarded
    def _on_color(self, camera: str, raw: bytes) -> None:
        self._color[camera].add(header_stamp_ns(raw), raw)
        self._release_when_complete()

    @guarded
    def _on_color_info(self, camera: str, msg: CameraInfo) -> None:
        self._color_info[camera].add(stamp_to_ns(msg.header.stamp), intrinsics_from_camera_info(msg))
        self._release_when_complete()

    def _window_of(self, camera: str, stamp_ns: int):
        """(the colour image's raw bytes, its intrinsics) of a camera at a cloud's stamp (within fusion.slop), or
        None when either has not come."""
        image = self._color[camera].nearest(stamp_ns, int(self.rig.fusion.slop * 1e9))
        info = None if image is None else self._color_info[camera].at(image[0])
        return None if info is None or info[0] != image[0] else (image[1], info[1])

    def _publishes_windows(self, camera: str, stamp_ns: int) -> bool:
        """Whether the camera's camera_node publishes colour windows: its publisher is matched, or a window of it
        came within fusion.camera_timeout of the stamp (a busy machine's discovery can report a running publisher
        unmatched for a while: a frame then placed by depth alone, unsaid)."""
        if camera not in self._windows:
            return False
        recent = self._color[camera].nearest(stamp_ns, int(self.rig.fusion.camera_timeout * 1e9)) is not None
        return recent or self._windows[camera].get_publisher_count() > 0

    def _awaited(self, cloud) -> list[str]:
        """The cameras with points in the cloud whose window of its instant has not come while their camera_node
        publishes windows: the cloud waits for those."""
        return [camera for camera in cloud.cameras_in(self.rig.camera_names)
                if self._publishes_windows(camera, cloud.stamp_ns) and self._window_of(camera, cloud.stamp_ns) is None]

    def _release_when_complete(self) -> None:
        if self._held is not None and not self._awaited(self._held[1]):
            self._release()

    @guarded
    def _on_hold_expired(self) -> None:
        if self._held is not None:
            self._release()

    def _release(self) -> None:
        held, self._held = self._held, None
        self._hold_timer.cancel()
        self._relocate(*held)

    def _note_views(self, cloud) -> None:
        """Each camera's colour window of the frame the cloud was fused from (its stamp within the pairing's slop),
        as the offline command notes the frame pair's windows before relocating it: none for a camera without a
        point in the cloud (fusion published the other alone) or without an image of its instant."""
        self._relocator.views.clear()  # one of another instant shows the robot elsewhere
        missing = []
        for camera in cloud.cameras_in(self.rig.camera_names):
            window = self._window_of(camera, cloud.stamp_ns)
            if window is None:
                missing.append(camera)
                continue
            try:
                color = image_to_array(decode(window[0], Image, f"colour image of '{camera}'"))
                self._relocator.note_view(camera, color, window[1])
            except ValueError as error:  # one bad image: the axis is placed by depth alone in that view
                self.get_logger().warning(f"colour image of '{camera}' not used: {error}", throttle_duration_sec=5.0)
        if missing:
            message = (f"no colour window of {', '.join(missing)} came with the cloud of {cloud.stamp_ns} ns: the "
                       "axis is placed by depth alone in that view")
            # a window late from a camera_node that publishes them is said for each frame (rare, and the frame
            # named); a camera publishing none would say it every frame: once per 5 s
            if any(self._publishes_windows(camera, cloud.stamp_ns) for camera in missing):
                self.get_logger().warning(message)
            else:
                self.get_logger().warning(message, throttle_duration_sec=5.0)

    @guarded
    def _on_cloud(self, raw: bytes) -> None:
        self.stats.received()
        started = time.perf_counter()
        msg = decode_cloud(raw, self._params["max_points"])  # refused when oversized before decoding
        cloud = stage_cloud_from_msg(msg, self.rig.base_frame, self.rig)
        if self._held is not None:  # a newer cloud came: the held one goes on with the windows it has
            self._release()
        if self._awaited(cloud):
            self._held = (msg, cloud, started)
            self._hold_timer.reset()
            return
        self._relocate(msg, cloud, started)

    def _relocate(self, msg: PointCloud2, cloud, started: float) -> None:
        if self._windows:
            self._note_views(cloud)
        try:
            relocation = self._relocator.relocate(cloud, warm_start=self._warm_start(cloud.stamp_ns))
        except ReconstructionError as error:
            self._diagnostics.publish(DiagnosticArray(header=msg.header, status=[quality_status(
                self.get_name(), msg.header.stamp, None, error=str(error))]))
            raise ValueError(f"cannot reconstruct the cloud of {len(cloud)} points: {error}") from error
        frame, stamp = self.rig.base_frame, cloud.stamp_ns
        centerline = relocation.centerline
        # The tip first: it is what a controller waits for; the cloud then its centreline (mesh_node pairs them).
        end = frame_rotations(centerline.normals[-1:], centerline.binormals[-1:], centerline.tangents[-1:])[0]
        self._tip.publish(pose_stamped(relocation.tip, end, frame, stamp))
        self.stats.published(stamp, started)
        self._cloud.publish(relocation_cloud_msg(relocation, frame))
        self._path.publish(centerline_path_bytes(centerline, frame, stamp))
        notches = [{"index": n.index, "center_s": n.center_s, "width": n.width, "bend": n.bend}
                   for n in relocation.notches]
        self._notches.publish(notches_array(notches))
        centres = np.array([n.center_s for n in relocation.notches], dtype=float)
        position, tangent, normal, binormal = centerline.frames_at(centres)
        self._markers.publish(self._notch_markers.array(notches, position, frame_rotations(normal, binormal, tangent),
                                                        frame, stamp))
        self._publish_quality(relocation, msg.header)
        if self._refiner is not None:
            self._refiner.offer(cloud, self._relocator.views)
        if self._params["output_dir"]:
            self._write(PathLib(self._params["output_dir"]).expanduser() / "relocated.ply", relocation)

    @guarded
    def _poll_refinement(self) -> None:
        status = None if self._refiner is None else self._refiner.poll()
        if status is not None:
            self._diagnostics.publish(DiagnosticArray(header=Header(stamp=self.get_clock().now().to_msg()),
                                                      status=[status]))

    def _on_write_calibration(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """~/write_calibration: the rig file with the refined pose written (OnlineRefiner.write); a failure is the
        response's message, never the node's end."""
        try:
            if self._refiner is None:
                response.success, response.message = False, "calibration.refine is off in the rig configuration"
            else:
                response.success, response.message = self._refiner.write(self._params["rig_file"],
                                                                          self._params["refined_rig_file"])
        except Exception as error:  # a bug must not take the graph down
            response.success, response.message = False, f"unexpected {type(error).__name__}: {error}"
        if response.success:
            self.get_logger().info(f"write_calibration: {response.message}")
        else:
            self.get_logger().warning(f"write_calibration: {response.message}")
        return response

    def destroy_node(self) -> None:
        if self._refiner is not None:
            self._refiner.close()
        super().destroy_node()

    def _warm_start(self, stamp_ns: int) -> bool:
        """Whether this frame starts from the previous frame's centreline: not after a jump of the stamps either way
        (a replay looping back, a camera reset, one stray cloud from the future), longer than fusion.camera_timeout,
        which would start it from a robot of another time; a line says so."""
        last, self._last_stamp_ns = self._last_stamp_ns, stamp_ns
        if not self._params["warm_start"]:
            return False
        if (jump := stamp_jump(last, stamp_ns, self.rig.fusion.camera_timeout)) is not None:
            self.get_logger().info(f"stamps jumped {'back' if jump < 0 else 'ahead'} by {abs(jump):.3f} s: this "
                                   "frame's centreline starts afresh, not from the previous frame's")
            return False
        return True

    def _publish_quality(self, relocation, header) -> None:
        """The frame's status and self-check on /diagnostics (quality_status)."""
        self._diagnostics.publish(DiagnosticArray(header=header, status=[quality_status(self.get_name(), header.stamp,
                                                                                        relocation)]))

    def _write(self, path: PathLib, relocation) -> None:
        from ntcr_recon.io.files import write_cloud_ply

        try:
            write_cloud_ply(path, relocation.relocated.xyz, relocation.relocated.rgb, relocation.normals)
        except (OSError, ValueError) as error:
            self.get_logger().error(f"could not write the relocated cloud to {path}: {error}")


LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN, "error": DiagnosticStatus.ERROR}


def quality_status(node_name: str, stamp, relocation, error: str | None = None) -> DiagnosticStatus:
    """A frame's result as a control node reads it without parsing text: the level is its status (a frame without a
    result, `error` naming why, is ERROR), the message its stamp and codes, the figures key-values."""
    stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
    when = f"frame {stamp.sec}.{stamp.nanosec:09d}"
    status = DiagnosticStatus(name=f"{node_name}: reconstruction quality", hardware_id="ntcr")
    if relocation is None:
        status.level, status.message = DiagnosticStatus.ERROR, f"error at {when}: no result ({error})"
        status.values = [KeyValue(key="status", value="error"), KeyValue(key="stamp_ns", value=str(stamp_ns))]
        return status
    codes = ",".join(dict.fromkeys(f.code for f in relocation.warnings))
    status.level = LEVELS[relocation.status]
    status.message = f"{relocation.status} at {when}" + (f": {codes}" if codes else "")
    uncertainty = relocation.quality.get("uncertainty_mm", {})
    values = {"status": relocation.status, "stamp_ns": stamp_ns, "codes": codes,
              **{f"uncertainty_mm.{name}": "" if value is None else f"{value:.4f}"
                 for name, value in uncertainty.items()},
              **{f"warning.{f.code}": f"{f.severity}: {f.message}" for f in relocation.warnings},
              **{key: value for key, value in relocation.quality.items() if key != "uncertainty_mm"}}
    status.values = [KeyValue(key=str(key), value=str(value)) for key, value in values.items()]
    return status


def main(args: list[str] | None = None) -> int:
    return run_node(RelocationNode, args)


if __name__ == "__main__":
    sys.exit(main())
