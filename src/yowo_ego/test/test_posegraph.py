"""Multiway registration's edge check (yowo_ego.edge_checks.verify_edge) on two rendered
keyframes: a tracking edge that SIFT + PnP contradict is replaced, unless the gyro's
rotation over the edge says the edge is right (a symmetric room's look-alike views)."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import look_at, rotation_angle_deg, se3
from yowo_ego.edge_checks import match_pair, verify_across, verify_edge
from yowo_ego.features import FeatureExtractor, KeyframeFeatures
from yowo_ego.frames import make_frame
from yowo_ego.odometry import Keyframe, OdometryEdge
from yowo_ego.posegraph import LoopParams, tied_segment_starts
from yowo_ego.rgbd_odometry import RgbdOdometry, downsample


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
    wrong = T_0_1 @ _move([0.0, 12.0, 0.0], [0.0, 0.0, 0.0])  # what a wrong dense minimum gives
    R_gyro = {"none": None, "true": T_0_1[:3, :3], "wrong": wrong[:3, :3]}[gyro]
    edge = OdometryEdge(
        source=1, target=0, T_target_source=wrong, information=np.eye(6), kind="odometry", R_gyro=R_gyro
    )
    out, was_replaced = verify_edge(edge, pair, features, keyframes, odometry, LoopParams())
    assert was_replaced == replaced
    if replaced:
        assert np.linalg.norm(out.T_target_source[:3, 3] - T_0_1[:3, 3]) < 0.005
        assert rotation_angle_deg(out.T_target_source[:3, :3], T_0_1[:3, :3]) < 0.2
        assert out.R_gyro is R_gyro
    else:
        assert out is edge


@pytest.fixture(scope="module")
def three_keyframes(renderer, ego_camera):
    """(T_0_1, T_1_2 true, features of the views 0, 1, 2, keyframes, odometry) along a walk."""
    T0 = look_at((0.8, 0.9, 1.6), (3.5, 3.2, 0.7))
    T_0_1, T_1_2 = _move([0.0, 5.0, 0.0], [0.08, 0.0, 0.04]), _move([0.0, 5.0, 0.0], [0.08, 0.0, 0.04])
    odometry, extract = RgbdOdometry(ego_camera.K), FeatureExtractor()
    poses = [T0, T0 @ T_0_1, T0 @ T_0_1 @ T_1_2]
    features, keyframes = [], []
    for i, T in enumerate(poses):
        view = renderer.render(ego_camera, T)
        frame = make_frame(i, view.rgb, view.depth, ego_camera)
        features.append(extract(cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY), frame.depth))
        keyframes.append(Keyframe(i, i, i, np.eye(4), *downsample(frame, odometry.params.scale), 0))
    return T_0_1, T_1_2, features, keyframes, odometry


def _across(T_0_1, edge_1_2, features, keyframes, odometry):
    edges = [
        OdometryEdge(source=1, target=0, T_target_source=T_0_1, information=np.eye(6), kind="odometry"),
        OdometryEdge(source=2, target=1, T_target_source=edge_1_2, information=np.eye(6), kind="odometry"),
    ]
    replaced = verify_across(edges, [True, False], [], features, keyframes, odometry, LoopParams())
    return replaced, edges[1].T_target_source


def test_an_unchecked_edge_is_corrected_across_its_neighbour(three_keyframes):
    T_0_1, T_1_2, features, keyframes, odometry = three_keyframes
    replaced, T = _across(T_0_1, T_1_2 @ _move([0.0, 10.0, 0.0], [0.0, 0.0, 0.0]), features, keyframes, odometry)
    assert replaced == 1
    assert np.linalg.norm(T[:3, 3] - T_1_2[:3, 3]) < 0.01 and rotation_angle_deg(T[:3, :3], T_1_2[:3, :3]) < 0.3


def _seen(K, T_world_cam, points, descriptors):
    """KeyframeFeatures of world points from a camera (pixels, depth, the points' descriptors)."""
    X = (points - T_world_cam[:3, 3]) @ T_world_cam[:3, :3]
    return KeyframeFeatures(X[:, :2] / X[:, 2:] @ K[:2, :2].T + K[:2, 2], descriptors, X[:, 2])


def test_an_edge_the_matches_support_stays_against_a_look_alike_view(three_keyframes):
    """Keyframe 2 sees part of the room (45 points) where it is and, where keyframe 0 saw
    another wall (55 points), a look-alike wall 0.4 m over with the same texture: PnP across
    keyframes 0 and 2 fits the look-alike, while the tracked edge keeps most of the matches'
    support; it is not replaced (small symmetric s2 without IMU: a correctly tracked edge was
    moved 0.50 m). Where only the look-alike is seen, it is."""
    T_0_1, T_1_2, _, keyframes, odometry = three_keyframes
    rng = np.random.default_rng(0)
    T0 = look_at((0.0, 0.0, 1.5), (0.0, 4.0, 1.5))
    points = T0[:3, :3] @ np.column_stack([rng.uniform(-1.5, 1.5, (100, 2)), rng.uniform(2.5, 4.0, 100)]).T
    points = points.T + T0[:3, 3]
    descriptors = rng.integers(0, 256, (100, 128)).astype(np.uint8)
    T2 = T0 @ T_0_1 @ T_1_2
    K = odometry.K_full
    for wall, replaced_expected in ((55, 0), (100, 1)):
        look_alike = points.copy()
        look_alike[:wall] += [0.4, 0.0, 0.0]
        features = [_seen(K, T0, points, descriptors), None, _seen(K, T2, look_alike, descriptors)]
        replaced, T = _across(T_0_1, T_1_2, features, keyframes, odometry)
        assert replaced == replaced_expected
        assert (
            np.linalg.norm(T[:3, 3] - T_1_2[:3, 3]) < 0.01
            if not replaced
            else np.linalg.norm(T[:3, 3] - T_1_2[:3, 3]) > 0.3
        )


def test_segments_tied_to_the_walk_by_measured_edges():
    """Keyframes 0-2 segment 0, 3-4 segment 1 (after a break), 5-6 segment 2, 7 segment 3: a loop
    ties segment 2 to 0 and a corrected edge ties 3 to 2; segment 1 hangs on its break's guess."""
    segments = [0, 0, 0, 1, 1, 2, 2, 3]

    def edge(a, b, kind):
        return OdometryEdge(source=a, target=b, T_target_source=np.eye(4), information=np.eye(6), kind=kind)

    edges = [edge(0, 1, "odometry"), edge(1, 2, "odometry"), edge(2, 3, "break"), edge(3, 4, "odometry")]
    edges += [edge(4, 5, "break"), edge(5, 6, "odometry"), edge(6, 1, "loop"), edge(6, 7, "odometry")]
    assert tied_segment_starts(segments, edges) == [5, 7]
    assert tied_segment_starts(segments, edges[:5]) == []  # breaks alone tie nothing
    assert tied_segment_starts([0, 0], edges[:1]) == []
