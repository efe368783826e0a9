"""Visual refinement of the multiway registration's keyframes (paper "Ego-camera
Processing"): SIFT matches of every registered keyframe pair, filtered (epipolar and depth
consistency), joined into tracks, then the bundle adjustment (eq. ego_bd) with the pose
graph's edges, the IMU and, without it, the floor's and walls' attitudes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from yowo_common.camera import CameraModel
from yowo_common.memory import release_free_memory

from .config import EgoParams
from .feature_tracks import build_tracks, filter_matches
from .features import KeyframeFeatures
from .imu import InertialTerms
from .odometry import Keyframe
from .posegraph import MultiwayResult
from .refine import BundleOutput, BundleProblem, solve_bundle
from .scene import FloorAttitudes, WallAttitudes, floor_attitudes, up_from_cameras, wall_attitudes

MIN_TRACKS = 10  # fewer feature tracks than this: no bundle adjustment


@dataclass(kw_only=True)
class SceneMap:
    """Landmarks (odometry frame) with descriptors and undistorted observations."""

    landmarks: np.ndarray
    descriptors: np.ndarray
    obs_keyframe: np.ndarray
    obs_landmark: np.ndarray
    obs_uv: np.ndarray

    @staticmethod
    def empty() -> "SceneMap":
        return SceneMap(
            landmarks=np.zeros((0, 3)),
            descriptors=np.zeros((0, 128), np.uint8),
            obs_keyframe=np.zeros(0, int),
            obs_landmark=np.zeros(0, int),
            obs_uv=np.zeros((0, 2)),
        )


def refine_keyframes(
    mw: MultiwayResult,
    features: list[KeyframeFeatures],
    keyframes: list[Keyframe],
    T_kf: list[np.ndarray],
    ideal: CameraModel,
    K_odometry: np.ndarray,
    params: EgoParams,
    stats: dict,
    warnings: list[str],
    inertial: InertialTerms | None = None,
) -> tuple[list[np.ndarray], SceneMap, np.ndarray | None, np.ndarray]:
    """Visual refinement: filtered matches of every registered keyframe pair ->
    tracks -> bundle adjustment (with the pose graph's edges and ``inertial``).
    Returns the refined keyframe poses, the map, the up direction of the IMU
    factors' gravity (None when none entered) and which keyframes had their heading
    held to the building's walls."""
    p, K = params, ideal.K
    accepted = _filtered_matches(mw, features, T_kf, K, p, stats)
    tracks = build_tracks(accepted, [len(f) for f in features])
    stats["tracks"] = tracks.count
    if tracks.count < MIN_TRACKS:
        warnings.append(f"only {tracks.count} feature tracks survived the filters; bundle adjustment skipped")
        return T_kf, SceneMap.empty(), None, np.zeros(len(T_kf), bool)
    problem = BundleProblem.from_tracks(tracks, features, T_kf, K, p.bundle)
    # Nothing after reads the features or the matches: they go before the solve's GBs come.
    features.clear()
    mw.pairs.clear()
    del tracks, accepted
    release_free_memory()
    floor, walls = _attitudes(keyframes, T_kf, K_odometry, p, stats, inertial)
    ba = solve_bundle(problem, T_kf, ideal, p.bundle, mw.edges, inertial, floor, walls)
    # Its factor graph's memory (gigabytes on a long floor) back before the cloud is fused.
    release_free_memory()
    return (
        ba.T_world_kf,
        _scene_map(ba, stats),
        inertial.up_odom if inertial is not None and inertial.between else None,
        np.isin(np.arange(len(T_kf)), list(walls.walls) if walls is not None else []),
    )


def _filtered_matches(
    mw: MultiwayResult,
    features: list[KeyframeFeatures],
    T_kf: list[np.ndarray],
    K: np.ndarray,
    params: EgoParams,
    stats: dict,
) -> list[tuple[int, int, np.ndarray]]:
    """Each registered pair's matches that pass the epipolar and depth-consistency filters,
    as (keyframe a, keyframe b, feature index pairs); the counts go into ``stats``."""
    accepted, n_matches, n_epi, n_depth = [], 0, 0, 0
    for pair in mw.pairs:
        fa, fb = features[pair.a], features[pair.b]
        m = pair.matches
        res = filter_matches(
            fa.uv[m[:, 0]],
            fb.uv[m[:, 1]],
            fa.depth[m[:, 0]],
            fb.depth[m[:, 1]],
            T_kf[pair.a],
            T_kf[pair.b],
            K,
            params.filter,
        )
        accepted.append((pair.a, pair.b, m[res.keep]))
        n_matches += len(m)
        n_epi += res.epipolar_rejected
        n_depth += res.depth_rejected
    stats.update(matches=n_matches, epipolar_rejected=n_epi, depth_rejected=n_depth)
    return accepted


def _attitudes(
    keyframes: list[Keyframe],
    T_kf: list[np.ndarray],
    K_odometry: np.ndarray,
    params: EgoParams,
    stats: dict,
    inertial: InertialTerms | None,
) -> tuple[FloorAttitudes | None, WallAttitudes | None]:
    """Without the IMU's factors (and where enabled): each keyframe's view of the floor and
    its largest wall, for the bundle adjustment's attitude factors."""
    p = params
    floor = walls = None
    if inertial is None and p.bundle.floor.enabled:
        floor = floor_attitudes(keyframes, T_kf, K_odometry, p.bundle.floor)
        stats["floor_attitudes"] = len(floor.normals) if floor is not None else 0
    if inertial is None and p.bundle.walls.enabled:
        up = floor.up_odom if floor is not None else up_from_cameras(T_kf)
        walls = wall_attitudes(keyframes, T_kf, K_odometry, up, p.bundle.walls)
        stats["wall_attitudes"] = len(walls.walls) if walls is not None else 0
    return floor, walls


def _scene_map(ba: BundleOutput, stats: dict) -> SceneMap:
    """The adjusted landmarks that kept at least two observations after outlier removal,
    and the adjustment's figures into ``stats``."""
    counts = np.bincount(ba.obs.point, minlength=len(ba.landmarks))
    keep = counts >= 2
    remap = np.cumsum(keep) - 1
    sel = keep[ba.obs.point]
    stats.update(
        landmarks=int(keep.sum()),
        observations=int(sel.sum()),
        bundle_rmse_px=ba.rmse_px,
        bundle_sigma_px=ba.sigma_px,
        bundle_dropped=ba.dropped,
        bundle_left_out=ba.left_out,
        bundle_iterations=ba.iterations,
    )
    if ba.biases:
        b = np.array(list(ba.biases.values()))
        stats.update(
            imu_accel_bias_mps2=float(np.linalg.norm(b[:, :3], axis=1).mean()),
            imu_gyro_bias_dps=float(np.degrees(np.linalg.norm(b[:, 3:], axis=1).mean())),
        )
    return SceneMap(
        landmarks=ba.landmarks[keep],
        descriptors=ba.descriptors[keep],
        obs_keyframe=ba.obs.camera[sel],
        obs_landmark=remap[ba.obs.point[sel]],
        obs_uv=ba.obs.uv[sel],
    )
