"""Pairing the cameras' frames by stamp (approximate time; the D405 has no hardware sync), ROS-free.

Three ways, one rule (`pair_frames`: frames of different cameras pair when their stamps differ by at most
`slop_ns`, nearest first; a frame without a partner goes alone):
  - `pair_frames`: every frame of a bag at once;
  - `pair_frame_stream`: a bag read front to back (the offline command), the same pairs, holding only the
    frames that may still find a partner;
  - `FramePairer`: live frames (fusion_node), with a silent-camera timeout, described below.

A `FramePairer` is fed each camera's frames as they arrive (`add(camera, stamp_ns, item)`; `item` is whatever
the caller keeps for a frame, e.g. its points) and releases, in stamp order, every frame pair that is complete
or can no longer be completed:
  - a pair: every camera has a frame within `slop_ns`;
  - a lone frame whose partner was lost (the other camera is alive and has already sent a later frame):
    given up and counted (`unpaired`), or with `publish_unpaired` released alone;
  - a lone frame of a camera whose partner is silent: the silent camera's newest stamp lags the newest stamp
    of the others by more than `timeout_ns` plus one of its own frame periods (stamps and the camera's own
    rate measure the silence, never the wall clock: a busy machine that delivers a frame late does not make a
    camera silent, and a bag replayed at any rate behaves like the live rig).
Of several releases ready at once only the newest is returned (the others are counted as superseded: a later
stage keeps only the newest anyway). Each camera keeps at most `queue_size` frames (the oldest goes first,
counted as queue_overflow), so nothing waits forever and nothing grows without bound. Stamps that jump back by more
than the timeout (a bag played again) restart the pairing.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ntcr_recon.core.cloud.fusion import CameraFrame, FramePair


def stamp_jump(previous_ns: int | None, stamp_ns: int, ahead_s: float) -> float | None:
    """How far (s; negative: back) the stamps jumped from previous_ns to stamp_ns, when they went back or ahead by
    more than ahead_s (a replay looping, a camera reset, a frame of another clock); None when they did not, or
    there is no previous stamp."""
    if previous_ns is None:
        return None
    jump = (stamp_ns - previous_ns) * 1e-9
    return jump if jump < 0 or jump > ahead_s else None


class InForce:
    """What was in force at a stamp, of items stamped as they came (a camera's camera_info): the newest stamped at
    or before it, else (it came after the data it belongs to: recordings give no order among the messages of one
    instant) the nearest later one. Keeps the last `history` items, whatever the order they came in."""

    def __init__(self, history: int = 8) -> None:
        self._items: deque[tuple[int, Any]] = deque(maxlen=history)

    def __bool__(self) -> bool:
        return bool(self._items)

    def add(self, stamp_ns: int, item: Any) -> None:
        self._items.append((stamp_ns, item))

    def at(self, stamp_ns: int) -> tuple[int, Any] | None:
        """(its stamp, the item) in force at stamp_ns; None when nothing came yet."""
        if not self._items:
            return None
        earlier = [entry for entry in self._items if entry[0] <= stamp_ns]
        return (max(earlier, key=lambda e: e[0]) if earlier else min(self._items, key=lambda e: e[0]))

    def nearest(self, stamp_ns: int, within_ns: int) -> tuple[int, Any] | None:
        """(its stamp, the item) stamped nearest stamp_ns, at most within_ns from it; None when none is."""
        entry = min(self._items, key=lambda e: abs(e[0] - stamp_ns), default=None)
        return entry if entry is not None and abs(entry[0] - stamp_ns) <= within_ns else None

    def any_after(self, stamp_ns: int) -> bool:
        """Whether an item stamped after stamp_ns came (so nothing of stamp_ns itself is still to come, in order)."""
        return any(entry[0] > stamp_ns for entry in self._items)


def pair_frames(streams: dict[str, list[CameraFrame]], slop_ns: int) -> list[FramePair]:
    """Pair frames of several cameras whose stamps differ by at most slop_ns (approximate time).

    The camera with most frames leads; each other camera contributes its nearest unused frame within the
    slop. A frame of any camera left without partner becomes a one-camera pair, so nothing is lost when a
    camera drops frames. Pairs come out in stamp order.
    """
    streams = {name: sorted(frames, key=lambda f: f.stamp_ns) for name, frames in streams.items() if frames}
    if not streams:
        return []
    leader = max(streams, key=lambda name: len(streams[name]))
    pairs = [{leader: frame} for frame in streams[leader]]
    lead_stamps = np.array([f.stamp_ns for f in streams[leader]], dtype=np.int64)
    unpaired: list[CameraFrame] = []
    for name, frames in streams.items():
        if name == leader:
            continue
        stamps = np.array([f.stamp_ns for f in frames], dtype=np.int64)
        distance = np.abs(stamps[:, None] - lead_stamps[None, :])
        taken = np.zeros(len(lead_stamps), dtype=bool)
        used = np.zeros(len(stamps), dtype=bool)
        # Closest matches first, so a frame never steals the partner of a better-matching one.
        for flat in np.argsort(distance, axis=None):
            i, j = divmod(int(flat), len(lead_stamps))
            if distance[i, j] > slop_ns:
                break
            if not (taken[j] or used[i]):
                pairs[j][name] = frames[i]
                taken[j] = used[i] = True
        unpaired.extend(frame for frame, was_used in zip(frames, used, strict=True) if not was_used)
    result = [FramePair(min(f.stamp_ns for f in p.values()), p) for p in pairs]
    result += [FramePair(f.stamp_ns, {f.camera: f}) for f in unpaired]
    return sorted(result, key=lambda p: p.stamp_ns)


def pair_frame_stream(frames: Iterable[CameraFrame], slop_ns: int, silent_after_ns: int) -> Iterator[FramePair]:
    """pair_frames for frames that arrive one by one, each camera's in stamp order (a bag read front to
    back): the same pairs, in stamp order, holding only the frames that may still find a partner.

    A pair is settled once every camera still sending has sent a frame stamped more than slop_ns after all
    of its frames (no later frame can be its partner). A camera whose newest frame is more than
    silent_after_ns older than the newest frame of any camera is silent and not waited for, so the frames
    held never span much more than that.
    """
    held: list[CameraFrame] = []
    latest: dict[str, int] = {}
    for frame in frames:
        held.append(frame)
        latest[frame.camera] = max(latest.get(frame.camera, frame.stamp_ns), frame.stamp_ns)
        newest = max(latest.values())
        settled_before = min(s for s in latest.values() if newest - s <= silent_after_ns) - slop_ns
        pairs = pair_frames(_by_camera(held), slop_ns)
        held = []
        for pair in pairs:
            if held or max(f.stamp_ns for f in pair.frames.values()) >= settled_before:
                held.extend(pair.frames.values())  # not settled, or after one that is not: keeps stamp order
            else:
                yield pair
    yield from pair_frames(_by_camera(held), slop_ns)


def _by_camera(frames: list[CameraFrame]) -> dict[str, list[CameraFrame]]:
    streams: dict[str, list[CameraFrame]] = {}
    for frame in frames:
        streams.setdefault(frame.camera, []).append(frame)
    return streams



@dataclass(frozen=True)
class _Frame:
    camera: str
    stamp_ns: int
    item: Any = field(compare=False)


@dataclass(frozen=True)
class Release:
    """Frames of one instant to fuse: `items` by camera; `missing` the cameras without a frame in it and
    `reason` why it goes anyway ('pair', 'silent: <cameras>', 'partner lost')."""

    stamp_ns: int
    items: dict[str, Any]
    missing: tuple[str, ...]
    reason: str


@dataclass
class Step:
    """What one `add` changed: the release to fuse (or None), cameras that fell silent or came back, and the
    jump back of the stamps (s) when the pairing restarted."""

    release: Release | None = None
    newly_silent: list[str] = field(default_factory=list)
    back: list[str] = field(default_factory=list)
    restarted_after_jump_s: float | None = None


class FramePairer:
    def __init__(self, cameras: list[str] | tuple[str, ...], slop_ns: int, timeout_ns: int, queue_size: int = 10,
                 publish_unpaired: bool = False) -> None:
        if not cameras:
            raise ValueError("a FramePairer needs at least one camera")
        self.cameras = tuple(cameras)
        self.slop_ns, self.timeout_ns, self.publish_unpaired = int(slop_ns), int(timeout_ns), publish_unpaired
        self._buffers: dict[str, deque[_Frame]] = {}
        self.resize(queue_size)
        self._newest: dict[str, int] = {}        # newest stamp received per camera
        self._periods: dict[str, deque[int]] = {name: deque(maxlen=15) for name in self.cameras}
        self._first_stamp: int | None = None     # a camera never heard of is silent from the first stamp on
        self.silent: set[str] = set()
        self.counts = {"pairs": 0, "alone": 0, "unpaired": 0, "superseded": 0, "queue_overflow": 0}

    def resize(self, queue_size: int) -> None:
        """Keep at most `queue_size` frames per camera from now on (the newest of those buffered stay)."""
        for name in self.cameras:
            old = list(self._buffers.get(name, ()))
            self._buffers[name] = deque(old[-queue_size:], maxlen=int(queue_size))

    def newest(self, camera: str) -> int | None:
        return self._newest.get(camera)

    def lag_s(self, camera: str) -> float | None:
        """How far (s) the camera's newest stamp lags the newest of all; None before it sent anything."""
        if camera not in self._newest:
            return None
        return (max(self._newest.values()) - self._newest[camera]) * 1e-9

    def period_ns(self, camera: str) -> int:
        """The camera's own frame period: median of its recent stamp steps (0 until known)."""
        steps = self._periods[camera]
        return int(np.median(steps)) if steps else 0

    def add(self, camera: str, stamp_ns: int, item: Any) -> Step:
        if camera not in self._buffers:
            raise ValueError(f"frame from camera {camera!r}, which is not one of {list(self.cameras)}")
        step = Step()
        stamp_ns = int(stamp_ns)
        if stamp_ns < self._newest.get(camera, stamp_ns) - self.timeout_ns:
            # Time went back (a bag played again): what is buffered belongs to another run of the clock.
            step.restarted_after_jump_s = (self._newest[camera] - stamp_ns) * 1e-9
            self._newest, self._first_stamp, self.silent = {}, None, set()
            for buffer in self._buffers.values():
                buffer.clear()
            for steps in self._periods.values():
                steps.clear()
        buffer = self._buffers[camera]
        if len(buffer) == buffer.maxlen:  # the oldest goes first
            buffer.popleft()
            self.counts["queue_overflow"] += 1
        buffer.append(_Frame(camera, stamp_ns, item))
        previous = self._newest.get(camera)
        if previous is not None and stamp_ns > previous:
            self._periods[camera].append(stamp_ns - previous)
        self._newest[camera] = max(stamp_ns, previous if previous is not None else stamp_ns)
        self._first_stamp = stamp_ns if self._first_stamp is None else self._first_stamp
        self._update_silence(step)
        step.release = self._release()
        return step

    def _update_silence(self, step: Step) -> None:
        newest = max(self._newest.values())
        silent = set()
        for name in self.cameras:
            # One of its own frame periods on top of the timeout: a camera whose next frame is merely due is
            # not silent, whatever its rate.
            allowance = self.timeout_ns + self.period_ns(name)
            if newest - self._newest.get(name, self._first_stamp) > allowance:
                silent.add(name)
        step.newly_silent = sorted(silent - self.silent)
        step.back = sorted(self.silent - silent)
        self.silent = silent

    def _release(self) -> Release | None:
        streams = {name: list(buffer) for name, buffer in self._buffers.items()}
        ready: list[Release] = []
        for pair in pair_frames(streams, self.slop_ns):
            missing = tuple(name for name in self.cameras if name not in pair.frames)
            # A missing camera that is alive and has not yet sent anything later than this pair may still do so.
            if any(name not in self.silent and self._newest.get(name, -1) < pair.stamp_ns + self.slop_ns
                   for name in missing):
                break
            self._take(pair.frames)
            items = {name: frame.item for name, frame in pair.frames.items()}
            if not missing:
                ready.append(Release(pair.stamp_ns, items, missing, "pair"))
            elif set(missing) <= self.silent:
                ready.append(Release(pair.stamp_ns, items, missing, f"silent: {', '.join(missing)}"))
            elif self.publish_unpaired:
                ready.append(Release(pair.stamp_ns, items, missing, "partner lost"))
            else:
                self.counts["unpaired"] += 1  # its partner was lost on the way: half a robot is worse than none
        self.counts["superseded"] += max(len(ready) - 1, 0)
        if not ready:
            return None
        newest = ready[-1]
        self.counts["alone" if newest.missing else "pairs"] += 1
        return newest

    def _take(self, frames: dict[str, _Frame]) -> None:
        for name, frame in frames.items():
            buffer = self._buffers[name]
            kept = [f for f in buffer if f is not frame]
            buffer.clear()
            buffer.extend(kept)
