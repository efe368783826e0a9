"""YOWO's node graph for machines with a ROS 2 Jazzy install (launch_ros has no PyPI
wheel; without a ROS install `yowo run` starts the same nodes itself). The nodes and
their parameters come from the plan `yowo run` and `yowo live` make (yowo_bringup.run):
one description of the graph.

Replay:  ros2 launch yowo_bringup yowo.launch.py bag:=/path/to/bag [mode:=cmc]
Live:    ros2 launch yowo_bringup yowo.launch.py cameras:="[cam00, cam01]"
         ... walk ..., then `yowo end-walk` finalises every stage.
Configuration: the tree of config/yowo.yaml (another file: config_file:=...); each node
gets its section as its `config` parameter, as `yowo run` does."""

import os

import yaml
from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from yowo_bringup.config import load_config
from yowo_bringup.run import launch_nodes, plan_live, plan_run


def _nodes(context):
    def arg(name):
        return LaunchConfiguration(name).perform(context)

    config = load_config(arg("config_file"))
    if arg("bag"):
        plan = plan_run(
            arg("bag").split(os.pathsep), arg("output"), mode=arg("mode"), config=config, source=arg("cmc_source")
        )
    else:
        plan = plan_live(
            yaml.safe_load(arg("cameras")) or [],
            arg("output"),
            mode=arg("mode"),
            config=config,
            source=arg("cmc_source") if arg("cmc_source") != "auto" else "keypoints",
        )
    return [Node(**kwargs) for kwargs in launch_nodes(plan)]


def generate_launch_description():
    default_config = os.path.join(get_package_share_directory("yowo_bringup"), "config", "yowo.yaml")
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "bag",
                default_value="",
                description="recording to replay, several joined by ':' in time order (empty: live topics)",
            ),
            DeclareLaunchArgument("cameras", default_value="[]", description="live: CMC names, e.g. [cam00, cam01]"),
            DeclareLaunchArgument(
                "mode",
                default_value="full",
                description="full (cameras registered in the map) or cmc (relative calibration only)",
            ),
            DeclareLaunchArgument(
                "cmc_source", default_value="auto", description="CMC agent keypoints: auto, keypoints, pose or images"
            ),
            DeclareLaunchArgument("output", default_value="results", description="results directory of the run"),
            DeclareLaunchArgument("config_file", default_value=default_config),
            OpaqueFunction(function=_nodes),
        ]
    )
