"""Bundle adjustment (eq. ego_bd) with depth range factors on synthetic tracks."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, look_at, rotation_angle_deg, se3, transform_points
from yowo_ego.feature_tracks import Tracks
from yowo_ego.features import KeyframeFeatures
from yowo_ego.refine import BundleParams, bundle_adjust, select_landmarks

CAM = CameraModel.from_fov(640, 480, 70.0)


def synthetic(outlier_fraction: float, seed: int = 0):
    """8 keyframes walking past textured walls 2-4 m away; every landmark is
    observed in every keyframe that sees it; a fraction of observations are
    gross mismatches (random pixels and depths)."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-1, 6, 900), rng.uniform(3.0, 3.5, 900), rng.uniform(0, 2.5, 900)])
    poses = [look_at((x, 0.0, 1.6), (x + 0.5, 3.0, 1.0)) for x in np.linspace(0, 3.0, 8)]
    features, kf, feat, trk = [], [], [], []
    for k, T in enumerate(poses):
        uv, front = CAM.project(transform_points(inv_se3(T), points))
        z = transform_points(inv_se3(T), points)[:, 2]
        seen = np.flatnonzero(front & CAM.in_image(uv, margin=5))
        uv = uv[seen] + rng.normal(0, 0.5, (len(seen), 2))
        depth = z[seen] * (1 + rng.normal(0, 0.004, len(seen)))
        bad = rng.random(len(seen)) < outlier_fraction
        uv[bad] = rng.uniform([0, 0], [640, 480], (bad.sum(), 2))
        depth[bad] = rng.uniform(1.0, 5.0, bad.sum())
        features.append(KeyframeFeatures(uv, np.zeros((len(seen), 128), np.float32), depth))
        kf += [k] * len(seen)
        feat += list(range(len(seen)))
        trk += list(seen)
    tracks = Tracks(np.array(kf), np.array(feat), np.array(trk))
    init = [poses[0]] + [
        T @ se3(Rotation.from_rotvec(rng.normal(0, 0.01, 3)).as_matrix(), rng.normal(0, 0.03, 3)) for T in poses[1:]
    ]
    return poses, init, tracks, features


def pose_errors(est, truth):
    return (
        np.mean([np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(est, truth)]),
        np.mean([rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(est, truth)]),
    )


def test_clean_tracks_are_recovered():
    truth, init, tracks, features = synthetic(0.0)
    out = bundle_adjust(tracks, features, init, CAM)
    pos, rot = pose_errors(out.T_world_kf, truth)
    assert pos < 0.003 and rot < 0.05
    assert out.rmse_px < 0.8


def test_huber_loss_resists_five_percent_outliers():
    truth, init, tracks, features = synthetic(0.05)
    huber = bundle_adjust(tracks, features, init, CAM, BundleParams(rounds=1))
    squared = bundle_adjust(tracks, features, init, CAM, BundleParams(rounds=1, huber_k=1e9))
    pos_h, rot_h = pose_errors(huber.T_world_kf, truth)
    pos_s, rot_s = pose_errors(squared.T_world_kf, truth)
    assert pos_h < 0.01 and rot_h < 0.15  # from 4 cm / 0.6 deg initial errors
    assert pos_h < 0.5 * pos_s and rot_h < 0.5 * rot_s
    # The second round drops the outliers and re-estimates the pixel noise.
    two_rounds = bundle_adjust(tracks, features, init, CAM)
    assert two_rounds.dropped > 0.8 * 0.05 * len(tracks.track)
    assert two_rounds.sigma_px == pytest.approx(0.5, rel=0.3)
    assert pose_errors(two_rounds.T_world_kf, truth)[0] <= pos_h + 1e-4


def test_observation_budget_keeps_each_keyframes_longest_tracks():
    """A map over the budget keeps, in every keyframe, its longest tracks: the
    observations fit, no keyframe is left without landmarks, and the tracks left out
    are the short ones."""
    rng = np.random.default_rng(1)
    n_kf, n_lm = 60, 3000
    start = rng.integers(0, n_kf, n_lm)
    length = np.minimum(rng.geometric(0.3, n_lm) + 1, n_kf - start)  # most tracks short, a few long
    landmark = np.repeat(np.arange(n_lm), length)
    keyframe = np.concatenate([np.arange(s, s + n) for s, n in zip(start, length)])
    length = np.bincount(landmark)
    assert select_landmarks(landmark, keyframe, 0).all()
    assert select_landmarks(landmark, keyframe, len(landmark)).all()
    budget = len(landmark) // 3
    kept = select_landmarks(landmark, keyframe, budget)
    assert 0.8 * budget < length[kept].sum() <= budget
    for k in range(n_kf):
        seen = np.unique(landmark[keyframe == k])
        assert kept[seen].any()
        assert kept[seen[np.argmax(length[seen])]]  # its longest track stays
    assert length[kept].mean() > 1.5 * length[~kept].mean()


def test_bundle_adjustment_within_an_observation_budget():
    truth, init, tracks, features = synthetic(0.0)
    budget = len(tracks.track) // 3
    out = bundle_adjust(tracks, features, init, CAM, BundleParams(max_observations=budget))
    assert 0.8 * budget < len(out.obs) <= budget
    assert len(out.obs) + out.left_out > 0.95 * len(tracks.track)  # what the tracks give, apart from 1-view tracks
    assert len(out.landmarks) == len(np.unique(out.obs.point)) < len(np.unique(tracks.track))
    pos, rot = pose_errors(out.T_world_kf, truth)
    assert pos < 0.006 and rot < 0.1  # from 4 cm / 0.6 deg; all observations: 3 mm / 0.05 deg
