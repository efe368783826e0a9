"""YOWO's node graph for machines with a ROS 2 Jazzy install (launch_ros has no PyPI
wheel; without a ROS install `yowo run` starts the same nodes itself).

Live:    ros2 launch yowo_bringup yowo.launch.py cameras:="[cam00, cam01]"
         ... walk ..., then `yowo end-walk` (or a replay's end) finalises every stage.
Replay:  ros2 launch yowo_bringup yowo.launch.py cameras:="[cam00, cam01]" bag:=/path/to/bag
Parameters: config/yowo.yaml (override with params_file:=...)."""
import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def _nodes(context):
    cameras = yaml.safe_load(LaunchConfiguration("cameras").perform(context)) or []
    params = LaunchConfiguration("params_file").perform(context)
    bag = LaunchConfiguration("bag").perform(context)
    nodes = [Node(package="yowo_cmc", executable="keypoint_tracker_node", name=f"keypoint_tracker_{c}",
                  parameters=[params, {"camera": c}]) for c in cameras]
    nodes += [
        Node(package="yowo_cmc", executable="group_sfm_node", name="group_sfm", parameters=[params, {"cameras": cameras}]),
        Node(package="yowo_ego", executable="ego_mapper_node", name="ego_mapper", parameters=[params]),
        Node(package="yowo_fusion", executable="fusion_node", name="fusion", parameters=[params, {"cameras": cameras}]),
    ]
    if bag:
        nodes.append(Node(package="yowo_bringup", executable="replay_node", name="replay",
                          parameters=[params, {"bag": bag}]))
    return nodes


def generate_launch_description():
    default_params = os.path.join(get_package_share_directory("yowo_bringup"), "config", "yowo.yaml")
    return LaunchDescription([
        DeclareLaunchArgument("cameras", description="CMC names, e.g. [cam00, cam01]"),
        DeclareLaunchArgument("bag", default_value="", description="recording to replay (empty: live topics)"),
        DeclareLaunchArgument("params_file", default_value=default_params),
        OpaqueFunction(function=_nodes),
    ])
