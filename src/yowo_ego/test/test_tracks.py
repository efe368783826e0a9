"""Epipolar and depth/triangulation consistency filter; multi-view tracks; the
PnP check of tracking edges."""

import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.geometry import inv_se3, rotation_angle_deg, se3, transform_points
from yowo_ego.edge_checks import PairMatches, verify_edge
from yowo_ego.feature_tracks import build_tracks, filter_matches
from yowo_ego.features import KeyframeFeatures, match, relative_pose
from yowo_ego.odometry import Keyframe, OdometryEdge
from yowo_ego.posegraph import LoopParams
from yowo_ego.rgbd_odometry import RgbdOdometry

K = np.array([[457.0, 0.0, 319.5], [0.0, 457.0, 239.5], [0.0, 0.0, 1.0]])


def project(T_world_cam, X):
    P = transform_points(inv_se3(T_world_cam), X)
    return P[:, :2] / P[:, 2:] @ K[:2, :2].T + K[:2, 2], P[:, 2]


def scene(n=300, seed=0):
    rng = np.random.default_rng(seed)
    uv = rng.uniform([40, 40], [600, 440], (n, 2))
    z = rng.uniform(1.2, 5.0, n)
    return np.column_stack([(uv - K[:2, 2]) / 457.0, np.ones(n)]) * z[:, None]  # in camera a = world


T_A = np.eye(4)
T_B = se3(Rotation.from_euler("xyz", [1.0, -6.0, 0.5], degrees=True).as_matrix(), [0.25, 0.02, 0.08])


def test_wrong_matches_on_the_epipolar_line_are_rejected_by_depth():
    X = scene()
    uv_a, z_a = project(T_A, X)
    uv_b, z_b = project(T_B, X)
    n = len(X)
    # Wrong matches: b's keypoint shows another surface point Y on a's viewing ray
    # (so it lies exactly on the epipolar line); b's depth there is that of Y.
    wrong = np.arange(n) % 3 == 0
    scale = np.where(np.arange(n) % 2 == 0, 0.75, 1.35)
    Y = X * scale[:, None]
    uv_y, z_y = project(T_B, Y)
    uv_b = np.where(wrong[:, None], uv_y, uv_b)
    z_b = np.where(wrong, z_y, z_b)
    rng = np.random.default_rng(1)
    noisy_a = uv_a + rng.normal(0, 0.3, uv_a.shape)
    noisy_b = uv_b + rng.normal(0, 0.3, uv_b.shape)
    depth_a = z_a * (1 + rng.normal(0, 0.003, n))
    depth_b = z_b * (1 + rng.normal(0, 0.003, n))
    # The poses carry a multiway-registration-sized error (5 mm, 0.1 deg).
    T_B_est = T_B @ se3(Rotation.from_euler("y", 0.1, degrees=True).as_matrix(), [0.005, 0.0, 0.0])
    result = filter_matches(noisy_a, noisy_b, depth_a, depth_b, T_A, T_B_est, K)
    assert result.epipolar_rejected <= 0.02 * n  # none of them is off the epipolar line
    assert not result.keep[wrong].any()
    assert result.keep[~wrong].mean() > 0.97
    assert result.depth_rejected >= wrong.sum()


def test_matches_off_the_epipolar_line_are_rejected():
    X = scene(100)
    uv_a, z_a = project(T_A, X)
    uv_b, z_b = project(T_B, X)
    shuffled = np.roll(np.arange(100), 7)
    result = filter_matches(uv_a, uv_b[shuffled], np.full(100, np.nan), np.full(100, np.nan), T_A, T_B, K)
    # Without depth only the epipolar check applies; a few land near their line by chance.
    assert result.keep.sum() <= 5 and result.epipolar_rejected >= 95
    assert filter_matches(uv_a, uv_b, z_a, z_b, T_A, T_B, K).keep.all()


def test_pure_rotation_wrong_matches_are_rejected_by_the_depth_transfer():
    """No baseline: the epipolar geometry and triangulation say nothing; the
    depth back-projection reprojected into the other view still does."""
    T_rot = se3(Rotation.from_euler("y", 8.0, degrees=True).as_matrix(), [0.0, 0.0, 0.0])
    X = scene(200)
    uv_a, z_a = project(T_A, X)
    uv_b, z_b = project(T_rot, X)
    wrong = np.arange(200) % 4 == 0
    uv_b[wrong] += np.array([12.0, -5.0])
    result = filter_matches(uv_a, uv_b, z_a, z_b, T_A, T_rot, K)
    assert not result.keep[wrong].any() and result.keep[~wrong].all()


def test_tracks_chain_matches_and_drop_conflicts():
    pairs = [
        (0, 1, np.array([[0, 0], [1, 1]])),
        (1, 2, np.array([[0, 5], [1, 6]])),
        (0, 2, np.array([[0, 7]])),
    ]  # feature 0 of kf 0 matched to 5 and 7 of kf 2
    tracks = build_tracks(pairs, [3, 3, 8])
    assert tracks.count == 1  # the conflicting track is dropped
    assert sorted(zip(tracks.keyframe.tolist(), tracks.feature.tolist())) == [(0, 1), (1, 1), (2, 6)]


def test_tracking_edge_is_checked_against_pnp():
    """A tracking edge 2 deg off (a wrong dense minimum) is replaced by the PnP
    estimate from the keyframes' matches; a right one is kept."""
    X = scene(300, seed=3)
    rng = np.random.default_rng(4)
    feats = []
    for T in (T_A, T_B):
        uv, z = project(T, X)
        feats.append(
            KeyframeFeatures(uv + rng.normal(0, 0.3, uv.shape), rng.normal(size=(300, 128)).astype(np.float32), z)
        )
    feats[1].descriptors[:] = feats[0].descriptors  # every point matches its twin
    m = match(feats[0], feats[1])
    assert len(m) == 300
    pair = PairMatches(0, 1, m, relative_pose(feats[0], feats[1], m, K))
    blank = np.zeros((240, 320, 3), np.uint8), np.zeros((240, 320), np.uint16)
    kfs = [Keyframe(i, i, i, np.eye(4), *blank, 0) for i in range(2)]
    odometry = RgbdOdometry(K)
    T_true = inv_se3(T_A) @ T_B  # T_a_b
    wrong = T_true @ se3(Rotation.from_euler("x", 2.0, degrees=True).as_matrix(), [0.0, 0.03, 0.0])
    fixed, replaced = verify_edge(
        OdometryEdge(source=1, target=0, T_target_source=wrong, information=np.eye(6), kind="odometry"),
        pair,
        feats,
        kfs,
        odometry,
        LoopParams(),
    )
    assert replaced
    assert np.linalg.norm(fixed.T_target_source[:3, 3] - T_true[:3, 3]) < 0.005
    assert rotation_angle_deg(fixed.T_target_source[:3, :3], T_true[:3, :3]) < 0.1
    kept, replaced = verify_edge(
        OdometryEdge(source=1, target=0, T_target_source=T_true, information=np.eye(6), kind="odometry"),
        pair,
        feats,
        kfs,
        odometry,
        LoopParams(),
    )
    assert not replaced and kept.T_target_source is T_true
