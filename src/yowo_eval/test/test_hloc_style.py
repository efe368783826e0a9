import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at, rotation_angle_deg, se3
from yowo_eval.hloc_style import HlocParams, KeyframeImage, build_database, localize
from yowo_sim.render import Renderer
from yowo_sim.scene import SceneSpec, build_scene

# 4 m x 4 m room (x, y in [0, 4]), ceiling 2.8 m, shelf along the y = 0 wall.
EGO = CameraModel.from_fov(640, 480, 70.0)
CMC = CameraModel(640, 480, CameraModel.from_fov(640, 480, 90.0).K, [-0.12, 0.02, 0.0, 0.0, 0.0])
T_CMC = look_at([0.3, 3.7, 2.6], [2.5, 1.0, 0.8])  # a ceiling corner looking down across the room
KEYFRAME_VIEWS = [
    ([1.0, 3.0, 1.6], [2.5, 1.0, 1.0]),
    ([2.0, 2.0, 1.6], [2.0, 0.0, 1.0]),
    ([2.0, 2.0, 1.6], [4.0, 0.0, 1.0]),
    ([2.0, 2.0, 1.6], [4.0, 2.0, 1.0]),
    ([1.2, 1.8, 1.6], [3.0, 0.0, 0.6]),
    ([2.0, 2.0, 1.6], [0.0, 4.0, 1.0]),
    ([2.0, 2.0, 1.6], [0.0, 2.0, 1.0]),
]


@pytest.fixture(scope="module")
def renderer():
    return Renderer(build_scene(SceneSpec(layout="room_4x4", num_furniture=2, seed=1)))


@pytest.fixture(scope="module")
def keyframes(renderer):
    poses = np.array([look_at(eye, target) for eye, target in KEYFRAME_VIEWS])
    images = {}
    for i, T in enumerate(poses):
        frame = renderer.render(EGO, T)
        images[i] = KeyframeImage(frame.rgb, frame.depth)
    return poses, images


@pytest.fixture(scope="module")
def background(renderer):
    return renderer.render(CMC, T_CMC).rgb


def errors(T):
    return np.linalg.norm(T[:3, 3] - T_CMC[:3, 3]), rotation_angle_deg(T[:3, :3], T_CMC[:3, :3])


def test_localises_ceiling_camera_without_prior(keyframes, background):
    poses, images = keyframes
    db = build_database(EGO, poses, images)
    result = localize(db, "cmc", background, CMC)
    assert result.T_world_cam is not None, result.reason
    pos, rot = errors(result.T_world_cam)
    assert pos < 0.02 and rot < 0.5
    assert result.num_inliers >= 50
    assert 0 in result.retrieved  # the keyframe with the most similar view


def symmetric_trap(keyframes):
    """A symmetric room whose two halves look alike: every keyframe's images again at the
    pose rotated 180 deg about the room's vertical centre line. The copies come first, so
    an exact tie in appearance goes to the copy."""
    poses, images = keyframes
    flip = se3(np.diag([-1.0, -1.0, 1.0]), [4.0, 4.0, 0.0])
    n = len(poses)
    return (np.concatenate([flip @ poses, poses]), {i: images[i % n] for i in range(2 * n)}, n)


def test_symmetric_room_fools_retrieval_without_prior(keyframes, background):
    poses, images, n = symmetric_trap(keyframes)
    db = build_database(EGO, poses, images)
    result = localize(db, "cmc", background, CMC, params=HlocParams(num_retrieved=1))
    assert result.retrieved[0] < n  # a copy: appearance cannot tell the halves apart
    assert result.T_world_cam is not None and errors(result.T_world_cam)[0] > 1.0


def test_prior_gates_out_the_symmetric_half(keyframes, background):
    poses, images, n = symmetric_trap(keyframes)
    db = build_database(EGO, poses, images)
    rough = se3(
        T_CMC[:3, :3] @ Rotation.from_rotvec([0.02, -0.03, 0.01]).as_matrix(), T_CMC[:3, 3] + [0.15, -0.1, 0.05]
    )
    assert 1.0 < errors(rough)[1] < 3.0
    result = localize(db, "cmc", background, CMC, prior=rough, params=HlocParams(num_retrieved=3))
    assert min(result.retrieved) >= n  # only the genuine half
    assert result.T_world_cam is not None, result.reason
    pos, rot = errors(result.T_world_cam)
    assert pos < 0.02 and rot < 0.5


def test_prior_far_from_the_map_is_reported(keyframes, background):
    poses, images = keyframes
    db = build_database(EGO, poses, images)
    away = look_at([2.0, 2.0, 2.7], [2.3, 2.0, 5.0])  # looking at the ceiling: no keyframe saw it
    result = localize(db, "cmc", background, CMC, prior=away)
    assert result.T_world_cam is None and "no keyframe" in result.reason
