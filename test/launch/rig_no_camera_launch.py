"""launch_testing: rig.launch.py with no D405 plugged in. Each camera_node waits for its device, saying so in a
log line and with /diagnostics ERROR; the stage nodes are up and idle (no tip); SIGINT, as Ctrl-C sends it,
ends every node with exit code 0.

Run by test/launch/test_launch_files.py in the build's environment."""

import time
import unittest

import launch_testing
import launch_testing.asserts
import pytest
import rclpy
from ament_index_python.packages import get_package_share_directory
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch_testing_ros import WaitForTopics

from launch import LaunchDescription


@pytest.mark.launch_test
def generate_test_description():
    share = get_package_share_directory("ntcr_recon")
    return LaunchDescription([
        IncludeLaunchDescription(PythonLaunchDescriptionSource(f"{share}/launch/rig.launch.py")),
        launch_testing.actions.ReadyToTest(),
    ])


class TestNoCamera(unittest.TestCase):
    def test_cameras_wait_and_the_rest_idles(self, proc_output, proc_info):
        proc_output.assertWaitFor("waiting for the device", timeout=120.0)
        with WaitForTopics([("/diagnostics", DiagnosticArray)], timeout=60.0):
            pass
        rclpy.init()
        node = rclpy.create_node("rig_launch_test")
        levels, tips = {}, []
        node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: levels.update(
            {status.name: status.level for status in m.status}), 10)
        node.create_subscription(PoseStamped, "/ntcr/tip", tips.append, 10)
        try:
            end = time.monotonic() + 20.0
            while time.monotonic() < end and not sum("camera" in name and level == DiagnosticStatus.ERROR
                                                     for name, level in levels.items()) >= 2:
                rclpy.spin_once(node, timeout_sec=0.1)
            end = time.monotonic() + 3.0
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.1)
            names = set(node.get_node_names())
        finally:
            node.destroy_node()
            rclpy.shutdown()
        cameras = {name: level for name, level in levels.items() if "camera" in name}
        print(f"rig.launch.py without cameras: /diagnostics {cameras}, nodes {sorted(names)}", flush=True)
        self.assertEqual(sorted(cameras.values()), [DiagnosticStatus.ERROR] * 2, levels)
        self.assertLessEqual({"camera_cam_a", "camera_cam_b", "fusion_node", "filter_node", "relocation_node",
                              "mesh_node"}, names)
        self.assertEqual(tips, [])


@launch_testing.post_shutdown_test()
class TestCtrlC(unittest.TestCase):
    def test_every_node_ends_cleanly(self, proc_info, proc_output):
        launch_testing.asserts.assertExitCodes(proc_info)
        for output in proc_output:
            self.assertNotIn("Traceback", output.text.decode())
