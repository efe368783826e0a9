"""YOWO's node graph for machines with a ROS 2 Jazzy install (launch_ros has no PyPI
wheel; without a ROS install `yowo run` starts the same nodes itself).

Live:    ros2 launch yowo_bringup yowo.launch.py cameras:="[cam00, cam01]"
         ... walk ..., then `yowo end-walk` (or a replay's end) finalises every stage.
Replay:  ros2 launch yowo_bringup yowo.launch.py cameras:="[cam00, cam01]" bag:=/path/to/bag
Configuration: the tree of config/yowo.yaml (another file: config_file:=...); each node
gets its section as its `config` parameter, as `yowo run` does."""
import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from yowo_bringup.config import load_config, node_config


def _nodes(context):
    cameras = yaml.safe_load(LaunchConfiguration("cameras").perform(context)) or []
    config = load_config(LaunchConfiguration("config_file").perform(context))
    bag = LaunchConfiguration("bag").perform(context)

    def params(node: str, **wiring) -> list[dict]:
        return [{**node_config(config, node), **wiring}]
    nodes = [Node(package="yowo_cmc", executable="keypoint_tracker_node", name=f"keypoint_tracker_{c}",
                  parameters=params("keypoint_tracker", camera=c)) for c in cameras]
    nodes += [
        Node(package="yowo_cmc", executable="group_sfm_node", name="group_sfm",
             parameters=params("group_sfm", cameras=cameras)),
        Node(package="yowo_ego", executable="ego_mapper_node", name="ego_mapper", parameters=params("ego_mapper")),
        Node(package="yowo_fusion", executable="fusion_node", name="fusion", parameters=params("fusion", cameras=cameras)),
    ]
    if bag:
        nodes.append(Node(package="yowo_bringup", executable="replay_node", name="replay",
                          parameters=params("replay", bag=bag)))
    return nodes


def generate_launch_description():
    default_config = os.path.join(get_package_share_directory("yowo_bringup"), "config", "yowo.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("cameras", description="CMC names, e.g. [cam00, cam01]"),
        DeclareLaunchArgument("bag", default_value="", description="recording to replay (empty: live topics)"),
        DeclareLaunchArgument("config_file", default_value=default_config),
        OpaqueFunction(function=_nodes),
    ])
