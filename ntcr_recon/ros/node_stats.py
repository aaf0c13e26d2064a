"""How a node is doing, in one place: input and output rates, frames dropped and why, processing time and
latency, on `/diagnostics` (every `diagnostics_period` s) and in a log line (every `log_period` s).

A node calls `received()` for every input message, `published(stamp_ns, started)` after publishing the result
of the input stamped `stamp_ns` (`started`: `time.perf_counter()` when its work began), and `dropped(reason,
detail)` for an input it refuses (the first drop of each kind, its reason and detail with the numbers taken out,
is logged; further ones within a log period are only counted and their number told with the next line, so a
stream of bad messages cannot flood the log). Both timers run on the steady clock: a replay that pauses its
/clock does not silence the report.

Latency is the node's clock minus the stamp of the input when the result is published: the age of the data,
meaningful when the stamps and the node's clock agree (a live rig, or `use_sim_time` on a replay); stamps far
from the clock (a bag replayed without sim time) give `n/a`.
"""

from __future__ import annotations

import contextlib
import re
import time
from collections import Counter, deque
from collections.abc import Callable

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from ntcr_recon.ros.messages import diagnostics

WINDOW = 300           # processing times / latencies kept for the percentiles
PLAUSIBLE_AGE_S = 10.0  # a latency beyond this means the stamps are on another clock than the node's
_NUMBER = re.compile(r"[-+]?\d[\d.eE+-]*")  # what differs between two drops of the same kind (sizes, stamps)

# (level, message, extra key -> value) a node adds to its report; level None: OK unless frames were dropped
StatusSource = Callable[[], tuple[bytes | None, str, dict[str, object]]]


class NodeStats:
    def __init__(self, node: Node, name: str, *, log_period: float = 5.0, diagnostics_period: float = 1.0,
                 status: StatusSource | None = None) -> None:
        self._node, self.name, self._status = node, name, status
        self.inputs = self.outputs = 0
        self.drops: Counter[str] = Counter()
        self._processing: deque[float] = deque(maxlen=WINDOW)
        self._latency: deque[float] = deque(maxlen=WINDOW)
        self._logged_kinds: dict[tuple[str, str], float] = {}  # drop kind -> steady time one was last logged
        self._suppressed: Counter[tuple[str, str]] = Counter()
        self._log_period = log_period
        now = time.monotonic()
        self._since_log = (now, 0, 0, 0)          # (time, inputs, outputs, drops) at the last log line
        self._since_diagnostics = (now, 0, 0, 0)  # and at the last /diagnostics message
        self._publisher = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        node.create_timer(diagnostics_period, self.publish_diagnostics, clock=steady)
        node.create_timer(log_period, self._log_line, clock=steady)

    # ---- what the node reports ---------------------------------------------------------------------------------
    def received(self) -> None:
        self.inputs += 1

    def published(self, stamp_ns: int, started: float) -> None:
        self.outputs += 1
        self._processing.append(time.perf_counter() - started)
        age = self._node.get_clock().now().nanoseconds - int(stamp_ns)
        if abs(age) < PLAUSIBLE_AGE_S * 1e9:
            self._latency.append(age * 1e-9)

    def dropped(self, reason: str, detail: str | None = None) -> None:
        """Count a dropped frame under `reason`; log `detail` (default: the reason) unless a drop of the same
        kind was logged less than a log period ago. The kind is the reason and the detail with its numbers taken
        out: the texts carry numbers that change every frame (sizes, stamps, spans), so keyed by the exact text
        a stream of bad frames logged each one, while two different defects are still both told."""
        self.drops[reason] += 1
        text = detail or reason
        kind = (reason, _NUMBER.sub("#", text))
        now = time.monotonic()
        if now - self._logged_kinds.get(kind, -float("inf")) < self._log_period:
            self._suppressed[kind] += 1
            return
        repeats = self._suppressed.pop(kind, 0)
        self._logged_kinds[kind] = now
        if len(self._logged_kinds) > 100:  # bounded: forget the kinds logged longest ago
            for old in sorted(self._logged_kinds, key=self._logged_kinds.get)[:50]:
                del self._logged_kinds[old]
                self._suppressed.pop(old, None)
        more = f" ({repeats} more like it since)" if repeats else ""
        self._node.get_logger().error(f"dropped a message ({reason}): {text}{more}")

    # ---- the report --------------------------------------------------------------------------------------------
    def summary(self, since: tuple[float, int, int, int]) -> dict[str, object]:
        elapsed = max(time.monotonic() - since[0], 1e-9)
        values: dict[str, object] = {
            "input_hz": f"{(self.inputs - since[1]) / elapsed:.1f}",
            "output_hz": f"{(self.outputs - since[2]) / elapsed:.1f}",
            "inputs": self.inputs, "outputs": self.outputs, "dropped": sum(self.drops.values()),
        }
        values.update({f"dropped.{reason}": count for reason, count in sorted(self.drops.items())})
        for key, series in (("processing_ms", self._processing), ("latency_ms", self._latency)):
            if series:
                p50, p95 = np.percentile(np.asarray(series) * 1e3, [50, 95])
                values[f"{key}.p50"], values[f"{key}.p95"] = f"{p50:.1f}", f"{p95:.1f}"
            else:
                values[f"{key}.p50"] = values[f"{key}.p95"] = "n/a"
        return values

    def _mark(self) -> tuple[float, int, int, int]:
        return time.monotonic(), self.inputs, self.outputs, sum(self.drops.values())

    def publish_diagnostics(self) -> None:
        values = self.summary(self._since_diagnostics)
        dropped_now = sum(self.drops.values()) - self._since_diagnostics[3]
        self._since_diagnostics = self._mark()
        level, message, extra = self._status() if self._status is not None else (None, "", {})
        if level is None:
            level = DiagnosticStatus.WARN if dropped_now else DiagnosticStatus.OK
        message = message or (f"{values['output_hz']} Hz out" + (f", {dropped_now} dropped" if dropped_now else ""))
        values.update(extra)
        with contextlib.suppress(Exception):  # the context may be going down under the timer
            self._publisher.publish(diagnostics(self.name, f"ntcr_recon/{self._node.get_name()}", level, message,
                                                values, self._node.get_clock().now().nanoseconds))

    def _log_line(self) -> None:
        values = self.summary(self._since_log)
        self._since_log = self._mark()
        drops = ", ".join(f"{reason} {count}" for reason, count in sorted(self.drops.items())) or "none"
        self._node.get_logger().info(
            f"in {values['input_hz']} Hz, out {values['output_hz']} Hz; processing p50 {values['processing_ms.p50']} "
            f"/ p95 {values['processing_ms.p95']} ms; latency p50 {values['latency_ms.p50']} / p95 "
            f"{values['latency_ms.p95']} ms; dropped so far: {drops}")
