"""Multiway registration's edge check (yowo_ego.posegraph.verify_edge) on two rendered
keyframes: a tracking edge that SIFT + PnP contradict is replaced, unless the gyro's
rotation over the edge says the edge is right (a symmetric room's look-alike views)."""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import look_at, rotation_angle_deg, se3
from yowo_ego.features import FeatureExtractor
from yowo_ego.frames import make_frame
from yowo_ego.odometry import Keyframe, OdometryEdge, RgbdOdometry, downsample
from yowo_ego.posegraph import LoopParams, match_pair, verify_edge


def _move(euler_deg, t):
    return se3(Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix(), t)


@pytest.fixture(scope="module")
def two_keyframes(renderer, ego_camera):
    """(T_0_1 true, features, keyframes, odometry, pair) of two views 8 deg / 11 cm apart."""
    T0 = look_at((0.8, 0.9, 1.6), (3.5, 3.2, 0.7))
    T_0_1 = _move([0.0, 8.0, 0.0], [0.1, 0.0, 0.05])
    odometry, extract = RgbdOdometry(ego_camera.K), FeatureExtractor()
    features, keyframes = [], []
    for i, T in enumerate((T0, T0 @ T_0_1)):
        view = renderer.render(ego_camera, T)
        frame = make_frame(i, view.rgb, view.depth, ego_camera)
        features.append(extract(cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY), frame.depth))
        keyframes.append(Keyframe(i, i, i, np.eye(4), *downsample(frame, odometry.params.scale), 0))
    pair = match_pair(features[0], features[1], 0, 1, ego_camera.K, LoopParams().features)
    assert pair.pnp is not None
    return T_0_1, features, keyframes, odometry, pair


@pytest.mark.parametrize("gyro, replaced", [("none", True), ("true", True), ("wrong", False)])
def test_an_edge_is_replaced_by_pnp_only_where_the_gyro_agrees(two_keyframes, gyro, replaced):
    T_0_1, features, keyframes, odometry, pair = two_keyframes
    wrong = T_0_1 @ _move([0.0, 12.0, 0.0], [0.0, 0.0, 0.0])      # what a wrong dense minimum gives
    R_gyro = {"none": None, "true": T_0_1[:3, :3], "wrong": wrong[:3, :3]}[gyro]
    edge = OdometryEdge(1, 0, wrong, np.eye(6), "odometry", R_gyro)
    out, was_replaced = verify_edge(edge, pair, features, keyframes, odometry, LoopParams())
    assert was_replaced == replaced
    if replaced:
        assert np.linalg.norm(out.T_target_source[:3, 3] - T_0_1[:3, 3]) < 0.005
        assert rotation_angle_deg(out.T_target_source[:3, :3], T_0_1[:3, :3]) < 0.2
        assert out.R_gyro is R_gyro
    else:
        assert out is edge
