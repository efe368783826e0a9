"""Bundle adjustment of the keyframes and scene landmarks (paper eq. ego_bd):
Huber-robust projection factors, Levenberg-Marquardt, built from
yowo_common.bundle's factor helpers. Beyond the paper's eq. ego_bd, each depth
measurement enters as a Huber-robust range factor between the keyframe and the
landmark (sigma from the structured-light noise model): it keeps the metric
scale of the RGB-D map and acts as the depth prior on landmarks without tying
them to the (drifting) initial poses as a world-frame prior would. The first
keyframe is held fixed (gauge). Two rounds: the pixel sigma is re-estimated
from the residuals (MAD) and gross outliers are dropped between them."""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from yowo_common.bundle import (FIXED_SIGMA, Observations, add_projection_factors, optimize, pose3,
                                reprojection_residuals, robust_sigma)
from yowo_common.camera import CameraModel
from yowo_common.geometry import transform_points

from .features import KeyframeFeatures, backproject
from .tracks import Tracks


@dataclass(frozen=True)
class BundleParams:
    sigma_px: float = 1.0                # first-round keypoint noise
    huber_k: float = 1.345
    depth_sigma_a_m: float = 0.0012      # sigma(z) = a + b (z - 0.4)^2 (Kinect-like structured light)
    depth_sigma_b: float = 0.0019
    max_iterations: int = 8              # per round; LM starts close (multiway registration): 15 changed no ATE by 0.1 mm
    rounds: int = 2
    outlier_k: float = 5.0               # observations beyond k sigma are dropped between rounds
    min_track_length: int = 2


@dataclass
class BundleOutput:
    T_world_kf: list[np.ndarray]
    landmarks: np.ndarray                # (P, 3) world
    descriptors: np.ndarray              # (P, 128) float32, of each landmark's first observation
    obs: Observations                    # camera = keyframe, point = landmark (undistorted pixels)
    rmse_px: float
    sigma_px: float
    initial_error: float
    final_error: float
    iterations: int
    dropped: int                         # observations removed as outliers


def depth_sigma(z: np.ndarray, params: BundleParams) -> np.ndarray:
    return params.depth_sigma_a_m + params.depth_sigma_b * (np.asarray(z) - 0.4) ** 2


def landmarks_from_tracks(tracks: Tracks, features: list[KeyframeFeatures], T_world_kf: list[np.ndarray],
                          K: np.ndarray, params: BundleParams = BundleParams()):
    """(landmark of each kept observation, initial landmark positions, keyframe,
    feature, undistorted pixel and depth of each kept observation). A landmark
    starts at the mean depth back-projection of its observations (the matches
    already passed the depth-consistency filter); tracks without any depth or
    shorter than min_track_length are left out."""
    kf, feat, trk = tracks.keyframe, tracks.feature, tracks.track
    uv = np.zeros((len(kf), 2))
    depth = np.full(len(kf), np.nan)
    world = np.zeros((len(kf), 3))
    for k in np.unique(kf):
        sel = kf == k
        f = features[k]
        uv[sel] = f.uv[feat[sel]]
        depth[sel] = f.depth[feat[sel]]
        has = sel & np.isfinite(depth)
        world[has] = transform_points(T_world_kf[k], backproject(uv[has], depth[has], K))
    n_tracks = tracks.count
    has = np.isfinite(depth)
    length = np.bincount(trk, minlength=n_tracks)
    with_depth = np.bincount(trk, weights=has.astype(float), minlength=n_tracks)
    sums = np.column_stack([np.bincount(trk, weights=world[:, i] * has, minlength=n_tracks) for i in range(3)])
    keep_track = (length >= params.min_track_length) & (with_depth > 0)
    points = sums[keep_track] / with_depth[keep_track, None]
    new_id = np.cumsum(keep_track) - 1
    sel = keep_track[trk]
    return new_id[trk[sel]], points, kf[sel], feat[sel], uv[sel], depth[sel]


def bundle_adjust(tracks: Tracks, features: list[KeyframeFeatures], T_world_kf: list[np.ndarray],
                  camera: CameraModel, params: BundleParams = BundleParams()) -> BundleOutput:
    """Refine keyframe poses and landmarks; `camera` is the undistorted pinhole."""
    K = camera.K
    lm, points, kf, feat, uv, depth = landmarks_from_tracks(tracks, features, T_world_kf, K, params)
    descriptors = np.zeros((len(points), 128), np.float32)
    first = np.unique(lm, return_index=True)[1]
    for i in first:
        descriptors[lm[i]] = features[kf[i]].descriptors[feat[i]]
    cameras = [camera] * len(T_world_kf)
    obs = Observations(kf, lm, uv, np.full(len(kf), params.sigma_px))
    rays = np.linalg.norm(np.column_stack([(uv - K[:2, 2]) / np.diag(K)[:2], np.ones(len(uv))]), axis=1)
    ranges = depth * rays                     # camera centre -> point distance
    T, P = list(T_world_kf), points
    sigma, dropped, keep = params.sigma_px, 0, np.ones(len(kf), bool)
    initial_error = final_error = 0.0
    iterations = 0
    for rnd in range(params.rounds):
        if rnd > 0:
            res = reprojection_residuals(cameras, T, P, obs)
            sigma = max(robust_sigma(res[keep]), 0.1)
            bad = ~np.isfinite(res).all(axis=1) | (np.linalg.norm(res, axis=1) > params.outlier_k * sigma)
            dropped = int((keep & bad).sum())
            keep &= ~bad
        current = Observations(obs.camera[keep], obs.point[keep], obs.uv[keep], np.full(int(keep.sum()), sigma))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for i, Ti in enumerate(T):
            values.insert(X(i), pose3(Ti))
        graph.add(gtsam.PriorFactorPose3(X(0), pose3(T[0]), gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)))
        for j in np.unique(current.point):
            values.insert(L(int(j)), gtsam.Point3(*P[j]))
        add_projection_factors(graph, current, cameras, X, L, params.huber_k)
        huber = gtsam.noiseModel.mEstimator.Huber.Create(params.huber_k)
        has = keep & np.isfinite(ranges)
        # Range sigmas on a 0.5 mm grid share their noise models.
        sigmas = np.maximum(np.round(depth_sigma(depth[has], params) / 5e-4), 1) * 5e-4
        models = {s: gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(1, float(s)))
                  for s in np.unique(sigmas)}
        for c, j, r, s in zip(obs.camera[has], obs.point[has], ranges[has], sigmas):
            graph.add(gtsam.RangeFactor3D(X(int(c)), L(int(j)), float(r), models[s]))
        result, e0, e1, its = optimize(graph, values, params.max_iterations)
        if rnd == 0:
            initial_error = e0
        final_error, iterations = e1, iterations + its
        T = [result.atPose3(X(i)).matrix() for i in range(len(T))]
        P = P.copy()
        for j in np.unique(current.point):
            P[j] = result.atPoint3(L(int(j)))
    res = reprojection_residuals(cameras, T, P, obs)[keep]
    rmse = float(np.sqrt(np.nanmean(np.sum(res**2, axis=1)))) if len(res) else float("nan")
    final_obs = Observations(obs.camera[keep], obs.point[keep], obs.uv[keep], np.full(int(keep.sum()), sigma))
    return BundleOutput(T, P, descriptors, final_obs, rmse, sigma, initial_error, final_error, iterations, dropped)
