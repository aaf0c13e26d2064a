"""A synthetic D405 for tests without hardware: a pyrealsense2 software device with the D405's layout (one
"Stereo Module" sensor streaming z16 depth and rgb8 colour from the same imager, a depth-units option), fed
with numpy frames that then travel through the real librealsense frame machinery, and recorded with
`rs.recorder` into a librealsense recording."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyrealsense2 as rs

if TYPE_CHECKING:  # only its fields are read: test/data/make_legacy_bag.py runs this without the package
    from ntcr_recon.core.cloud.deproject import Intrinsics


def rs_intrinsics(intrinsics: Intrinsics, scale: int = 1) -> rs.intrinsics:
    result = rs.intrinsics()
    result.width, result.height = intrinsics.width * scale, intrinsics.height * scale
    result.fx, result.fy = intrinsics.fx * scale, intrinsics.fy * scale
    result.ppx, result.ppy = intrinsics.cx * scale, intrinsics.cy * scale
    result.model, result.coeffs = rs.distortion.none, [0.0] * 5
    return result


def _video_stream(kind, uid: int, intrinsics: rs.intrinsics, fps: int, fmt, bpp: int) -> rs.video_stream:
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid = kind, 0, uid
    stream.width, stream.height, stream.fps, stream.fmt, stream.bpp = (intrinsics.width, intrinsics.height, fps,
                                                                       fmt, bpp)
    stream.intrinsics = intrinsics
    return stream


class SoftwareD405:
    """A software device with a serial number; `feed` pushes one depth (+ colour) frame into it.

    depth_unit: the value of the depth-units option (read-only unless `writable_unit`). color_scale: colour
    resolution relative to depth (not 1: a colour stream that needs aligning, with identity extrinsics).
    """

    def __init__(self, intrinsics: Intrinsics, serial: str = "230322270001", fps: int = 30,
                 depth_unit: float = 1e-4, color: bool = True, color_scale: int = 1,
                 writable_unit: bool = False) -> None:
        self.intrinsics, self.fps = intrinsics, fps
        self.device = rs.software_device()
        self.device.register_info(rs.camera_info.serial_number, serial)
        self.device.register_info(rs.camera_info.name, "Intel RealSense D405 (software device)")
        self.sensor = self.device.add_sensor("Stereo Module")
        self.depth_profile = self.sensor.add_video_stream(
            _video_stream(rs.stream.depth, 0, rs_intrinsics(intrinsics), fps, rs.format.z16, 2)
        ).as_video_stream_profile()
        self.color_profile = None
        if color:
            self.color_profile = self.sensor.add_video_stream(
                _video_stream(rs.stream.color, 1, rs_intrinsics(intrinsics, color_scale), fps, rs.format.rgb8, 3)
            ).as_video_stream_profile()
            if color_scale != 1:
                same_place = rs.extrinsics()
                same_place.rotation, same_place.translation = [1, 0, 0, 0, 1, 0, 0, 0, 1], [0, 0, 0]
                self.depth_profile.register_extrinsics_to(self.color_profile, same_place)
        if writable_unit:
            # This pyrealsense2 swaps option_range's step and default: (min, max, default, step) here.
            self.sensor.add_option(rs.option.depth_units, rs.option_range(1e-6, 1e-2, depth_unit, 1e-6), True)
        else:
            self.sensor.add_read_only_option(rs.option.depth_units, depth_unit)

    def feed(self, depth: np.ndarray, color: np.ndarray | None, timestamp_ms: float, frame_number: int,
             domain=rs.timestamp_domain.system_time) -> None:
        """One frame: raw uint16 depth (H, W) and RGB colour (h, w, 3), the same timestamp, depth first."""
        streams = [(self.depth_profile, np.ascontiguousarray(depth, np.uint16), 2)]
        if color is not None:
            streams.append((self.color_profile, np.ascontiguousarray(color, np.uint8), 3))
        for profile, pixels, bpp in streams:
            frame = rs.software_video_frame()
            frame.pixels, frame.bpp, frame.stride = pixels, bpp, pixels.shape[1] * bpp
            frame.timestamp, frame.domain, frame.frame_number = timestamp_ms, domain, frame_number
            frame.profile = profile
            self.sensor.on_video_frame(frame)

    def record(self, path: Path, frames, paced: bool = False) -> Path:
        """Write `frames` [(depth, colour, timestamp_ms), ...] as a librealsense recording at `path` (.db3).

        The recorder files each frame at the time it arrives: `paced` feeds them at their timestamps' intervals,
        as a camera would, so a real-time playback has a schedule to keep (unpaced, they all arrive at once)."""
        recorder = rs.recorder(str(path), self.device)
        sink = rs.frame_queue(len(frames) * 2 + 2, True)
        self.sensor.open([p for p in (self.depth_profile, self.color_profile) if p is not None])
        self.sensor.start(sink)
        started = time.monotonic()
        for number, (depth, color, timestamp_ms) in enumerate(frames):
            if paced:
                time.sleep(max(0.0, started + (timestamp_ms - frames[0][2]) / 1000 - time.monotonic()))
            self.feed(depth, color, timestamp_ms, number)
        self.sensor.stop()
        self.sensor.close()
        recorder.pause()
        del recorder  # the file is complete once the recorder is gone
        return path
