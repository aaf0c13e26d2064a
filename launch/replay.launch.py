"""The whole graph fed by a recorded rosbag2 bag (camera_node's bag source), the bag's stamps driving the clock.

ros2 launch ntcr_recon replay.launch.py bag:=/path/to/bags/bend45 loop:=true [config:=...] [rate:=1.0]

`config` defaults to the rig.yaml inside the bag directory (the simulator writes one); a bag recorded on a rig
needs that rig's configuration. The first camera_node publishes /clock from the frames' stamps and the stage
nodes run on it (use_sim_time), so a bag replayed at any rate behaves like the live rig. (`ros2 bag play
--clock` feeding realsense-ros topics works as well: fusion_node reads `.../depth/color/points`.) The camera
nodes get one `start_time` (as `ntcr-recon run` gives them), so they replay in step: the frames of one instant
reach fusion together. The sample bags are 0.1 s long: `loop:=true` keeps them coming.
"""

import importlib.util
import os
import time

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration

from launch import LaunchDescription
from ntcr_recon.ros.graph import START_DELAY_S


def _rig_launch():
    """rig.launch.py beside this file (installed together in share/ntcr_recon/launch): the shared graph."""
    spec = importlib.util.spec_from_file_location("ntcr_rig_launch",
                                                  os.path.join(os.path.dirname(__file__), "rig.launch.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


rig_launch = _rig_launch()
common_arguments, graph_nodes = rig_launch.common_arguments, rig_launch.graph_nodes


def bag_source(context, index: int) -> dict:
    return {"source": "bag", "bag_path": os.path.abspath(LaunchConfiguration("bag").perform(context)),
            "rate": float(LaunchConfiguration("rate").perform(context)),
            "loop": LaunchConfiguration("loop").perform(context).lower() == "true",
            "publish_clock": index == 0,
            "start_time": float(LaunchConfiguration("start_time").perform(context))}


def resolve_config(context) -> list:
    if not LaunchConfiguration("config").perform(context):
        bag = LaunchConfiguration("bag").perform(context)
        context.launch_configurations["config"] = os.path.join(os.path.abspath(bag), "rig.yaml")
    # One wall-clock instant for every camera's first frame, fixed once per launch.
    context.launch_configurations["start_time"] = f"{time.time() + START_DELAY_S:.3f}"
    return []


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("bag", description="rosbag2 directory to replay"),
        *common_arguments(""),
        DeclareLaunchArgument("rate", default_value="1.0", description="replay speed, 0 = as fast as possible"),
        DeclareLaunchArgument("loop", default_value="false"),
        DeclareLaunchArgument("use_sim_time", default_value="true"),
        OpaqueFunction(function=resolve_config),
        OpaqueFunction(function=lambda context: graph_nodes(context, bag_source)),
    ])
