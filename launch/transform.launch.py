"""Move one camera's cloud into the base frame with transform_node.

ros2 launch ntcr_recon transform.launch.py camera:=cam_a params:=/path/to/transform.yaml
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("ntcr_recon")
    camera = LaunchConfiguration("camera")
    return LaunchDescription([
        DeclareLaunchArgument("camera", default_value="cam_a"),
        DeclareLaunchArgument("namespace", default_value="ntcr"),
        DeclareLaunchArgument("params", default_value=os.path.join(share, "config", "transform_cam_a.yaml")),
        Node(
            package="ntcr_recon",
            executable="transform_node",
            name=[camera, "_to_base"],
            namespace=LaunchConfiguration("namespace"),
            parameters=[LaunchConfiguration("params")],
            remappings=[("points_in", PathJoinSubstitution([camera, "depth", "color", "points"])),
                        ("points_out", PathJoinSubstitution([camera, "points_base"]))],
        ),
    ])
