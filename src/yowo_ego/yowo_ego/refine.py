"""Bundle adjustment of the keyframes and scene landmarks (paper eq. ego_bd):
Huber-robust projection factors, Levenberg-Marquardt, built from
yowo_common.bundle's factor helpers. Beyond the paper's eq. ego_bd, each depth
measurement enters as a Huber-robust range factor between the keyframe and the
landmark (sigma from the structured-light noise model): it keeps the metric
scale of the RGB-D map and acts as the depth prior on landmarks without tying
them to the (drifting) initial poses as a world-frame prior would. The first
keyframe is held fixed (gauge). Two rounds: the pixel sigma is re-estimated
from the residuals (MAD) and gross outliers are dropped between them.

The pose graph's edges (dense tracking, IMU bridges, tracking breaks, the loops the
line process kept) enter as Huber-robust between factors with their information:
without them a keyframe that sees few features (a bare wall) hangs on a handful of
projections, and a few wrong matches moved such keyframes by metres (texture_poor).
With the IMU (``InertialTerms``), consecutive keyframes are joined by GTSAM's
CombinedImuFactor (preintegrated gyro and accelerometer) with a velocity and a
bias per keyframe."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from yowo_common.bundle import (
    FIXED_SIGMA,
    Observations,
    add_projection_factors,
    optimize,
    pose3,
    reprojection_residuals,
    robust_sigma,
)
from yowo_common.camera import CameraModel
from yowo_common.geometry import transform_points

from .feature_tracks import Tracks
from .features import KeyframeFeatures, backproject
from .imu import InertialTerms
from .odometry import OdometryEdge
from .scene import FloorAttitudeParams, FloorAttitudes, WallAttitudeParams, WallAttitudes


@dataclass(frozen=True)
class BundleParams:
    sigma_px: float = 1.0  # keypoint noise in the first round (later rounds estimate it)
    huber_k: float = 1.345  # Huber threshold of the projection and range factors [sigmas]
    # Depth noise a of the range factors' sigma(z) = a + b (z - 0.4)^2 (Kinect-like structured light).
    depth_sigma_a_m: float = 0.0012
    depth_sigma_b: float = 0.0019  # growth b of the depth noise sigma(z) = a + b (z - 0.4)^2 [1/m]
    # Levenberg-Marquardt iterations per round at most [count]. LM starts close (multiway registration).
    max_iterations: int = 8
    rounds: int = 2  # solves; the pixel sigma is re-estimated and outliers dropped between them [count]
    outlier_k: float = 5.0  # observations beyond this many sigmas are dropped between rounds [sigmas]
    min_track_length: int = 2  # keyframes a track needs to become a landmark [count]
    # The pose graph's edges as between factors in the adjustment. Their Open3D information
    # counts each depth correspondence as 1 m of noise, i.e. a few mm / 0.1 deg per tracking edge.
    pose_graph_factors: bool = True
    edge_information_scale: float = 1.0  # multiplier of the pose graph edges' information [x]
    # Huber threshold of the edge factors' whitened error [sigmas]. A wrong edge yields to the features.
    edge_huber_k: float = 1.345
    # Observations the adjustment (and so the map) keeps at most, 0: all [count]. GTSAM's solve
    # takes kilobytes per observation, so above this each keyframe keeps its longest tracks
    # (select_landmarks).
    max_observations: int = 500_000
    # Without an IMU: each keyframe's view of the floor as a prior on its tilt (FloorAttitudeParams).
    floor: FloorAttitudeParams = FloorAttitudeParams()
    # Without an IMU: each keyframe's largest wall as a prior on its heading (WallAttitudeParams).
    walls: WallAttitudeParams = WallAttitudeParams()


@dataclass(kw_only=True)
class BundleOutput:
    T_world_kf: list[np.ndarray]
    landmarks: np.ndarray  # (P, 3) world
    descriptors: np.ndarray  # (P, 128) uint8 (SIFT), of each landmark's first observation
    obs: Observations  # camera = keyframe, point = landmark (undistorted pixels)
    rmse_px: float
    sigma_px: float
    initial_error: float
    final_error: float
    iterations: int
    dropped: int  # observations removed as outliers
    left_out: int  # observations over params.max_observations (select_landmarks)
    velocities: dict[int, np.ndarray]  # keyframe -> world velocity [m/s] (IMU factors only)
    biases: dict[int, np.ndarray]  # keyframe -> (accelerometer, gyro) bias, IMU frame (IMU factors only)


def depth_sigma(z: np.ndarray, params: BundleParams) -> np.ndarray:
    return params.depth_sigma_a_m + params.depth_sigma_b * (np.asarray(z) - 0.4) ** 2


def landmarks_from_tracks(
    tracks: Tracks,
    features: list[KeyframeFeatures],
    T_world_kf: list[np.ndarray],
    K: np.ndarray,
    params: BundleParams = BundleParams(),
):
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


def select_landmarks(landmark: np.ndarray, keyframe: np.ndarray, budget: int) -> np.ndarray:
    """Which landmarks to keep (bool per landmark) so that their observations fit the
    budget: every keyframe ranks the landmarks it sees by track length (the longest tie
    keyframes furthest apart, loops included), and a landmark stays if it is among the
    first q of any of its keyframes, q the largest that fits. Keyframes keep an equal
    share, so none is left hanging on its pose-graph edges alone."""
    n = int(landmark.max()) + 1 if len(landmark) else 0
    if budget <= 0 or len(landmark) <= budget:
        return np.ones(n, bool)
    length = np.bincount(landmark, minlength=n)
    order = np.lexsort((landmark, -length[landmark], keyframe))  # per keyframe, longest tracks first
    first = np.searchsorted(keyframe[order], keyframe[order])  # start of each keyframe's run
    rank = np.empty(len(landmark), int)
    rank[order] = np.arange(len(order)) - first
    best = np.full(n, np.iinfo(int).max)
    np.minimum.at(best, landmark, rank)  # a landmark's best rank in any keyframe
    lo, hi = 0, int(rank.max()) + 1  # observations kept at q = lo fit, at q = hi do not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if length[best < mid].sum() <= budget else (lo, mid)
    return best < lo


def edge_factor(edge: OdometryEdge, params: BundleParams) -> gtsam.BetweenFactorPose3:
    """A pose-graph edge as a GTSAM between factor. Open3D's information is for a
    perturbation of T_target_source on the left (in the target's frame), GTSAM's
    between error is on the right: info = Ad_T^T info_left Ad_T."""
    T = pose3(edge.T_target_source)
    Ad = T.AdjointMap()
    info = Ad.T @ (edge.information * params.edge_information_scale) @ Ad
    model = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(params.edge_huber_k),
        gtsam.noiseModel.Gaussian.Information(0.5 * (info + info.T)),
    )
    return gtsam.BetweenFactorPose3(X(edge.target), X(edge.source), T, model)


def gauge_model(
    T0: np.ndarray, up_odom: np.ndarray | None = None, tilt_deg: float = 0.0, turn_deg: float = 0.0
) -> gtsam.noiseModel.Base:
    """The first keyframe's prior: fixed; with a vertical from other factors (``up_odom``:
    the IMU's gravity, the keyframes' floor) free to tilt by ``tilt_deg`` about the axes
    across it, so that those factors set the vertical rather than the first keyframe's
    pose (the IMU's initial guess of gravity, off by the accelerometer bias: ~0.5 deg; a
    first keyframe tracked before the floor came into view); with a heading from other
    factors (the keyframes' walls) free to turn by ``turn_deg`` about it too."""
    if up_odom is None:
        return gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)
    u = np.asarray(up_odom, float)
    tilt, turn = max(np.radians(tilt_deg), FIXED_SIGMA), max(np.radians(turn_deg), FIXED_SIGMA)
    rot_nav = tilt**2 * (np.eye(3) - np.outer(u, u)) + turn**2 * np.outer(u, u)
    R = T0[:3, :3]  # tangent perturbations are in the keyframe's frame
    cov = np.zeros((6, 6))
    cov[:3, :3] = R.T @ rot_nav @ R
    cov[3:, 3:] = FIXED_SIGMA**2 * np.eye(3)
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def add_inertial(graph, values, T_world_kf: list[np.ndarray], inertial: InertialTerms, previous=None) -> None:
    """CombinedImuFactor between each pair of consecutive keyframes the IMU covers;
    velocities start from the keyframe positions' differences, biases from the
    terms' estimate (or ``previous`` values), with a prior where each chain starts."""
    nodes = sorted({i for i in inertial.between} | {i + 1 for i in inertial.between})
    t = inertial.stamps_s
    for i in nodes:
        lo, hi = (i - 1 if i - 1 in nodes else i), (i + 1 if i + 1 in nodes else i)
        v = (T_world_kf[hi][:3, 3] - T_world_kf[lo][:3, 3]) / max(t[hi] - t[lo], 1e-3)
        if previous is not None and previous.exists(V(i)):
            values.insert(V(i), previous.atVector(V(i)))
            values.insert(B(i), previous.atConstantBias(B(i)))
        else:
            values.insert(V(i), v)
            values.insert(B(i), inertial.bias)
        if i - 1 not in inertial.between:
            graph.add(gtsam.PriorFactorConstantBias(B(i), inertial.bias, inertial.bias_prior))
    for i, pim in inertial.between.items():
        graph.add(gtsam.CombinedImuFactor(X(i), V(i), X(i + 1), V(i + 1), B(i), B(i + 1), pim))


@dataclass(kw_only=True)
class BundleProblem:
    """What the adjustment takes from the tracks and keyframe features: each kept
    observation's landmark, keyframe, undistorted pixel and depth, the landmarks' initial
    positions and descriptors. The features (a 25-minute floor's: 0.32 GB, its matches
    0.05 GB) can go before the solve."""

    landmark: np.ndarray  # (M,) per observation
    keyframe: np.ndarray  # (M,)
    uv: np.ndarray  # (M, 2) undistorted pixels
    depth: np.ndarray  # (M,) metres, NaN without
    points: np.ndarray  # (P, 3) world, initial
    descriptors: np.ndarray  # (P, 128) uint8, of each landmark's first observation
    left_out: int  # observations over params.max_observations

    @classmethod
    def from_tracks(
        cls,
        tracks: Tracks,
        features: list[KeyframeFeatures],
        T_world_kf: list[np.ndarray],
        K: np.ndarray,
        params: BundleParams = BundleParams(),
    ) -> "BundleProblem":
        lm, points, kf, feat, uv, depth = landmarks_from_tracks(tracks, features, T_world_kf, K, params)
        kept = select_landmarks(lm, kf, params.max_observations)
        left_out = int((~kept[lm]).sum())
        if left_out:
            sel = kept[lm]
            lm, points, kf, feat, uv, depth = (
                np.cumsum(kept)[lm[sel]] - 1,
                points[kept],
                kf[sel],
                feat[sel],
                uv[sel],
                depth[sel],
            )
        descriptors = np.zeros((len(points), 128), np.uint8)
        first = np.unique(lm, return_index=True)[1]
        for i in first:
            descriptors[lm[i]] = features[kf[i]].descriptors[feat[i]]
        return cls(
            landmark=lm,
            keyframe=kf,
            uv=uv,
            depth=depth,
            points=points,
            descriptors=descriptors,
            left_out=left_out,
        )


def bundle_adjust(
    tracks: Tracks,
    features: list[KeyframeFeatures],
    T_world_kf: list[np.ndarray],
    camera: CameraModel,
    params: BundleParams = BundleParams(),
    edges: list[OdometryEdge] = (),
    inertial: InertialTerms | None = None,
    floor: FloorAttitudes | None = None,
    walls: WallAttitudes | None = None,
) -> BundleOutput:
    """Refine keyframe poses and landmarks; `camera` is the undistorted pinhole.
    ``edges``: the pose graph's (with ``params.pose_graph_factors``); ``inertial``:
    preintegrated IMU between consecutive keyframes; ``floor`` / ``walls``: each keyframe's
    view of the floor / its largest wall."""
    return solve_bundle(
        BundleProblem.from_tracks(tracks, features, T_world_kf, camera.K, params),
        T_world_kf,
        camera,
        params,
        edges,
        inertial,
        floor,
        walls,
    )


def solve_bundle(
    problem: BundleProblem,
    T_world_kf: list[np.ndarray],
    camera: CameraModel,
    params: BundleParams = BundleParams(),
    edges: list[OdometryEdge] = (),
    inertial: InertialTerms | None = None,
    floor: FloorAttitudes | None = None,
    walls: WallAttitudes | None = None,
) -> BundleOutput:
    """bundle_adjust on a BundleProblem; ``floor``: the keyframes' views of the floor, each an
    attitude factor (GTSAM's AttitudeFactorPose3, Huber) towards the up direction they share;
    ``walls``: their largest walls, each one towards the building's axis it belongs to."""
    depth = problem.depth
    cameras = [camera] * len(T_world_kf)
    obs = Observations(problem.keyframe, problem.landmark, problem.uv, np.full(len(problem.keyframe), params.sigma_px))
    ranges = depth * _ray_lengths(problem.uv, camera.K)  # camera centre -> point distance
    vertical = _gauge_vertical(params, inertial, floor, walls)
    T, P = list(T_world_kf), problem.points
    sigma, dropped, keep = params.sigma_px, 0, np.ones(len(obs.camera), bool)
    initial_error = final_error = 0.0
    iterations = 0
    result = None
    for rnd in range(params.rounds):
        if rnd > 0:
            sigma, dropped, keep = _drop_outliers(cameras, T, P, obs, keep, params)
        current = _kept(obs, keep, sigma)
        graph, values = _projection_graph(current, cameras, T, P, vertical, params)
        _add_range_factors(graph, obs, keep, ranges, depth, params)
        if params.pose_graph_factors:
            for e in edges:
                graph.add(edge_factor(e, params))
        if inertial is not None and inertial.between:
            add_inertial(graph, values, T, inertial, result)
        _add_attitude_factors(graph, floor, walls, params)
        result, e0, e1, its = optimize(graph, values, params.max_iterations)
        if rnd == 0:
            initial_error = e0
        final_error, iterations = e1, iterations + its
        T, P = _solved_states(result, len(T), P, current)
    res = reprojection_residuals(cameras, T, P, obs)[keep]
    velocities, biases = _imu_states(result, inertial)
    return BundleOutput(
        T_world_kf=T,
        landmarks=P,
        descriptors=problem.descriptors,
        obs=_kept(obs, keep, sigma),
        rmse_px=float(np.sqrt(np.nanmean(np.sum(res**2, axis=1)))) if len(res) else float("nan"),
        sigma_px=sigma,
        initial_error=initial_error,
        final_error=final_error,
        iterations=iterations,
        dropped=dropped,
        left_out=problem.left_out,
        velocities=velocities,
        biases=biases,
    )


def _ray_lengths(uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Length of each undistorted pixel's ray at unit depth: range = depth x this."""
    return np.linalg.norm(np.column_stack([(uv - K[:2, 2]) / np.diag(K)[:2], np.ones(len(uv))]), axis=1)


def _gauge_vertical(
    params: BundleParams,
    inertial: InertialTerms | None,
    floor: FloorAttitudes | None,
    walls: WallAttitudes | None,
) -> tuple:
    """gauge_model's arguments after the first pose: the vertical the other factors set (the
    IMU's gravity, else the floor's, else the walls'), and the turn the walls allow."""
    vertical = (
        (inertial.up_odom, inertial.tilt_prior_deg)
        if inertial is not None and inertial.between
        else (floor.up_odom, params.floor.tilt_prior_deg)
        if floor is not None
        else (walls.up_odom, 0.0)
        if walls is not None
        else ()
    )
    if walls is not None:
        vertical += (params.walls.turn_prior_deg,)
    return vertical


def _kept(obs: Observations, keep: np.ndarray, sigma: float) -> Observations:
    """The observations still kept, all with the pixel sigma ``sigma``."""
    return Observations(obs.camera[keep], obs.point[keep], obs.uv[keep], np.full(int(keep.sum()), sigma))


def _drop_outliers(
    cameras: list[CameraModel],
    T: list[np.ndarray],
    P: np.ndarray,
    obs: Observations,
    keep: np.ndarray,
    params: BundleParams,
) -> tuple[float, int, np.ndarray]:
    """Between rounds: the pixel sigma re-estimated from the kept residuals (MAD), the
    observations beyond ``params.outlier_k`` of it dropped. Returns (sigma, observations
    dropped, what is kept now)."""
    res = reprojection_residuals(cameras, T, P, obs)
    sigma = max(robust_sigma(res[keep]), 0.1)
    bad = ~np.isfinite(res).all(axis=1) | (np.linalg.norm(res, axis=1) > params.outlier_k * sigma)
    return sigma, int((keep & bad).sum()), keep & ~bad


def _projection_graph(
    current: Observations,
    cameras: list[CameraModel],
    T: list[np.ndarray],
    P: np.ndarray,
    vertical: tuple,
    params: BundleParams,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """A round's graph and initial values: the keyframe poses (the first's gauge prior), the
    observed landmarks and the projection factors of the ``current`` observations."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, Ti in enumerate(T):
        values.insert(X(i), pose3(Ti))
    graph.add(gtsam.PriorFactorPose3(X(0), pose3(T[0]), gauge_model(T[0], *vertical)))
    for j in np.unique(current.point):
        values.insert(L(int(j)), gtsam.Point3(*P[j]))
    add_projection_factors(graph, current, cameras, X, L, params.huber_k)
    return graph, values


def _add_range_factors(
    graph: gtsam.NonlinearFactorGraph,
    obs: Observations,
    keep: np.ndarray,
    ranges: np.ndarray,
    depth: np.ndarray,
    params: BundleParams,
) -> None:
    """A Huber-robust range factor per kept observation with depth (sigma: depth_sigma)."""
    huber = gtsam.noiseModel.mEstimator.Huber.Create(params.huber_k)
    has = keep & np.isfinite(ranges)
    # Range sigmas on a 0.5 mm grid share their noise models.
    sigmas = np.maximum(np.round(depth_sigma(depth[has], params) / 5e-4), 1) * 5e-4
    models = {
        s: gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(1, float(s)))
        for s in np.unique(sigmas)
    }
    for c, j, r, s in zip(obs.camera[has], obs.point[has], ranges[has], sigmas):
        graph.add(gtsam.RangeFactor3D(X(int(c)), L(int(j)), float(r), models[s]))


def _add_attitude_factors(
    graph: gtsam.NonlinearFactorGraph,
    floor: FloorAttitudes | None,
    walls: WallAttitudes | None,
    params: BundleParams,
) -> None:
    """Huber-robust attitude factors: each keyframe's floor normal towards the shared up
    direction, each one's wall normal towards the building's axis it belongs to."""
    huber = gtsam.noiseModel.mEstimator.Huber.Create(params.huber_k)
    if floor is not None:
        tilt = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Isotropic.Sigma(2, float(np.radians(params.floor.sigma_deg)))
        )
        for i, n in floor.normals.items():
            graph.add(gtsam.AttitudeFactorPose3(X(i), gtsam.Unit3(floor.up_odom), tilt, gtsam.Unit3(n)))
    if walls is not None:
        turn = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Isotropic.Sigma(2, float(np.radians(params.walls.sigma_deg)))
        )
        for i, (n, axis) in walls.walls.items():
            graph.add(gtsam.AttitudeFactorPose3(X(i), gtsam.Unit3(axis), turn, gtsam.Unit3(n)))


def _solved_states(
    result: gtsam.Values, n_keyframes: int, P: np.ndarray, current: Observations
) -> tuple[list[np.ndarray], np.ndarray]:
    """The keyframe poses and landmarks of a round's solution (landmarks it did not see as they were)."""
    T = [result.atPose3(X(i)).matrix() for i in range(n_keyframes)]
    P = P.copy()
    for j in np.unique(current.point):
        P[j] = result.atPoint3(L(int(j)))
    return T, P


def _imu_states(
    result: gtsam.Values | None, inertial: InertialTerms | None
) -> tuple[dict[int, np.ndarray], dict[int, np.ndarray]]:
    """Each IMU-joined keyframe's velocity and (accelerometer, gyro) bias in the solution."""
    velocities, biases = {}, {}
    if inertial is not None and result is not None:
        for i in sorted({i for i in inertial.between} | {i + 1 for i in inertial.between}):
            velocities[i] = np.asarray(result.atVector(V(i)))
            b = result.atConstantBias(B(i))
            biases[i] = np.concatenate([b.accelerometer(), b.gyroscope()])
    return velocities, biases
