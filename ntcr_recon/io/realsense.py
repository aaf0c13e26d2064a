"""camera_node's `realsense` (a live D405) and `file` (a librealsense recording) sources, through pyrealsense2.

`RealSenseSource` picks a device by serial number, opens it at construction (SourceError: no device, wrong
serial, no such profile) and, when frames stop (device dropped), re-opens it with a growing backoff.
`RecordingSource` plays a .db3 (or legacy .bag) recording, looping with stamps shifted so time keeps moving
forward. Both stream at sensor level through `io.realsense_streams` and yield `SourceFrame`s like
`BagSource`, which camera_node deprojects like any other source. The device part takes any `rs.device`, so
tests hand it a `rs.software_device` fed with synthetic frames. No `rs.pipeline`: pyrealsense2 2.59 no
longer lists a software device added to a context (2.54 did), so a pipeline could not be tested.

The depth unit is set to the configured one (0.1 mm on a D405) when the sensor lets it be set, and what the
device then reports is what the frames carry: never the 1 mm steps realsense-ros forces.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import pyrealsense2 as rs

from ntcr_recon.core.config.rig import CameraConfig
from ntcr_recon.io.camera_sources import SourceError, SourceFrame
from ntcr_recon.io.realsense_streams import (
    DepthFilters,
    FrameTimeoutError,
    SensorStreams,
    frame_stamp_ns,
    profile_text,
    select_streams,
)

NO_DEVICE = "no RealSense device connected"
RECORDING_SUFFIXES = (".db3", ".bag")
MAX_RECONNECT_PERIOD = 30.0
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

    def _open(self) -> SensorStreams:
        device = self._pick_device()
        what = f"RealSense {_serial(device)} (camera '{self.camera.name}')"
        try:
            self._configure(device, what)
            streams = SensorStreams(device, *select_streams(device, self.camera.width, self.camera.height,
                                                       self.camera.fps, self.color, self.log, what))
        except RuntimeError as error:  # librealsense's own (device busy, gone mid-way...): say which device
            raise SourceError(f"{what}: {error}") from error
        self.log.info(f"{what}: streaming depth {profile_text(streams.depth_profile)}"
                      + (f" + colour {profile_text(streams.color_profile)}" if streams.color_profile else "")
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
            streams = SensorStreams(device, *select_streams(device, None, None, None, self.color, self.log,
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
