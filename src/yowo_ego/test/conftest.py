"""Shared fixtures: one synthetic room and its renderer per test session (building
the textured scene is the slow part)."""
import pytest
import rclpy

from yowo_ego.ego_mapper_node import EgoMapperNode
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset

from yowo_common.camera import CameraModel
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
