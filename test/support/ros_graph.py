"""Helpers for tests that run real nodes: a private DDS domain, nodes started as their own processes
through their console scripts, and a test-side rclpy node that publishes and collects."""

from __future__ import annotations

import itertools
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

# Domain ids 1..100 are safe on Linux; start at a random one so concurrent runs rarely meet, and
# localhost-only discovery (conftest) keeps them off the network either way.
_DOMAINS = itertools.cycle(range(1, 101))
for _ in range(random.Random(os.getpid()).randrange(100)):
    next(_DOMAINS)

VENV_BIN = Path(sys.executable).parent


def frame_statuses(statuses) -> dict[int, tuple[object, dict[str, str]]]:
    """relocation_node's per-frame statuses (diagnostic_msgs DiagnosticStatus, in the order they came) by their
    frame's stamp (the `stamp_ns` value, ns): (the status, its values as a dict), the last one of each stamp.
    Statuses without a stamp (other nodes') are left out."""
    by_stamp = {}
    for status in statuses:
        values = {kv.key: kv.value for kv in status.values}
        if "stamp_ns" in values:
            by_stamp[int(values["stamp_ns"])] = status, values
    return by_stamp


class RosGraph:
    """One private DDS domain with node processes and an in-process test node."""

    def __init__(self, name: str = "test_probe") -> None:
        self.domain_id = next(_DOMAINS)
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id), PYTHONUNBUFFERED="1")
        self.context = Context()
        rclpy.init(context=self.context, domain_id=self.domain_id)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.processes: list[tuple[subprocess.Popen, Path]] = []

    def start(self, executable: str, *ros_args: str) -> subprocess.Popen:
        """Start a console script (a node) in this domain; its output goes to a log file."""
        log = Path(tempfile.mkstemp(prefix=f"{executable}-", suffix=".log")[1])
        command = [str(VENV_BIN / executable), *(["--ros-args", *ros_args] if ros_args else [])]
        process = subprocess.Popen(command, env=self.env, stdout=log.open("w"), stderr=subprocess.STDOUT)
        self.processes.append((process, log))
        return process

    def log_of(self, process: subprocess.Popen) -> str:
        return next(log for p, log in self.processes if p is process).read_text()

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Spin the test node until `condition()` holds or `timeout` seconds pass."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return condition()

    def call(self, service_type, name: str, request, timeout: float = 20.0, resend_after: float = 2.0):
        """The response of service `name` to `request`, sent again every `resend_after` seconds unanswered.

        wait_for_service holds once the server is discovered, which can be before the server has matched the
        client's request and reply topics: a request sent in that gap is lost (a full suite run once waited out
        10 s for a SetParameters reply). The requests this suite sends are idempotent, so sending one again is
        safe; the first reply wins.
        """
        client = self.node.create_client(service_type, name)
        deadline = time.monotonic() + timeout
        if not client.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"service {name} not available within {timeout} s; logs:\n" + self.all_logs())
        futures = []
        while time.monotonic() < deadline:
            futures.append(client.call_async(request))
            if self.spin_until(lambda: any(f.done() for f in futures),
                               min(resend_after, max(deadline - time.monotonic(), 0.0))):
                return next(f for f in futures if f.done()).result()
        raise TimeoutError(f"no reply from {name} within {timeout} s ({len(futures)} requests); logs:\n"
                           + self.all_logs())

    def wait_for_subscribers(self, publisher, count: int = 1, timeout: float = 20.0) -> None:
        if not self.spin_until(lambda: publisher.get_subscription_count() >= count, timeout):
            raise TimeoutError(f"no subscriber on {publisher.topic_name} within {timeout} s; logs:\n"
                               + self.all_logs())

    def all_logs(self) -> str:
        return "\n".join(f"--- {log.name}\n{log.read_text()}" for _, log in self.processes)

    def close(self) -> None:
        for process, _ in self.processes:
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        for process, _ in self.processes:
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        for _, log in self.processes:
            log.unlink(missing_ok=True)

    def __enter__(self) -> RosGraph:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
