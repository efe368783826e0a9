"""Shared fixtures: one synthetic room and its renderer per test session (building
the textured scene is the slow part)."""

import numpy as np
import pytest
import rclpy

from yowo_common.camera import CameraModel
from yowo_ego.ego_mapper_node import EgoMapperNode
from yowo_ego.imu import ImuBuffer
from yowo_ego.recording import EgoRecording, find_ego_topics, read_ego_frames
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset
from yowo_sim.render import Renderer
from yowo_sim.scene import SceneSpec, build_scene


@pytest.fixture(scope="session")
def ego_camera():
    """The simulator's ego camera (VGA, 70 deg horizontal field of view)."""
    return CameraModel.from_fov(640, 480, 70.0)


@pytest.fixture(scope="session")
def room():
    """A 4 m x 4 m room with furniture, rich texture (the 'tiny' preset's layout)."""
    return build_scene(SceneSpec(layout="room_4x4", num_furniture=2, seed=1))


@pytest.fixture(scope="session")
def renderer(room):
    return Renderer(room)


@pytest.fixture(scope="session")
def tiny_bag(tmp_path_factory):
    """A generated 'tiny' recording (seed 0: a fast turn makes odometry alone drift ~2 cm)."""
    bag = tmp_path_factory.mktemp("ego") / "tiny"
    generate(get_preset("tiny", cmc_images=False), 0, bag)
    return bag


def dark_noise(frame, rng):
    """What a depth camera facing a bare wall in darkness delivers: dim sensor noise in
    8 px blocks (enough for the input check, nothing to match) and depth on 10 % of the
    pixels at random ranges, new every frame."""
    stamp, color, depth = frame
    h, w = depth.shape
    noise = rng.integers(0, 40, (h // 8, w // 8, 1), dtype=np.uint8)
    color = np.ascontiguousarray(np.repeat(np.repeat(noise, 8, 0), 8, 1).repeat(3, 2))
    depth = np.full((h, w), np.nan, np.float32)
    some = rng.random((h, w)) < 0.1
    depth[some] = rng.uniform(0.5, 4.0, int(some.sum()))
    return stamp, color, depth


@pytest.fixture(scope="session")
def darken():
    """`dark_noise` for tests that darken frames of their own."""
    return dark_noise


@pytest.fixture(scope="session")
def dark_walk(tiny_bag):
    """(recording with its IMU samples, frames, the dark frames' indices) of the tiny walk
    with frames 60-67 (0.53 s) replaced by `dark_noise`: nothing to track there."""
    recording = EgoRecording(find_ego_topics(tiny_bag))
    recording.imu = ImuBuffer()
    frames = list(read_ego_frames(tiny_bag, recording))
    rng, dark = np.random.default_rng(0), range(60, 68)
    return recording, [dark_noise(f, rng) if i in dark else f for i, f in enumerate(frames)], dark


@pytest.fixture
def make_node():
    """make_node(*ros_args): an EgoMapperNode with those ROS arguments (e.g. "-p",
    "imu_topic:=/ego/imu"); tests hand it messages through its callbacks, no DDS."""
    nodes = []

    def make(*ros_args):
        rclpy.init(args=["--ros-args", *ros_args] if ros_args else None)
        nodes.append(EgoMapperNode())
        nodes[-1].published.clear()
        return nodes[-1]

    yield make
    for n in nodes:
        n.destroy_node()
    rclpy.try_shutdown()
