"""librealsense streaming at sensor level, shared by the live and the recorded source (`io.realsense`).

A device's depth sensor streams z16 depth and, where asked, colour (rgb8/bgr8/rgba8/bgra8) into one frame
queue; `SensorStreams` pairs depth with colour by timestamp and aligns colour to depth with `rs.align` when the
two streams differ (on a D405 the colour comes from the depth imager itself and needs none); `DepthFilters`
runs librealsense's own spatial / temporal / hole-filling filters; `source_frame` turns a pair into the
SourceFrame every camera source yields (raw 16-bit depth with the device's own depth unit, intrinsics from
the stream profile). The device is any `rs.device`: real, playback or `rs.software_device`.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np
import pyrealsense2 as rs

from ntcr_recon.core.cloud.deproject import Intrinsics
from ntcr_recon.io.camera_sources import SourceError, SourceFrame

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


def profile_text(profile) -> str:
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
        raise SourceError(f"the colour stream ({profile_text(color_profile)}) differs from the depth stream "
                          f"({profile_text(depth_profile)}) and the device gives no depth-to-colour extrinsics "
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


class SensorStreams:
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
            raise SourceError(f"cannot start streaming {', '.join(profile_text(p) for p in sum(groups.values(), []))}"
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
        offered = sorted({profile_text(p) for s in sensors for p in s.get_stream_profiles()
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
