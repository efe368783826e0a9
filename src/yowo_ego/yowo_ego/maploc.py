"""Relocalisation of a lost frame in the map around it, by its depth (our addition:
the paper's tracking has none; issue #18's walks without an IMU).

A whip turn of the head (600+ deg/s at 15 Hz) along bare or dark walls leaves dense
odometry and features nothing to match between consecutive frames, yet the room
around the walker has been seen: the frame's depth fits the recent keyframes' depth
clouds at one heading. The walker cannot have moved far since the previous frame and
turns about the vertical, so the search is over the heading alone at the previous
frame's position (the vertical from the map's horizontal surfaces: floor, ceiling,
tables), then point-to-plane ICP from the best headings. A pose is accepted only when
it fits well, stays within reach of the previous frame, and fits clearly better than
any other heading that does: a box-shaped room offers look-alike headings 90 or 180
deg apart."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from yowo_common.geometry import rotation_angle_deg, se3

_reg = o3d.pipelines.registration


@dataclass(frozen=True)
class MapLocParams:
    enabled: bool = True  # place a frame no attempt tracks in the map of the recent keyframes by its depth
    keyframes: int = 60  # most recent keyframes of the current chain that form the map [count]
    pixel_step: int = 4  # every pixel_step-th pixel (each way) of the odometry depth enters the clouds [px]
    voxel_m: float = 0.04  # voxel size of the map's and the frame's clouds
    heading_step_deg: float = 3.0  # step of the scan over the heading about the vertical
    inlier_m: float = 0.15  # heading scan: a frame point this close to the map fits
    candidates: int = 4  # best headings (local maxima of the scan) refined by ICP [count]
    icp_distances_m: tuple[float, ...] = (0.15, 0.08, 0.04)  # point-to-plane ICP's correspondence distances, in turn
    icp_iterations: int = 20  # ICP iterations per correspondence distance at most [count]
    min_fitness: float = 0.8  # share of the frame's points within the finest ICP distance [share]
    # Fitness margin over the best other heading (more than distinct_deg away) that stays within reach [share].
    min_margin: float = 0.1
    distinct_deg: float = 10.0  # headings further apart than this are other headings (min_margin)
    reach_margin_m: float = 0.1  # reach beyond odometry.max_speed_mps x the time since the previous frame
    horizontal_deg: float = 25.0  # surface normals this close to the cameras' mean down: horizontal
    sigma_deg: float = 1.0  # rotation sigma of the "map" edge to the previous keyframe
    sigma_m: float = 0.03  # translation sigma of the "map" edge to the previous keyframe


@dataclass
class MapLocResult:
    T_odom_cam: np.ndarray | None  # None: not relocalised (see reason)
    fitness: float = 0.0
    margin: float = 0.0
    reason: str = ""


def depth_points(depth_mm: np.ndarray, K: np.ndarray, step: int) -> np.ndarray:
    """(N, 3) camera-frame points of every step-th pixel with depth."""
    z = depth_mm[::step, ::step].astype(float) / 1000.0
    v, u = np.mgrid[0 : depth_mm.shape[0] : step, 0 : depth_mm.shape[1] : step].astype(float)
    ok = z > 0
    return np.column_stack([(u[ok] - K[0, 2]) / K[0, 0] * z[ok], (v[ok] - K[1, 2]) / K[1, 1] * z[ok], z[ok]])


def _cloud(points: np.ndarray, params: MapLocParams) -> o3d.geometry.PointCloud:
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(params.voxel_m)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * params.voxel_m, max_nn=30))
    return cloud


def map_cloud(
    depths_mm: list[np.ndarray], T_odom_cams: list[np.ndarray], K: np.ndarray, params: MapLocParams
) -> o3d.geometry.PointCloud:
    """The keyframes' depth in the odometry frame, voxel-filtered, with normals."""
    points = [depth_points(d, K, params.pixel_step) @ T[:3, :3].T + T[:3, 3] for d, T in zip(depths_mm, T_odom_cams)]
    return _cloud(np.vstack(points) if points else np.zeros((0, 3)), params)


def up_direction(cloud: o3d.geometry.PointCloud, T_odom_cams: list[np.ndarray], params: MapLocParams) -> np.ndarray:
    """The vertical in the odometry frame: the mean normal of the map's horizontal
    surfaces (those within horizontal_deg of the cameras' mean down direction; a
    head-mounted camera's image y axis points roughly down), that mean down direction
    alone where the map has none."""
    down = np.mean([T[:3, 1] for T in T_odom_cams], axis=0)
    down /= np.linalg.norm(down)
    normals = np.asarray(cloud.normals)
    flat = normals[np.abs(normals @ down) >= np.cos(np.radians(params.horizontal_deg))]
    if len(flat) < 100:
        return -down
    w, v = np.linalg.eigh(flat.T @ flat)
    up = v[:, -1]
    return up if up @ down < 0 else -up


def relocalise(
    depth_mm: np.ndarray,
    K: np.ndarray,
    cloud: o3d.geometry.PointCloud,
    up: np.ndarray,
    T_odom_prev: np.ndarray,
    max_move_m: float,
    params: MapLocParams,
) -> MapLocResult:
    """The frame's pose in the map: heading scan about `up` at the previous frame's
    position, ICP from the best headings, the best one that stays within max_move_m of
    the previous frame if it fits well and clearly better than any other heading."""
    if len(cloud.points) < 100:
        return MapLocResult(None, reason=f"the map has {len(cloud.points)} points")
    frame = _cloud(depth_points(depth_mm, K, params.pixel_step), params)
    source = np.asarray(frame.points)
    if len(source) < 100:
        return MapLocResult(None, reason=f"the frame has {len(source)} points with depth")
    tree = cKDTree(np.asarray(cloud.points))
    headings = np.radians(np.arange(0.0, 360.0, params.heading_step_deg))
    R_prev, t_prev = T_odom_prev[:3, :3], T_odom_prev[:3, 3]
    turns = Rotation.from_rotvec(headings[:, None] * up[None, :]).as_matrix()
    world = np.einsum("hij,jk,nk->hni", turns, R_prev, source) + t_prev
    dist, _ = tree.query(world.reshape(-1, 3), distance_upper_bound=params.inlier_m)
    score = (dist.reshape(len(headings), -1) < params.inlier_m).mean(axis=1)
    peaks = [
        k
        for k in range(len(score))
        if score[k] >= score[k - 1] and score[k] >= score[(k + 1) % len(score)] and score[k] > 0
    ]
    peaks = sorted(peaks, key=lambda k: -score[k])[: params.candidates]
    fits = []
    for k in peaks:
        T = se3(turns[k] @ R_prev, t_prev)
        for distance in params.icp_distances_m:
            result = _reg.registration_icp(
                frame,
                cloud,
                distance,
                T,
                _reg.TransformationEstimationPointToPlane(),
                _reg.ICPConvergenceCriteria(max_iteration=params.icp_iterations),
            )
            T = np.asarray(result.transformation)
        if np.linalg.norm(T[:3, 3] - t_prev) <= max_move_m:
            fits.append((result.fitness, T))
    if not fits:
        return MapLocResult(None, reason=f"no heading fits within {max_move_m:.2f} m of the previous frame")
    fits.sort(key=lambda f: -f[0])
    fitness, T = fits[0]
    others = [f for f, T2 in fits[1:] if rotation_angle_deg(T[:3, :3], T2[:3, :3]) > params.distinct_deg]
    margin = fitness - max(others, default=0.0)
    if fitness < params.min_fitness:
        return MapLocResult(None, fitness, margin, f"best fit {fitness:.2f} < {params.min_fitness:g}")
    if margin < params.min_margin:
        return MapLocResult(None, fitness, margin, f"another heading fits almost as well ({margin:.2f} better)")
    return MapLocResult(T, fitness, margin)
