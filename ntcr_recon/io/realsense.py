"""camera_node's `realsense` (a live D405) and `file` (a librealsense recording) sources, through pyrealsense2.

Both open a librealsense device at sensor level (depth z16 + colour rgb8 streamed into one frame queue), pair
depth with colour by timestamp, align colour to depth with `rs.align` when the two streams differ (on a D405
the colour comes from the depth imager itself and needs none), optionally run librealsense's own spatial /
temporal / hole-filling filters on the depth, and yield `SourceFrame`s like `BagSource`: raw 16-bit depth
with the device's own depth unit, intrinsics from the stream profile, the frame's own timestamp. camera_node
deprojects them like any other source. The device part takes any `rs.device`, so tests hand it a
`rs.software_device` fed with synthetic frames. No `rs.pipeline`: pyrealsense2 2.59 no longer lists a
software device added to a context (2.54 did), so a pipeline could not be tested; the same sensor-level
code serves real, software and playback devices.

The depth unit is set to the configured one (0.1 mm on a D405) when the sensor lets it be set, and what the
device then reports is what the frames carry: never the 1 mm steps realsense-ros forces.

Public API (no rclpy import):
    NO_DEVICE                                 # the error text when no device is connected
    RealSenseSource(camera: CameraConfig, *, spatial=False, temporal=False, hole_filling=False, color=True,
                    reconnect_period=1.0, frame_timeout=5.0, log=None, devices=None)
        # opens the device at construction (SourceError: no device / wrong serial / no such profile);
        # iterating re-opens with backoff when frames stop (device dropped); close() ends the iteration.
        # devices: () -> list of rs.device to choose from (default: the connected ones)
    RecordingSource(path, *, loop=False, real_time=False, spatial=False, temporal=False, hole_filling=False,
                    log=None)
        # a .db3 (or legacy .bag) recording; loops with stamps shifted so time keeps moving forward
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from ntcr_recon.core.config import CameraConfig
from ntcr_recon.core.deproject import Intrinsics
from ntcr_recon.io.camera_sources import SourceError, SourceFrame

NO_DEVICE = "no RealSense device connected"
RECORDING_SUFFIXES = (".db3", ".bag")
MAX_RECONNECT_PERIOD = 30.0
_POLL_MS = 50  # how often a wait for frames looks at the stop flag / the end of a recording
_COLOR_CHANNELS = {rs.format.rgb8: (3, False), rs.format.bgr8: (3, True), rs.format.rgba8: (4, False),
                   rs.format.bgra8: (4, True)}


class FrameTimeoutError(SourceError):
    """No frame arrived within the timeout: the device stopped delivering (unplugged, USB reset...)."""


def stream_intrinsics(profile) -> Intrinsics:
    """The core's pinhole intrinsics of a librealsense video stream profile (D405 depth is rectified)."""
    i = profile.as_video_stream_profile().get_intrinsics()
    return Intrinsics(int(i.width), int(i.height), float(i.fx), float(i.fy), float(i.ppx), float(i.ppy))


def depth_unit_of(depth_frame) -> float:
    """Metres per raw depth unit. librealsense holds it as float32 (1e-4 reads 9.99999975e-05): keep the
    seven significant digits a float32 carries, so 0.1 mm stays exactly the configured 1e-4."""
    return float(f"{depth_frame.as_depth_frame().get_units():.7g}")


def frame_stamp_ns(frame) -> int:
    """A frame's own timestamp (milliseconds in its timestamp domain) in integer nanoseconds."""
    return int(round(frame.get_timestamp() * 1e6))


def _profile_text(profile) -> str:
    video = profile.as_video_stream_profile()
    return f"{video.width()}x{video.height()}@{profile.fps()} {profile.format()}".replace("format.", "")


def _same_intrinsics(a, b) -> bool:
    return stream_intrinsics(a) == stream_intrinsics(b)


def _needs_alignment(depth_profile, color_profile) -> bool:
    """Whether colour pixels differ from depth pixels: other intrinsics, or a non-identity depth->colour pose."""
    try:
        extrinsics = depth_profile.get_extrinsics_to(color_profile)
    except RuntimeError:  # none registered: the same imager only if the pixel grids agree
        if _same_intrinsics(depth_profile, color_profile):
            return False
        raise SourceError(f"the colour stream ({_profile_text(color_profile)}) differs from the depth stream "
                          f"({_profile_text(depth_profile)}) and the device gives no depth-to-colour extrinsics "
                          "to align it") from None
    identity = (np.allclose(np.reshape(extrinsics.rotation, (3, 3)), np.eye(3), atol=1e-6)
                and np.allclose(extrinsics.translation, 0.0, atol=1e-6))
    return not (identity and _same_intrinsics(depth_profile, color_profile))


def find_profile(sensors: Sequence, stream, formats: list, width: int | None, height: int | None,
                 fps: float | None, prefer: int | None = None) -> tuple[int, object] | None:
    """(index into `sensors`, profile) streaming `stream` in one of `formats` (first preferred) at the size
    and rate asked (None = any), preferring sensor `prefer`; None when no sensor offers it."""
    candidates = []
    for index, sensor in enumerate(sensors):
        for profile in sensor.get_stream_profiles():
            if profile.stream_type() != stream or profile.format() not in formats:
                continue
            video = profile.as_video_stream_profile()
            if ((width is None or video.width() == width) and (height is None or video.height() == height)
                    and (fps is None or profile.fps() == round(fps))):
                candidates.append(((index != prefer, formats.index(profile.format()), len(candidates)), index,
                                   profile))
    if not candidates:
        return None
    _, index, profile = min(candidates, key=lambda c: c[0])
    return index, profile


class DepthFilters:
    """librealsense's own post-processing of the depth frame, in the order librealsense recommends."""

    def __init__(self, spatial: bool = False, temporal: bool = False, hole_filling: bool = False) -> None:
        wanted = ((spatial, rs.spatial_filter), (temporal, rs.temporal_filter), (hole_filling, rs.hole_filling_filter))
        self.blocks = [make() for on, make in wanted if on]

    def __call__(self, depth_frame):
        for block in self.blocks:
            depth_frame = block.process(depth_frame)
        return depth_frame


class _BlockingSink:
    """Where a playback device's frames go: a bounded queue whose callback waits while it is full, so a
    non-real-time playback runs at the pace of its consumer and drops nothing (a live device streams into a
    `rs.frame_queue` instead, which drops the oldest frame rather than stall the camera)."""

    def __init__(self, size: int = 4) -> None:
        self._frames: queue.Queue = queue.Queue(size)
        self.stop = threading.Event()

    def __call__(self, frame) -> None:
        frame.keep()
        while not self.stop.is_set():
            try:
                self._frames.put(frame, timeout=_POLL_MS / 1000)
                return
            except queue.Full:
                continue

    def try_wait_for_frame(self, timeout_ms: int):
        try:
            return True, self._frames.get(timeout=timeout_ms / 1000)
        except queue.Empty:
            return False, None


class _Streams:
    """A device's depth (+ colour) streams at sensor level, read back as (depth, colour | None) frame pairs."""

    def __init__(self, device, sensors: Sequence, depth: tuple[int, object], color: tuple[int, object] | None,
                 blocking: bool = False) -> None:
        self.device = device  # frames must not outlive their device: it is released after them (close)
        self.depth_profile = depth[1]
        self.color_profile = color[1] if color is not None else None
        self.period_ms = 1000.0 / self.depth_profile.fps()
        self.align = (rs.align(rs.stream.depth) if self.color_profile is not None
                      and _needs_alignment(self.depth_profile, self.color_profile) else None)
        self._composite_parts: list = []
        self._composer = rs.processing_block(
            lambda frame, source: source.frame_ready(source.allocate_composite_frame(self._composite_parts)))
        self._composed = rs.frame_queue(1, True)
        self._composer.start(self._composed)
        groups: dict[int, list] = {}
        for index, profile in [depth, *([color] if color is not None else [])]:
            groups.setdefault(index, []).append(profile)
        self.queue = _BlockingSink() if blocking else rs.frame_queue(8, True)
        self._started = []
        try:
            for index, profiles in groups.items():
                sensors[index].open(profiles)
                self._started.append(sensors[index])
                sensors[index].start(self.queue)
        except RuntimeError as error:
            self.close()
            raise SourceError(f"cannot start streaming {', '.join(_profile_text(p) for p in sum(groups.values(), []))}"
                              f": {error}") from error

    def frames(self, timeout_s: float, stop: threading.Event, filters: DepthFilters, stamp_ns: Callable[..., int],
               ended: Callable[[], bool] = lambda: False) -> Iterator[SourceFrame]:
        """`pairs` as SourceFrames (depth through `filters`, stamped by `stamp_ns(depth frame)`). The frames'
        pixels are copied out, so no librealsense frame outlives the streams."""
        for depth, color in self.pairs(timeout_s, stop, ended):
            depth = filters(depth)
            frame = source_frame(depth, color, stamp_ns(depth))
            del depth, color
            yield frame

    def pairs(self, timeout_s: float, stop: threading.Event, ended: Callable[[], bool] = lambda: False
              ) -> Iterator[tuple]:
        """Depth frames with the colour frame of the same timestamp (within half a frame period), or None when
        it never comes. Ends when `stop` is set or `ended()` (a finished recording); raises FrameTimeoutError when
        no depth frame arrives for `timeout_s`."""
        pending = None  # a depth frame whose colour has not come yet
        colors: list = []  # colour frames waiting for their depth (the last few)
        started = last_frame = time.monotonic()
        received = False
        while not stop.is_set():
            ok, frame = self.queue.try_wait_for_frame(_POLL_MS)
            if not ok:
                # A playback reports `stopped` before its first frame too: believe it once frames came, or late.
                if ended() and (received or time.monotonic() - started > 1.0):
                    break
                if time.monotonic() - last_frame > timeout_s:
                    raise FrameTimeoutError(f"no depth frame for {timeout_s:g} s")
                continue
            received = True
            if frame.profile.stream_type() == rs.stream.color:
                if pending is not None and self._matches(pending, frame):
                    yield self._paired(pending, frame)
                    pending = None
                else:
                    colors = [*colors[-3:], frame]
                continue
            last_frame = time.monotonic()  # a device whose depth stopped has dropped, whatever else comes
            if pending is not None:  # the previous depth frame's colour never came: it goes without
                yield self._paired(pending, None)
                pending = None
            match = next((c for c in colors if self._matches(frame, c)), None)
            if match is not None or self.color_profile is None:
                colors = [c for c in colors if c is not match]
                yield self._paired(frame, match)
            else:
                pending = frame
        if pending is not None and not stop.is_set():
            yield self._paired(pending, None)

    def _matches(self, depth, color) -> bool:
        return (depth.get_frame_timestamp_domain() == color.get_frame_timestamp_domain()
                and abs(depth.get_timestamp() - color.get_timestamp()) < self.period_ms / 2)

    def _paired(self, depth, color) -> tuple:
        if color is None or self.align is None:
            return depth, color
        self._composite_parts = [depth, color]  # the processing block makes them one frameset, for rs.align
        self._composer.invoke(depth)
        frameset = self._composed.wait_for_frame(1000).as_frameset()
        aligned = self.align.process(frameset)
        return aligned.get_depth_frame(), aligned.get_color_frame()

    def close(self) -> None:
        if isinstance(self.queue, _BlockingSink):
            self.queue.stop.set()  # a callback waiting on a full queue must not hold up sensor.stop()
        for sensor in self._started:
            for step in (sensor.stop, sensor.close):
                with contextlib.suppress(RuntimeError):  # already stopped, or the device is gone
                    step()
        self._started = []
        # Release every frame still held before the device can go: a frame freed after its device crashes.
        self._composite_parts = []
        for sink in (self.queue, self._composed):
            while sink.try_wait_for_frame(0)[0]:
                pass


def source_frame(depth_frame, color_frame, stamp_ns: int) -> SourceFrame:
    """A librealsense depth (+ colour) frame pair as the SourceFrame every camera source yields."""
    depth = np.array(depth_frame.get_data(), dtype=np.uint16, copy=True)
    color = None
    if color_frame is not None:
        channels, bgr = _COLOR_CHANNELS[color_frame.profile.format()]
        video = color_frame.as_video_frame()
        pixels = np.asanyarray(video.get_data()).reshape(video.get_height(), video.get_width(), channels)
        color = np.ascontiguousarray(pixels[:, :, 2::-1] if bgr else pixels[:, :, :3])
    return SourceFrame(stamp_ns=stamp_ns, depth=depth, depth_unit=depth_unit_of(depth_frame),
                       intrinsics=stream_intrinsics(depth_frame.profile), color=color)


def select_streams(device, width: int | None, height: int | None, fps: float | None, color: bool, log,
                   what: str) -> tuple[list, tuple, tuple | None]:
    """(sensors, depth, colour | None) of `device`, each stream as (sensor index, profile): z16 depth at the
    size and rate asked (None = any) and, with `color`, colour of the same size and rate (else any size)."""
    sensors = list(device.query_sensors())
    depth_index = next((i for i, sensor in enumerate(sensors) if sensor.is_depth_sensor()), None)
    depth = find_profile(sensors, rs.stream.depth, [rs.format.z16], width, height, fps, depth_index)
    if depth is None:
        offered = sorted({_profile_text(p) for s in sensors for p in s.get_stream_profiles()
                          if p.stream_type() == rs.stream.depth})
        asked = "" if width is None else f" {width}x{height}@{fps:g}"
        raise SourceError(f"{what} has no z16 depth profile{asked} (depth profiles: {', '.join(offered) or 'none'})")
    color_pair = None
    if color:
        video = depth[1].as_video_stream_profile()
        formats = list(_COLOR_CHANNELS)
        color_pair = (find_profile(sensors, rs.stream.color, formats, video.width(), video.height(), depth[1].fps(),
                                   depth[0])
                      or find_profile(sensors, rs.stream.color, formats, None, None, depth[1].fps(), depth[0]))
        if color_pair is None:
            log.warning(f"{what} streams no rgb8/bgr8 colour at {depth[1].fps()} fps: clouds go without colour")
    return sensors, depth, color_pair


def _serial(device) -> str:
    if device.supports(rs.camera_info.serial_number):
        return device.get_info(rs.camera_info.serial_number)
    return "?"


class RealSenseSource:
    """A live D405 (any librealsense depth camera), picked by serial number, as SourceFrames."""

    def __init__(self, camera: CameraConfig, *, spatial: bool = False, temporal: bool = False,
                 hole_filling: bool = False, color: bool = True, reconnect_period: float = 1.0,
                 frame_timeout: float = 5.0, log=None,
                 devices: Callable[[], Sequence] | None = None) -> None:
        self.camera = camera
        self.color = color
        self.reconnect_period, self.frame_timeout = reconnect_period, frame_timeout
        self.log = log or logging.getLogger(__name__)
        self.devices = devices or (lambda: list(rs.context().query_devices()))
        self.filters = DepthFilters(spatial, temporal, hole_filling)
        self.reconnects = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._clock_offset_ns: int | None = None  # for hardware-clock stamps: device clock -> epoch
        self._streams = self._open()  # fail at start-up with a clear error: no device, wrong serial, no profile

    def _pick_device(self):
        devices = list(self.devices())
        if not devices:
            raise SourceError(NO_DEVICE)
        serials = [_serial(d) for d in devices]
        wanted = self.camera.serial_number
        if wanted:
            if wanted not in serials:
                raise SourceError(f"no RealSense device with serial number '{wanted}' for camera "
                                  f"'{self.camera.name}' (connected: {', '.join(serials)})")
            return devices[serials.index(wanted)]
        if len(devices) > 1:
            raise SourceError(f"{len(devices)} RealSense devices connected ({', '.join(serials)}): set "
                              f"{self.camera.name}.serial_number to pick one")
        return devices[0]

    def _open(self) -> _Streams:
        device = self._pick_device()
        what = f"RealSense {_serial(device)} (camera '{self.camera.name}')"
        try:
            self._configure(device, what)
            streams = _Streams(device, *select_streams(device, self.camera.width, self.camera.height,
                                                       self.camera.fps, self.color, self.log, what))
        except RuntimeError as error:  # librealsense's own (device busy, gone mid-way...): say which device
            raise SourceError(f"{what}: {error}") from error
        self.log.info(f"{what}: streaming depth {_profile_text(streams.depth_profile)}"
                      + (f" + colour {_profile_text(streams.color_profile)}" if streams.color_profile else "")
                      + (" (colour aligned to depth)" if streams.align else ""))
        return streams

    def _configure(self, device, what: str) -> None:
        """Depth unit as configured (kept fine: 0.1 mm), host-corrected frame timestamps where supported."""
        for sensor in device.query_sensors():
            if not sensor.is_depth_sensor():
                continue
            depth_sensor = sensor.as_depth_sensor()
            for option, value in ((rs.option.depth_units, self.camera.depth_unit),
                                  (rs.option.global_time_enabled, 1.0)):
                if depth_sensor.supports(option) and not depth_sensor.is_option_read_only(option):
                    try:
                        depth_sensor.set_option(option, value)
                    except RuntimeError as error:  # out of the device's range: what it keeps is checked below
                        self.log.warning(f"{what}: cannot set {option} to {value}: {error}")
            actual = float(f"{depth_sensor.get_depth_scale():.7g}")
            if not math.isclose(actual, self.camera.depth_unit, rel_tol=1e-6):
                self.log.warning(f"{what}: depth unit is {actual} m, not the configured {self.camera.depth_unit} "
                                 "m (the device does not allow it); frames carry the device's unit")

    def _stamp_ns(self, frame) -> int:
        stamp = frame_stamp_ns(frame)
        if frame.get_frame_timestamp_domain() != rs.timestamp_domain.hardware_clock:
            return stamp  # system / global time: already milliseconds since the epoch
        if self._clock_offset_ns is None:  # device clock: keep its intervals, anchored at the host clock once
            self._clock_offset_ns = time.time_ns() - stamp
        return stamp + self._clock_offset_ns

    def __iter__(self) -> Iterator[SourceFrame]:
        delay = self.reconnect_period
        while not self._stop.is_set():
            streams = self._streams
            if streams is None:
                try:
                    streams = self._open()
                except (SourceError, RuntimeError) as error:
                    self.log.warning(f"camera '{self.camera.name}': {error}; retrying in {delay:.1f} s")
                    self._stop.wait(delay)
                    delay = min(2 * delay, MAX_RECONNECT_PERIOD)
                    continue
                with self._lock:
                    if self._stop.is_set():
                        streams.close()
                        return
                    self._streams = streams
                self.reconnects += 1
                self.log.info(f"camera '{self.camera.name}': re-opened (reconnect {self.reconnects})")
                delay = self.reconnect_period
            try:
                yield from streams.frames(self.frame_timeout, self._stop, self.filters, self._stamp_ns)
            except (FrameTimeoutError, RuntimeError) as error:  # the device dropped: close, open again
                self.log.warning(f"camera '{self.camera.name}': {error}; closing the device and re-opening it")
                with self._lock:
                    streams.close()
                    self._streams = None
                self._clock_offset_ns = None

    def close(self) -> None:
        self._stop.set()
        with self._lock:
            if self._streams is not None:
                self._streams.close()
                self._streams = None


def _finished(playback) -> bool:
    return playback.current_status() == rs.playback_status.stopped


class RecordingSource:
    """A librealsense recording (.db3; legacy .bag where pyrealsense2 still reads it) as SourceFrames.

    `real_time`: librealsense paces playback at the recorded rate (dropping what the consumer misses);
    otherwise every frame is delivered as fast as it is taken (camera_node paces by its `rate`). With `loop`
    the recording repeats, stamps shifted by its length plus one frame period.
    """

    def __init__(self, path: str | Path, *, loop: bool = False, real_time: bool = False, spatial: bool = False,
                 temporal: bool = False, hole_filling: bool = False, color: bool = True, log=None) -> None:
        self.path = Path(path)
        self.loop, self.real_time, self.color = loop, real_time, color
        self.log = log or logging.getLogger(__name__)
        self.filters = DepthFilters(spatial, temporal, hole_filling)
        self._stop = threading.Event()
        if not self.path.is_file():
            raise SourceError(f"recording {self.path} does not exist")
        if self.path.suffix not in RECORDING_SUFFIXES:
            raise SourceError(f"recording {self.path} is not a librealsense recording "
                              f"({' or '.join(RECORDING_SUFFIXES)})")
        device, _ = self._load()  # refuse an unreadable file or one without depth now, not in the node's thread
        select_streams(device, None, None, None, False, self.log, f"recording {self.path}")

    def _load(self):
        context = rs.context()  # one per pass: a context refuses to load the same file twice
        try:
            device = context.load_device(str(self.path))
        except RuntimeError as error:
            raise SourceError(f"cannot play recording {self.path}: {error}") from error
        playback = device.as_playback()
        playback.set_real_time(self.real_time)
        return device, playback

    def __iter__(self) -> Iterator[SourceFrame]:
        offset_ns = 0
        while not self._stop.is_set():
            first = last = None
            device, playback = self._load()
            streams = _Streams(device, *select_streams(device, None, None, None, self.color, self.log,
                                                       f"recording {self.path}"), blocking=True)
            try:
                period_ns = int(round(streams.period_ms * 1e6))
                for frame in streams.frames(math.inf, self._stop, self.filters, frame_stamp_ns,
                                            functools.partial(_finished, playback)):
                    first = frame.stamp_ns if first is None else first
                    last = frame.stamp_ns
                    frame.stamp_ns += offset_ns
                    yield frame
            finally:
                streams.close()
            if not self.loop or first is None:
                return
            offset_ns += last - first + period_ns

    def close(self) -> None:
        self._stop.set()
