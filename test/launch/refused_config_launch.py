"""launch_testing: rig.launch.py with a rig configuration one node refuses. That node exits with CONFIG_REFUSED (2),
its error naming the key, and the launch shuts itself down (rig.launch.py's OnProcessExit handler) with a reason
naming the node, instead of respawning it forever; the other nodes are stopped by the launch, cleanly.

Only mesh_node refuses: the rig file is bags/bend45/rig.yaml with a section of mesh_node's own setting
robot.notch_count to -3 (ROS parameter files apply a node's section over `/**`). Had every node refused (one bad
value in `/**`), the first exit would shut the launch down while the others were still starting, and the
launch's SIGINT / SIGTERM would reach them at any point of their start (one that was about to refuse was then
recorded with -15, not 2): what each exit code means would depend on timing. With one refusing node every exit
has one meaning: mesh_node 2, every other node 0 (stopped by the launch's SIGINT). mesh_node is the node that
starts last (it loads open3d before reading its parameters), so the others are up when it refuses.

The launch must end by itself: the active test only waits for it. launch_testing itself shuts a launch down once
the active tests are over (reason "LaunchService.shutdown() called") and calls it a failure when the launch ends
before they are over, so the shutdown's reason is recorded here (launch itself never prints it) and the launch
is held until the active tests are over (hold_until_tests_done).

Run by test/launch/test_launch_files.py in the build's environment (NTCR_TEST_BAG names the bag whose rig.yaml is
used)."""

import asyncio
import atexit
import os
import signal
import tempfile
import threading
import time
import unittest

import launch_testing
import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from launch.actions import IncludeLaunchDescription, LogInfo, RegisterEventHandler
from launch.event_handlers import OnProcessExit, OnProcessStart, OnShutdown
from launch.launch_description_sources import PythonLaunchDescriptionSource

from launch import Action, LaunchDescription

CONFIG_REFUSED = 2  # ntcr_recon.ros.graph.CONFIG_REFUSED (the test is meant to notice if it changes)
REFUSING_NODE = "mesh_node"
BAD_KEY, BAD_VALUE = "robot.notch_count", -3
# the graph's processes, named by their executables (launch names a process <executable>-<n>): two cameras
EXECUTABLES = ("camera_node", "camera_node", "fusion_node", "filter_node", "relocation_node", "mesh_node")
REFUSAL_TIMEOUT_S = 120.0

shutdowns: list[str] = []  # the reason of every Shutdown event, in order
shut_down = threading.Event()
starts: list[str] = []  # process names, one per start (a respawn starts one again)
exits: list[tuple[str, int]] = []  # (process name, exit code) of every exit (launch_testing's proc_info keeps the last)
active_tests_done = threading.Event()


def executable(process_name: str) -> str:
    return process_name.rsplit("-", 1)[0]


def bad_rig_file() -> str:
    """bags/bend45/rig.yaml plus a mesh_node section with the bad value; removed when the launch test ends."""
    with open(os.path.join(os.environ["NTCR_TEST_BAG"], "rig.yaml")) as stream:
        document = yaml.safe_load(stream)
    section, name = BAD_KEY.split(".")
    document[f"/{REFUSING_NODE}"] = {"ros__parameters": {section: {name: BAD_VALUE}}}
    handle, path = tempfile.mkstemp(prefix="ntcr_refused_", suffix=".yaml")
    with os.fdopen(handle, "w") as stream:
        yaml.safe_dump(document, stream, sort_keys=False)  # `/**` first: rig.launch.py reads its camera_names
    atexit.register(os.remove, path)
    return path


class HoldUntilTestsDone(Action):
    """hold_until_tests_done as an action the launch waits for. Not an OpaqueCoroutine: that cancels itself on
    any later Shutdown (launch_testing's own, once the tests are over), and a cancelled action ends the launch's
    run at once ("run task was canceled"), the other nodes' exits unrecorded (CI)."""

    _future = None

    def execute(self, context) -> None:
        self._future = context.asyncio_loop.create_task(hold_until_tests_done(context))

    def get_asyncio_future(self):
        return self._future


def on_shutdown(event, context) -> list:
    """Record the reason (and say it: launch does not), then, on the first shutdown, keep the launch up until the
    active tests are over."""
    shutdowns.append(event.reason)
    first = not shut_down.is_set()
    shut_down.set()
    return [LogInfo(msg=f"launch shut down: {event.reason}"), *([HoldUntilTestsDone()] if first else [])]


async def hold_until_tests_done(context) -> None:
    """The launch ends (LaunchService.run returns) once its processes have exited; launch_testing then fails the run
    unless its active tests have finished, which they do a moment after the shutdown they wait for. Wait for them
    (their runner thread, launch_testing's 'test_runner_thread'), and for every started process's exit: once the
    tests are over launch_testing shuts the launch down itself, which cancels its run task, and an exit not yet
    recorded then is lost (CI saw the other five nodes' exits missing so). 60 s at most."""
    deadline = time.monotonic() + 60.0
    runners = [thread for thread in threading.enumerate() if thread.name == "test_runner_thread"]
    while time.monotonic() < deadline and (not active_tests_done.is_set() or any(t.is_alive() for t in runners)
                                           or len(exits) < len(starts)):
        await asyncio.sleep(0.05)


@pytest.mark.launch_test
def generate_test_description():
    share = get_package_share_directory("ntcr_recon")
    return LaunchDescription([
        RegisterEventHandler(OnShutdown(on_shutdown=on_shutdown)),
        RegisterEventHandler(OnProcessStart(on_start=lambda event, context: starts.append(event.process_name))),
        RegisterEventHandler(OnProcessExit(
            on_exit=lambda event, context: exits.append((event.process_name, event.returncode)))),
        IncludeLaunchDescription(PythonLaunchDescriptionSource(f"{share}/launch/rig.launch.py"),
                                 launch_arguments={"config": bad_rig_file()}.items()),
        launch_testing.actions.ReadyToTest(),
    ])


class TestRefusal(unittest.TestCase):
    @classmethod
    def tearDownClass(cls):
        active_tests_done.set()

    def test_the_launch_shuts_itself_down(self):
        # no SIGINT from here: the launch has to end on its own, within the time a start takes
        self.assertTrue(shut_down.wait(REFUSAL_TIMEOUT_S), f"no shutdown {REFUSAL_TIMEOUT_S:.0f} s after the start; "
                                                           f"exits so far {exits}")
        print(f"shutdown reasons {shutdowns}; exits so far {exits}", flush=True)


@launch_testing.post_shutdown_test()
class TestAfterShutdown(unittest.TestCase):
    def test_the_reason_names_the_refusing_node(self):
        # the first shutdown is the launch's own (a later one, e.g. launch_testing's, is a no-op)
        self.assertRegex(shutdowns[0], rf"^{REFUSING_NODE}-\d+ refused its configuration "
                                       rf"\(exit code {CONFIG_REFUSED}\)$")

    def test_the_refusing_node_exits_2_and_is_not_respawned(self):
        refused = [(name, code) for name, code in exits if name.startswith(REFUSING_NODE + "-")]
        self.assertEqual([code for _, code in refused], [CONFIG_REFUSED], exits)
        self.assertEqual(sorted(executable(name) for name in starts), sorted(EXECUTABLES), starts)  # one start each

    def test_the_others_are_stopped_cleanly(self):
        others = [(name, code) for name, code in exits if not name.startswith(REFUSING_NODE + "-")]
        self.assertEqual(sorted(executable(name) for name, _ in others),
                         sorted(e for e in EXECUTABLES if e != REFUSING_NODE), exits)
        # 0: each ended on the launch's SIGINT as on a Ctrl-C; not -SIGINT / -SIGTERM (interrupted mid-start, or
        # still running after sigterm_timeout), 1 (an error) or 2 (refused as well)
        self.assertEqual([code for _, code in others], [0] * len(others),
                         f"exit codes {exits} (-{int(signal.SIGINT)}: SIGINT, -{int(signal.SIGTERM)}: SIGTERM)")

    def test_the_refusal_names_the_key_and_nothing_crashed(self, proc_output):
        texts = {}
        for io in proc_output:
            texts.setdefault(io.process_name, []).append(io.text.decode(errors="replace"))
        refusing = "".join(next(text for name, text in texts.items() if name.startswith(REFUSING_NODE + "-")))
        self.assertIn(f"error: rig configuration: {BAD_KEY} must be > 0", refusing)
        self.assertIn(f"got {BAD_VALUE}", refusing)
        for name, text in texts.items():
            self.assertNotIn("Traceback", "".join(text), name)
