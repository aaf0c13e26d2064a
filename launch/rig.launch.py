"""The whole graph on a live rig: one camera_node per camera (realsense source), fusion, filter, relocation, mesh.

ros2 launch ntcr_recon rig.launch.py config:=/path/to/my_rig.yaml [rviz:=true] [mesh_rate:=1.0]

The rig configuration (a ROS 2 parameter file, see config/rig_template.yaml) names the cameras (their serial
numbers, stream profiles and extrinsics), the robot and the stages' settings; every node reads it. A node that
dies is started again after `respawn_delay` seconds (as `ntcr-recon run` does), and a camera that is not
plugged in is waited for by its camera_node (a log line every few seconds, /diagnostics ERROR). A node that
refuses its configuration (exit code 2) would refuse it at every respawn: the launch is shut down instead, as
`ntcr-recon run` stops the graph. The stage nodes, the respawn delay and the nodes' DDS transports (UDP, unless
FASTDDS_BUILTIN_TRANSPORTS says otherwise) are `ntcr-recon run`'s (ntcr_recon.ros.graph).
"""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    LogInfo,
    OpaqueFunction,
    RegisterEventHandler,
    SetEnvironmentVariable,
)
from launch.conditions import IfCondition
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription
from ntcr_recon.ros.graph import CONFIG_REFUSED, NODE_TRANSPORTS, RESPAWN_DELAY_S, STAGE_NODES


def camera_names(config_path: str) -> list[str]:
    """The rig configuration's camera_names (the parameter file's first ros__parameters section)."""
    with open(config_path) as stream:
        document = yaml.safe_load(stream)
    parameters = next(v["ros__parameters"] for v in document.values() if "ros__parameters" in v)
    return list(parameters["camera_names"])


def graph_nodes(context, source_parameters) -> list[Node]:
    config = LaunchConfiguration("config").perform(context)
    use_sim_time = LaunchConfiguration("use_sim_time").perform(context).lower() == "true"
    nodes = []
    for index, camera in enumerate(camera_names(config)):
        parameters = {"camera": camera, **source_parameters(context, index)}
        nodes.append(Node(package="ntcr_recon", executable="camera_node", name=f"camera_{camera}", output="screen",
                          parameters=[config, parameters], respawn=True, respawn_delay=RESPAWN_DELAY_S))
    for executable in STAGE_NODES:
        extra = {"use_sim_time": use_sim_time}
        if executable == "mesh_node":
            extra["rate"] = float(LaunchConfiguration("mesh_rate").perform(context))
        if executable == "relocation_node":  # calibration.refine's ~/write_calibration edits this file
            extra["rig_file"] = os.path.abspath(config)
        nodes.append(Node(package="ntcr_recon", executable=executable, name=executable, output="screen",
                          parameters=[config, extra], respawn=True, respawn_delay=RESPAWN_DELAY_S))
    return nodes


def live_cameras(context, index: int) -> dict:
    return {"source": "realsense"}


def shutdown_on_refused_configuration(event, context) -> list:
    """OnProcessExit: a node that refused its configuration (exit code CONFIG_REFUSED) would refuse it again at
    every respawn, forever; shut the launch down instead, naming it. Any other exit: respawn does its work."""
    if event.returncode != CONFIG_REFUSED:
        return []
    # (event.name is the event's type; the process is event.process_name.) launch logs no shutdown's reason: say it
    reason = f"{event.process_name} refused its configuration (exit code {CONFIG_REFUSED})"
    return [LogInfo(msg=f"shutting the launch down: {reason}"), EmitEvent(event=Shutdown(reason=reason))]


def common_arguments(default_config: str) -> list:
    share = get_package_share_directory("ntcr_recon")
    return [
        # the nodes' DDS transports where the environment does not choose them: a respawned node would hear
        # nothing over shared memory (ntcr_recon.ros.graph)
        *(SetEnvironmentVariable(name, EnvironmentVariable(name, default_value=value))
          for name, value in NODE_TRANSPORTS.items()),
        RegisterEventHandler(OnProcessExit(on_exit=shutdown_on_refused_configuration)),
        DeclareLaunchArgument("config", default_value=default_config, description="rig configuration (YAML)"),
        DeclareLaunchArgument("mesh_rate", default_value="1.0", description="meshes per second"),
        DeclareLaunchArgument("rviz", default_value="false", description="start RViz2 with config/ntcr.rviz"),
        Node(package="rviz2", executable="rviz2", arguments=["-d", os.path.join(share, "config", "ntcr.rviz")],
             condition=IfCondition(LaunchConfiguration("rviz"))),
    ]


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("ntcr_recon")
    return LaunchDescription([
        *common_arguments(os.path.join(share, "config", "rig_template.yaml")),
        DeclareLaunchArgument("use_sim_time", default_value="false"),
        OpaqueFunction(function=lambda context: graph_nodes(context, live_cameras)),
    ])
