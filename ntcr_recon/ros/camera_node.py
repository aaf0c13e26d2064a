"""camera_node: one camera's frames -> `<ns>/<cam>/depth/color/points` (+ `<ns>/<cam>/depth/camera_info`), and its
colour image's window about the robot's pixels -> `<ns>/<cam>/color/image_rect_raw` (rgb8, + the window's
intrinsics on `<ns>/<cam>/color/camera_info`: core.relocation.limbs.CameraView.around, what relocation_node places
the axis across the view with).

One instance per camera (parameter `camera`, a name of the rig's camera_names). The source is a parameter:
  bag       a rosbag2 bag (`bag_path`): the camera's depth (16UC1 in the configured depth_unit, or 32FC1 metres),
            camera_info and colour, or, in a bag of recorded clouds only, its `.../depth/color/points` as recorded;
            at `rate` times the recorded rate (0: as fast as it can), looping with `loop`, publishing /clock from
            the frames' stamps with `publish_clock` (so `use_sim_time` nodes follow the bag);
  realsense a live D405 (pyrealsense2), picked by the configuration's serial_number, at its width/height/fps,
            depth unit kept at the configured value (0.1 mm on a D405);
  file      a librealsense recording (`file_path`) played back through pyrealsense2.
Every depth frame goes through the core's camera cloud (`core.cloud.fusion.depth_points`, the offline pipeline's
own): with `crop_to_robot` only the image window that can see the robot's crop box is deprojected, and only
the points inside the box are published (what fusion keeps anyway; a fifth of the bytes on the wire). The
cloud holds the valid points with their pixel (fields pixel_u, pixel_v: the later stages find neighbours in
the image by it), in the camera's optical frame (the configuration's frame_id), with the frame's own stamp.
The first frame's depth step is measured (`depth_step_mm` on /diagnostics): depth too coarse for the tube (a
realsense-ros recording's 1 mm unit) is a WARN there and a log line, the warning the offline command gives.
So is the band its stereo matcher spoils at depth edges (`core.reconstruction.edge_bands.EdgeBands`, the offline
pipeline's measure, rad: on the first frames until one shows a far background, at most EDGE_BAND_ATTEMPTS):
published once on `<ns>/<cam>/edge_band`
(std_msgs/Float64, transient local) for relocation_node, which places the tip with it as the offline command
does with the depth images (`edge_band_mrad` on /diagnostics).

A live camera that is not connected at start-up is waited for (`wait_for_device`, default true): a log line
every few seconds and /diagnostics ERROR naming what is missing until it appears, as the source already
reconnects after a drop; with `wait_for_device:=false` the node refuses to start instead. A frame whose
intrinsics cannot be a camera's (non-finite or non-positive focal length, non-finite centre) is dropped with a
message naming the value, and the node goes on; a producer thread that dies of anything else (or a live source
that stops for good) ends the process with exit code 1, so that `ntcr-recon run` or launch respawns it. Rates,
drops and timing: ros/node_stats.py.
"""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Float64

from ntcr_recon.core.base import compiled
from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.core.cloud.fusion import CameraFrame, deprojected, depth_points
from ntcr_recon.core.quality.measures import depth_quantisation_warning, depth_step
from ntcr_recon.core.reconstruction.edge_bands import EdgeBands
from ntcr_recon.core.relocation.limbs import CameraView
from ntcr_recon.core.relocation.tip import EDGE_BAND_ATTEMPTS
from ntcr_recon.io.camera_sources import BagSource, Pacer, SourceError, SourceFrame
from ntcr_recon.ros.graph import START_DELAY_S
from ntcr_recon.ros.messages import RCLPY, camera_cloud_to_msg, checked_intrinsics, header, stamp_msg
from ntcr_recon.ros.node_stats import NodeStats
from ntcr_recon.ros.node_support import (
    CAMERA_QOS,
    LATCHED_QOS,
    WINDOW_QOS,
    ParameterError,
    RigNode,
    describe,
    run_node,
)
from ntcr_recon.ros.topics import edge_band_topic

SOURCES = ("bag", "realsense", "file")

PARAMETERS = {
    "camera": ("cam_a", describe("name of this camera in the rig's camera_names", read_only=True)),
    "source": ("bag", describe(f"where frames come from: {' | '.join(SOURCES)}", read_only=True)),
    "bag_path": ("", describe("rosbag2 directory replayed by the 'bag' source", read_only=True)),
    "file_path": ("", describe("librealsense recording (.bag / .db3) played by the 'file' source", read_only=True)),
    "rate": (1.0, describe("replay speed relative to the recorded rate; 0 = as fast as possible", minimum=0.0,
                           maximum=100.0)),
    "loop": (False, describe("replay the bag / file again and again (stamps keep increasing)", read_only=True)),
    "publish_clock": (False, describe("publish /clock from the frames' stamps (bag / file; one node per graph)",
                                      read_only=True)),
    "start_time": (0.0, describe("bag / file: wall-clock time (s since the epoch) at which the first frame is due; "
                                  "camera nodes given the same value replay in step (0: when ready)", minimum=0.0,
                                  read_only=True)),
    "wait_for_subscriber": (True, describe("bag / file: start replaying once the cloud topic has a subscriber (with "
                                           "relocation.limbs: and the colour window one, or 3 s on), so a "
                                           "graph started together loses no frame", read_only=True)),
    "crop_to_robot": (True, describe("deproject only the pixels that can see the robot's crop box, and publish only "
                                     "the points inside it")),
    "spatial_filter": (False, describe("realsense: librealsense spatial edge-preserving filter", read_only=True)),
    "temporal_filter": (False, describe("realsense: librealsense temporal filter", read_only=True)),
    "hole_filling": (False, describe("realsense: librealsense hole-filling filter", read_only=True)),
    "reconnect_period": (1.0, describe("realsense: seconds between attempts to (re)open the device",
                                       minimum=0.1, maximum=60.0, read_only=True)),
    "wait_for_device": (True, describe("realsense: a camera not connected at start is waited for (log line and "
                                       "diagnostics ERROR every few seconds); false: refuse to start",
                                       read_only=True)),
}
WAITING_LOG_PERIOD_S = 5.0
# How long a replay waits, once its cloud has a subscriber, for one on its colour window (a graph's nodes discover
# each other within a second or two; a camera_node alone has none, and starts after this).
COLOR_SUBSCRIBER_GRACE_S = 3.0


def camera_info_msg(frame: SourceFrame, frame_id: str) -> CameraInfo:
    """The frame's recorded camera_info re-stamped, or one built from its intrinsics (no distortion)."""
    recorded = frame.camera_info
    if recorded is None:
        return intrinsics_info_msg(frame.intrinsics, frame_id, frame.stamp_ns)
    info = CameraInfo(header=header(frame_id, frame.stamp_ns))
    info.height, info.width = int(recorded.height), int(recorded.width)
    info.distortion_model = str(recorded.distortion_model)
    info.d = [float(v) for v in recorded.d]
    info.k, info.r, info.p = (np.asarray(getattr(recorded, name), dtype=float) for name in "krp")
    return info


def intrinsics_info_msg(intrinsics: Intrinsics, frame_id: str, stamp_ns: int) -> CameraInfo:
    """A camera_info of pinhole intrinsics (rectified: no distortion)."""
    info = CameraInfo(header=header(frame_id, stamp_ns))
    info.height, info.width, info.distortion_model = intrinsics.height, intrinsics.width, "plumb_bob"
    info.d = [0.0] * 5
    info.k = np.array([intrinsics.fx, 0, intrinsics.cx, 0, intrinsics.fy, intrinsics.cy, 0, 0, 1], dtype=float)
    info.r = np.eye(3).reshape(-1)
    info.p = np.array([intrinsics.fx, 0, intrinsics.cx, 0, 0, intrinsics.fy, intrinsics.cy, 0, 0, 0, 1, 0], float)
    return info


def color_image_msg(color: np.ndarray, frame_id: str, stamp_ns: int) -> Image:
    """An (H, W, 3) uint8 RGB image as an rgb8 Image."""
    color = np.ascontiguousarray(color, dtype=np.uint8)
    height, width = color.shape[:2]
    return Image(header=header(frame_id, stamp_ns), height=height, width=width, encoding="rgb8", is_bigendian=0,
                 step=3 * width, data=color.tobytes())


def recorded_cloud_msg(recorded, stamp_ns: int) -> PointCloud2:
    """A recorded (rosbags) PointCloud2 as an rclpy message, bytes untouched, stamp possibly shifted by a loop."""
    msg = PointCloud2(header=header(str(recorded.header.frame_id), stamp_ns), height=int(recorded.height),
                      width=int(recorded.width), is_bigendian=bool(recorded.is_bigendian),
                      point_step=int(recorded.point_step), row_step=int(recorded.row_step),
                      is_dense=bool(recorded.is_dense))
    msg.fields = [RCLPY.point_field(name=str(f.name), offset=int(f.offset), datatype=int(f.datatype),
                                    count=int(f.count)) for f in recorded.fields]
    msg.data = np.asarray(recorded.data, dtype=np.uint8).tobytes()
    return msg


class CameraNode(RigNode):
    def __init__(self, node_name: str = "camera_node") -> None:
        self._source = None
        self._waiting_for: str | None = None  # why the live source could not be opened yet
        super().__init__(node_name, PARAMETERS)
        self.stats = NodeStats(self, f"ntcr_recon: camera {self.camera}", status=self._status)
        points_topic = self.rig.topics.camera_topic(self.camera, "points")
        self._cloud_publisher = self.create_publisher(PointCloud2, points_topic, CAMERA_QOS)
        self._info_publisher = self.create_publisher(
            CameraInfo, self.rig.topics.camera_topic(self.camera, "depth_info"), CAMERA_QOS)
        # the colour window about the robot's pixels, with its intrinsics: relocation_node places the axis across
        # this camera's view by the tube's limbs there (core.relocation.limbs)
        self._color_publisher = self.create_publisher(Image, self.rig.topics.camera_topic(self.camera, "color"),
                                                      WINDOW_QOS)
        self._color_info_publisher = self.create_publisher(
            CameraInfo, self.rig.topics.camera_topic(self.camera, "color_info"), WINDOW_QOS)
        self._clock_publisher = self.create_publisher(Clock, "/clock", 10) if self._params["publish_clock"] else None
        self._edge_band_publisher = self.create_publisher(Float64, edge_band_topic(self.rig.topics, self.camera),
                                                          LATCHED_QOS)
        self._stop = threading.Event()
        self.failure: str | None = None  # set when the producer thread died: run_nodes then exits non-zero
        self.frames_published = self.frames_skipped = 0
        self._thread = threading.Thread(target=self._pump, name="camera_source", daemon=True)
        self._thread.start()
        self.get_logger().info(f"camera '{self.camera}' from the {self._params['source']} source -> {points_topic}")

    def configure(self, rig, params: dict) -> None:
        if params["camera"] not in rig.camera_names:
            raise ParameterError(f"parameter 'camera' is '{params['camera']}', which is not one of the rig's "
                                 f"camera_names {list(rig.camera_names)}")
        if params["source"] not in SOURCES:
            raise ParameterError(f"parameter 'source' must be one of {SOURCES}, got '{params['source']}'")
        if self._source is None and self._waiting_for is None:  # opened once; its parameters are read-only
            try:
                self._source = self._open_source(rig, params)
            except ParameterError as error:
                if not (params["source"] == "realsense" and params["wait_for_device"]):
                    raise
                self._waiting_for = str(error)  # the producer thread keeps trying
        self.rig, self.camera, self._params = rig, params["camera"], params
        self._windows: dict[Intrinsics, object] = {}
        # the depth quantisation the frames show, measured on the first one (the self-check the offline
        # command makes; in the graph no other node sees depth images)
        self._depth_step: float | None = None
        self._depth_warning: str | None = None
        self._edge_bands = EdgeBands()  # this camera's, published once measured

    def _open_source(self, rig, params: dict):
        try:
            if params["source"] == "bag":
                if not params["bag_path"]:
                    raise ParameterError("parameter 'bag_path' must name a rosbag2 directory for the 'bag' source")
                return BagSource(params["bag_path"], params["camera"], rig.topics, loop=params["loop"])
            from ntcr_recon.io.realsense import RealSenseSource, RecordingSource

            filters = {"spatial": params["spatial_filter"], "temporal": params["temporal_filter"],
                       "hole_filling": params["hole_filling"]}
            if params["source"] == "file":
                if not params["file_path"]:
                    raise ParameterError("parameter 'file_path' must name a recording for the 'file' source")
                # Paced here by the frames' stamps (rate), like a bag: the recording is read as fast as asked.
                return RecordingSource(params["file_path"], loop=params["loop"], real_time=False,
                                       log=self.get_logger(), **filters)
            return RealSenseSource(rig.cameras[params["camera"]], reconnect_period=params["reconnect_period"],
                                   log=self.get_logger(), **filters)
        except SourceError as error:
            raise ParameterError(f"source '{params['source']}': {error}") from error

    # ---- the producer thread -------------------------------------------------------------------------------
    def _due(self, stamp_ns: int) -> float | None:
        """Wall-clock time (s) at which the frame of `stamp_ns` is due at `rate` (io.camera_sources.Pacer: afresh
        after a jump of the stamps, said in a line); None when not paced."""
        rate = self._params["rate"]
        if rate <= 0 or self._params["source"] == "realsense":
            return None
        if self._pacer is None:  # the first frame is due at start_time (even if that has passed: then this node
            # skips frames to catch up, in step with the others) or now
            self._pacer = Pacer(rate, self._start_time(), self.rig.fusion.camera_timeout)
        self._pacer.rate = rate  # as set now
        due = self._pacer.due(stamp_ns, time.time())
        if self._pacer.jumped is not None:
            jump = self._pacer.jumped
            self.get_logger().info(f"camera '{self.camera}': stamps jumped {'back' if jump < 0 else 'ahead'} by "
                                   f"{abs(jump):.3f} s: the replay's pacing starts afresh")
        return due

    def _start_time(self) -> float:
        """When the first frame is due: `start_time` (one instant for every camera of the graph), or now. When the
        kernels were compiled at this start (a first start after an install, core/base/compiled.py), not before
        START_DELAY_S after they were ready: every camera reads the same instant from the cache, so they stay in
        step, and no frame is skipped as late for the compilation."""
        start = self._params["start_time"]
        if not start:
            return time.time()
        ready = compiled.ready_at()
        return max(start, ready + START_DELAY_S) if ready is not None else start

    def _too_late(self, stamp_ns: int) -> bool:
        """A paced replay more than 1.5 frame periods behind skips the frame, as a live camera drops frames
        rather than falling behind: the cameras stay in step with the clock, and so with each other."""
        due = self._due(stamp_ns)
        period = 1.0 / (self.rig.cameras[self.camera].fps * self._params["rate"]) if due is not None else 0.0
        late = due is not None and time.time() - due > 1.5 * period
        self.frames_skipped += late
        if late:
            self.stats.received()
            self.stats.drops["late"] += 1  # counted, not logged: the source-finished line sums them up
        return late

    def _status(self) -> tuple[bytes | None, str, dict[str, object]]:
        if self._waiting_for is not None:
            return DiagnosticStatus.ERROR, f"waiting for the camera: {self._waiting_for}", {}
        values = {"frames_published": self.frames_published, "frames_skipped": self.frames_skipped}
        if self._depth_step is not None:
            values["depth_step_mm"] = round(self._depth_step * 1e3, 4)
        if (band := self._edge_bands.angles.get(self.camera)) is not None:
            values["edge_band_mrad"] = round(band * 1e3, 4)
        if self._depth_warning is not None:
            return DiagnosticStatus.WARN, self._depth_warning, values
        return None, "", values

    def _note_depth_step(self, depth: np.ndarray, unit: float) -> None:
        self._depth_step = depth_step(depth, unit)
        self._depth_warning = depth_quantisation_warning(self.camera, self._depth_step, self.rig.robot)
        if self._depth_warning is not None:
            self.get_logger().warning(self._depth_warning)

    def _note_edge_band(self, depth: np.ndarray, unit: float, focal: float) -> None:
        """The edge band measured on this frame while not yet known (EdgeBands), published once it is."""
        if not self._edge_bands.wants(self.camera):
            return
        self._edge_bands.note_image(self.camera, depth, unit, focal)
        self._edge_bands.measure(self.camera)
        band = self._edge_bands.angles.get(self.camera)
        if band is not None:
            self._edge_band_publisher.publish(Float64(data=band))
            self.get_logger().info(f"edge band of '{self.camera}': {band * focal:.2f} px")
        elif self._edge_bands.attempts(self.camera) == EDGE_BAND_ATTEMPTS:
            self.get_logger().info(f"no edge band in {EDGE_BAND_ATTEMPTS} frames of '{self.camera}' (no far "
                                   "background): the tip is placed by the silhouettes' erosion")

    def _wait_for_device(self) -> bool:
        """Try to open the live source every reconnect_period until it opens (True) or the node stops."""
        last_log = -float("inf")
        while not self._stop.is_set():
            try:
                self._source = self._open_source(self.rig, self._params)
            except ParameterError as error:
                self._waiting_for = str(error)
                if time.monotonic() - last_log >= WAITING_LOG_PERIOD_S:
                    self.get_logger().error(f"camera '{self.camera}': waiting for the device ({error})")
                    last_log = time.monotonic()
                if self._stop.wait(self._params["reconnect_period"]):
                    return False
                continue
            self._waiting_for = None
            self.get_logger().info(f"camera '{self.camera}': device found, streaming")
            return True
        return False

    def _pump(self) -> None:
        self._pacer = None
        if self._source is None and not self._wait_for_device():
            return
        if self._params["wait_for_subscriber"] and self._params["source"] != "realsense":
            self.get_logger().info(f"waiting for a subscriber on {self._cloud_publisher.topic_name}")
            while self._cloud_publisher.get_subscription_count() == 0:
                if self._stop.wait(0.05):
                    return
            # and, for a while, one on the colour window (relocation_node's, started with the graph): frames replayed
            # before it matched would be placed by depth alone there, and by the limbs in the offline command
            grace = time.monotonic() + (COLOR_SUBSCRIBER_GRACE_S if self.rig.relocation.limbs else 0.0)
            while self._color_publisher.get_subscription_count() == 0 and time.monotonic() < grace:
                if self._stop.wait(0.05):
                    return
        if hasattr(self._source, "skip"):
            self._source.skip = self._too_late
        try:
            for frame in self._source:
                if self._stop.is_set():
                    return
                due = self._due(frame.stamp_ns)
                if due is not None and due > time.time() and self._stop.wait(due - time.time()):
                    return
                self.stats.received()
                try:
                    self._publish(frame)
                except (ValueError, ArithmeticError) as error:  # one bad frame (wrong size, bad encoding,
                    # intrinsics that overflow the crop window): say so, go on; the same defect in every frame is
                    # logged once per log period, not per frame
                    if isinstance(error, ValueError):  # its message names the defect
                        reason, text = getattr(error, "reason", "invalid"), str(error)
                    else:
                        reason, text = "arithmetic", f"{type(error).__name__}: {error}"
                    self.stats.dropped(reason, f"camera '{self.camera}' frame: {text}")
        except SourceError as error:
            self.get_logger().error(f"camera source stopped: {error}")
            if self._params["source"] == "realsense":  # a live camera gone for good: let the runner respawn us
                self.failure = f"camera source stopped: {error}"
        except Exception as error:  # the context may be shut down under a publish at Ctrl-C
            if not self._stop.is_set() and self.context.ok():
                self.get_logger().error(f"camera source failed: {type(error).__name__}: {error}")
                # without its producer the node would live on publishing nothing: end the process (non-zero)
                self.failure = f"camera source failed: {type(error).__name__}: {error}"
            return
        self.get_logger().info(f"source finished after {self.frames_published} frames "
                               f"({self.frames_skipped} skipped to keep up)")

    def _publish(self, frame: SourceFrame) -> None:
        started = time.perf_counter()
        if self._clock_publisher is not None:
            self._clock_publisher.publish(Clock(clock=stamp_msg(frame.stamp_ns)))
        camera = self.rig.cameras[self.camera]
        if frame.cloud is not None:
            self._cloud_publisher.publish(recorded_cloud_msg(frame.cloud, frame.stamp_ns))
            self.frames_published += 1
            self.stats.published(frame.stamp_ns, started)
            return
        i = frame.intrinsics  # before any arithmetic on them (an inf focal length overflowed the crop window)
        checked_intrinsics(i.width, i.height, i.fx, i.fy, i.cx, i.cy)
        unit = camera.depth_unit if frame.depth_unit is None else frame.depth_unit
        if self._depth_step is None:
            self._note_depth_step(frame.depth, unit)
        self._note_edge_band(frame.depth, unit, i.fx)
        depth_frame = CameraFrame(self.camera, frame.stamp_ns, depth=frame.depth, intrinsics=frame.intrinsics,
                                  color=frame.color, depth_unit=frame.depth_unit)
        if self._params["crop_to_robot"]:
            # Only the points inside the crop box travel: fusion would drop the others, and a D405 window's
            # full cloud (~28 000 points, 0.7 MB) overflows a shared-memory segment, so that over UDP a
            # best-effort subscriber lost half of them on a busy machine. The windows are kept by intrinsics.
            points = depth_points(depth_frame, self.rig, self.rig.crop_box(), self._windows)
            xyz, rgb, pixel = points.optical, points.rgb, points.pixel
        else:
            xyz, rgb, pixel = deprojected(depth_frame, self.rig)
        # the camera_info first: a subscriber pairing them (fusion_node's pixel footprint) has it when the cloud
        # of its stamp comes, as a driver publishes it before its image
        self._info_publisher.publish(camera_info_msg(frame, camera.frame_id))
        # the colour about the robot's pixels before the cloud too, as the offline command cuts it: relocation_node
        # needs it when the cloud comes through fusion and the filters (after them, it came after the cloud on a
        # busy machine); a colour of another size than the depth (registered by scaling) goes without, and
        # relocation_node places that view by depth alone
        wanted = self.rig.relocation.limbs and frame.color is not None
        view = CameraView.aligned(frame.color, i, camera.extrinsic) if wanted else None
        view = None if view is None or pixel is None else view.around(pixel)
        if view is not None:
            self._color_info_publisher.publish(intrinsics_info_msg(view.intrinsics, camera.frame_id, frame.stamp_ns))
            self._color_publisher.publish(color_image_msg(view.color, camera.frame_id, frame.stamp_ns))
        self._cloud_publisher.publish(camera_cloud_to_msg(xyz, rgb, pixel, camera.frame_id, frame.stamp_ns))
        self.frames_published += 1
        self.stats.published(frame.stamp_ns, started)

    def destroy_node(self) -> None:
        self._stop.set()
        source = self._source
        _close(source)  # wakes a producer blocked in the source (a frame wait, a reconnect delay)
        if getattr(self, "_thread", None) is not None:
            self._thread.join(timeout=5)
        if self._source is not source:  # a device the producer opened meanwhile (waiting for it) is closed too
            _close(self._source)
        super().destroy_node()


def _close(source) -> None:
    if source is not None and hasattr(source, "close"):
        source.close()


def main(args: list[str] | None = None) -> int:
    return run_node(CameraNode, args)


if __name__ == "__main__":
    sys.exit(main())
