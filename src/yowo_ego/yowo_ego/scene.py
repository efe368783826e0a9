"""Point cloud from the optimised keyframe poses (TSDF fusion), planar patches
(Open3D ``detect_planar_patches``, the detector the paper cites), the ground
plane and the vertical rectification R_rect (paper eq. rot_gp2w).

Ground plane: the paper takes the plane with the most points. That can be a
large wall, and the patch detector splits the floor into many pieces, so here:
the direction is the normal of the largest patch within ``floor_max_tilt_deg``
of the up direction a head-worn camera suggests (the mean of the keyframes'
image-up axes); the floor is the most populated height level, below the
cameras, of the cloud points facing that way; its plane is then re-fitted to
all of those points (every room shares one floor). Patch normals have no
consistent sign, so they are oriented like the points' own normals, which face
the nearest camera.

World frame (REP 103, z up): R_rect turns the floor normal onto +z; the origin
is the first ego camera centre projected onto the floor, so the floor is z = 0;
world +x is the first camera's viewing direction projected onto the floor (the
agent's initial heading, as a body frame's x would be).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from yowo_common.geometry import inv_se3, rotation_aligning, se3, transform_points

from .degeneracy import depth_points
from .odometry import Keyframe


@dataclass(frozen=True)
class CloudParams:
    voxel_m: float = 0.03  # voxel size of the TSDF the keyframes are fused into
    block_resolution: int = 8  # voxels along a TSDF block's side [count]
    depth_max_m: float = 5.0  # depth beyond which a pixel is not fused
    trunc_voxels: float = 4.0  # the TSDF's truncation distance [voxels]
    min_weight: float = 2.0  # TSDF surface points seen fewer times are dropped [views]
    plane_voxel_m: float = 0.06  # cloud resolution for plane detection
    plane_min_points: int = 60  # points a planar patch needs at least [count]
    plane_min_edge_m: float = 0.4  # a planar patch's shortest edge at least
    patch_normal_cos: float = 0.94  # a point belongs to a patch when its normal is within 20 deg [cos]
    floor_bin_m: float = 0.02  # bin of the height histogram of upward-facing points
    floor_max_tilt_deg: float = 35.0  # floor candidates: patches whose normal is this close to the up guess
    floor_below_camera_m: float = 0.5  # floor candidates: points this far below the cameras' median height at least
    floor_refit_band_m: float = 0.04  # the floor plane is refit to the upward-facing points this close to its level


@dataclass(kw_only=True)
class PlanarPatch:
    normal: np.ndarray  # unit, facing the side the cameras saw
    center: np.ndarray
    d: float  # n . p + d = 0
    corners: np.ndarray  # (4, 3) patch rectangle
    num_points: int

    def transformed(self, T: np.ndarray) -> "PlanarPatch":
        n = T[:3, :3] @ self.normal
        c = transform_points(T, self.center)[0]
        return PlanarPatch(
            normal=n, center=c, d=float(-n @ c), corners=transform_points(T, self.corners), num_points=self.num_points
        )


@dataclass(kw_only=True)
class Rectification:
    T_world_odom: np.ndarray  # applied to every pose, landmark and cloud point
    R_rect: np.ndarray  # eq. rot_gp2w (before the heading turn)
    floor_normal_odom: np.ndarray  # v_gp
    floor_points: int
    camera_height_m: float  # first camera centre above the floor


def fuse_cloud(
    keyframes: list[Keyframe], T_odom_kf: list[np.ndarray], K_small: np.ndarray, params: CloudParams = CloudParams()
) -> tuple[np.ndarray, np.ndarray]:
    """TSDF-fuse the keyframes' (downsampled) RGB-D images; returns surface
    points (N, 3) and colours (N, 3) in [0, 1], in the frame of the poses."""
    vbg = o3d.t.geometry.VoxelBlockGrid(
        ("tsdf", "weight", "color"),
        (o3d.core.float32, o3d.core.float32, o3d.core.float32),
        ((1), (1), (3)),
        params.voxel_m,
        params.block_resolution,
        20000,
    )
    K = o3d.core.Tensor(K_small)
    for kf, T in zip(keyframes, T_odom_kf):
        depth = o3d.t.geometry.Image(o3d.core.Tensor(kf.depth_mm))
        color = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(kf.color)))
        extrinsic = o3d.core.Tensor(inv_se3(T))
        coords = vbg.compute_unique_block_coordinates(
            depth, K, extrinsic, 1000.0, params.depth_max_m, params.trunc_voxels
        )
        vbg.integrate(coords, depth, color, K, extrinsic, 1000.0, params.depth_max_m, params.trunc_voxels)
    pcd = vbg.extract_point_cloud(weight_threshold=params.min_weight)
    if "positions" not in pcd.point or len(pcd.point.positions) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    colors = pcd.point.colors.numpy().astype(float)
    if colors.size and colors.max() > 1.0:  # uint8 input keeps the 0..255 range
        colors /= 255.0
    return pcd.point.positions.numpy().astype(float), np.clip(colors, 0.0, 1.0)


def planar_patches(
    points: np.ndarray, cameras: np.ndarray, params: CloudParams = CloudParams()
) -> tuple[list[PlanarPatch], np.ndarray, np.ndarray]:
    """Planar patches of a (downsampled) cloud. Returns the patches, the
    downsampled points and their normals (oriented towards the nearest camera)."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(params.plane_voxel_m)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * params.plane_voxel_m, max_nn=30))
    pts = np.asarray(pcd.points)
    normals = np.asarray(pcd.normals)
    if len(pts) < params.plane_min_points:  # a walk of a few frames: no plane to find
        return [], pts, normals
    # Orient point normals towards the closest camera centre (the side it was seen from).
    nearest = cameras[cKDTree(cameras).query(pts)[1]]
    flip = np.einsum("ij,ij->i", normals, nearest - pts) < 0
    normals[flip] *= -1
    pcd.normals = o3d.utility.Vector3dVector(normals)
    boxes = pcd.detect_planar_patches(
        normal_variance_threshold_deg=60,
        coplanarity_deg=75,
        outlier_ratio=0.75,
        min_plane_edge_length=params.plane_min_edge_m,
        min_num_points=params.plane_min_points,
        search_param=o3d.geometry.KDTreeSearchParamKNN(knn=30),
    )
    patches = []
    for box in boxes:
        R = np.asarray(box.R)
        n = R[:, 2] / np.linalg.norm(R[:, 2])
        c = np.asarray(box.center)
        inside = np.asarray(box.get_point_indices_within_bounding_box(pcd.points), dtype=int)
        # A patch's box can be thick and hold other surfaces too (the floor's box
        # may reach the ceiling): its own points are those whose normal agrees,
        # and the plane sits at their median offset, not at the box centre.
        dots = normals[inside] @ n
        own = inside[np.abs(dots) >= params.patch_normal_cos]
        if len(own) == 0:
            continue
        if np.mean(normals[own] @ n) < 0:
            n = -n
        c = c + (np.median(pts[own] @ n) - c @ n) * n
        ext = np.asarray(box.extent)
        u, v = R[:, 0] * ext[0] / 2, R[:, 1] * ext[1] / 2
        corners = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
        patches.append(PlanarPatch(normal=n, center=c, d=float(-n @ c), corners=corners, num_points=len(own)))
    return patches, pts, normals


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centroid = points.mean(axis=0)
    _, _, Vt = np.linalg.svd(points - centroid, full_matrices=False)
    return Vt[2], centroid


def find_floor(
    patches: list[PlanarPatch],
    points: np.ndarray,
    normals: np.ndarray,
    cameras: np.ndarray,
    up_guess: np.ndarray,
    params: CloudParams = CloudParams(),
) -> tuple[np.ndarray, np.ndarray, int]:
    """(floor normal pointing up, a point on the floor, supporting points).

    The direction: the normal of the planar patch within ``floor_max_tilt_deg``
    of the up guess whose plane the most cloud points below the cameras lie on
    (facing its way): the floor continues through every room, while the patch
    detector splits it into pieces, so its largest single patch can be a table
    top or a slanted surface. The height: the most populated level, below the
    cameras, of the cloud points facing that way (a height histogram). Finally a
    plane fit to every upward-facing point near that level."""
    up_guess = up_guess / np.linalg.norm(up_guess)
    cos_tilt = np.cos(np.radians(params.floor_max_tilt_deg))
    horizontal = [(p.normal if p.normal @ up_guess > 0 else -p.normal, p.center) for p in patches]
    horizontal = [(n, c) for n, c in horizontal if n @ up_guess >= cos_tilt]
    if not horizontal:
        raise ValueError("no horizontal planar patch in the point cloud: cannot find the floor")

    def plane_support(n: np.ndarray, c: np.ndarray) -> int:
        on = (normals @ n >= params.patch_normal_cos) & (np.abs((points - c) @ n) <= 2 * params.floor_refit_band_m)
        return int(np.sum(on & (points @ n <= np.median(cameras @ n) - params.floor_below_camera_m)))

    n = max(horizontal, key=lambda t: plane_support(*t))[0]
    facing = normals @ n >= params.patch_normal_cos
    h = points[facing] @ n
    below = h <= np.median(cameras @ n) - params.floor_below_camera_m
    if below.sum() < 3:
        raise ValueError("no upward-facing surface below the cameras: cannot find the floor")
    counts, edges = np.histogram(
        h[below], bins=np.arange(h[below].min(), h[below].max() + 2 * params.floor_bin_m, params.floor_bin_m)
    )
    level = edges[np.argmax(counts)] + params.floor_bin_m / 2
    c, support = n * level, 0
    for band in (2 * params.floor_refit_band_m, params.floor_refit_band_m):
        near = facing & (np.abs((points - c) @ n) <= band)
        if near.sum() < 3:
            break
        support = int(near.sum())
        n_fit, c = _fit_plane(points[near])
        n = n_fit if n_fit @ n > 0 else -n_fit
    return n, c, support


def rectify(
    floor_normal: np.ndarray, floor_point: np.ndarray, T_odom_first: np.ndarray, support: int = 0
) -> Rectification:
    """T_world_odom: eq. rot_gp2w (floor normal -> +z), then the heading and
    origin conventions of the module docstring."""
    R_rect = rotation_aligning(floor_normal, [0.0, 0.0, 1.0])
    forward = R_rect @ T_odom_first[:3, 2]
    yaw = np.arctan2(forward[1], forward[0]) if np.hypot(forward[0], forward[1]) > 1e-6 else 0.0
    c, s = np.cos(-yaw), np.sin(-yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R_rect
    first = R @ T_odom_first[:3, 3]
    floor_z = float((R @ floor_point)[2])
    T = se3(R, [-first[0], -first[1], -floor_z])
    return Rectification(
        T_world_odom=T,
        R_rect=R_rect,
        floor_normal_odom=np.asarray(floor_normal, float),
        floor_points=support,
        camera_height_m=float(transform_points(T, T_odom_first[:3, 3])[0, 2]),
    )


def up_from_cameras(T_odom_cam: list[np.ndarray]) -> np.ndarray:
    """Mean image-up direction (-y of the optical frame) of a head-worn camera."""
    up = -np.mean([T[:3, 1] for T in T_odom_cam], axis=0)
    return up / np.linalg.norm(up)


@dataclass(frozen=True)
class FloorAttitudeParams:
    """Without an IMU, the floor each keyframe sees sets its tilt in the bundle adjustment
    (yowo_ego.refine): a building's floor is one plane, so a keyframe whose view of it
    leans against the map's floor was tracked with a tilt (bare walls let dense odometry
    tilt unseen). Not the paper's (an extension, like the IMU's gravity)."""

    enabled: bool = True  # without an IMU, hold each keyframe's tilt to the floor it sees
    sigma_deg: float = 1.0  # sigma of a keyframe's floor normal (a plane fit to its own depth)
    tilt_prior_deg: float = 5.0  # the map may tilt this much (the first keyframe's prior)
    below_camera_m: float = 0.8  # floor candidates: this far below the camera at least
    max_tilt_deg: float = 20.0  # floor candidates: normals this close to the up direction the keyframe's pose predicts
    distance_m: float = 0.02  # RANSAC inlier distance of the plane fit
    min_points: int = 1500  # inliers (of the 320x240 depth) for a keyframe to count [count]
    stride: int = 2  # every stride-th pixel each way [px]


def _plane(P: np.ndarray, distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(unit normal, inlier indices) of the largest plane through points P: Open3D's RANSAC,
    then least squares over its inliers."""
    _, inliers = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P)).segment_plane(distance_m, 3, 100)
    inliers = np.asarray(inliers, int)
    Q = P[inliers] - P[inliers].mean(axis=0)
    return np.linalg.svd(Q, full_matrices=False)[2][2], inliers


def floor_normal_in_view(
    depth_mm: np.ndarray, K: np.ndarray, up_cam: np.ndarray, params: FloorAttitudeParams = FloorAttitudeParams()
) -> np.ndarray | None:
    """The floor's upward normal in the camera frame from one depth image (intrinsics K),
    or None: a plane through the points at least ``below_camera_m`` under the camera
    (along ``up_cam``, the up direction the keyframe's pose predicts) within
    ``max_tilt_deg`` of it."""
    s = params.stride
    P, valid = depth_points(depth_mm, K, s)
    P = P[valid]
    P = P[P @ up_cam <= -params.below_camera_m]
    if len(P) < params.min_points // (s * s):
        return None
    o3d.utility.random.seed(0)  # the same recording gives the same map
    n, inliers = _plane(P, params.distance_m)
    if len(inliers) * s * s < params.min_points:
        return None
    n = n if n @ up_cam > 0 else -n
    return n if n @ up_cam >= np.cos(np.radians(params.max_tilt_deg)) else None


@dataclass
class FloorAttitudes:
    """The floor's up direction in the odometry frame (the keyframes' consensus) and each
    keyframe's own view of it (camera frame), by keyframe index."""

    up_odom: np.ndarray
    normals: dict[int, np.ndarray]


def floor_attitudes(
    keyframes: list[Keyframe],
    T_odom_kf: list[np.ndarray],
    K: np.ndarray,
    params: FloorAttitudeParams = FloorAttitudeParams(),
) -> FloorAttitudes | None:
    """The keyframes that see the floor (``floor_normal_in_view``, K of their depth images)
    and the up direction most of them agree on; None with fewer than three."""
    guess = up_from_cameras(T_odom_kf)
    normals = {}
    for i, (kf, T) in enumerate(zip(keyframes, T_odom_kf)):
        n = floor_normal_in_view(kf.depth_mm, K, T[:3, :3].T @ guess, params)
        if n is not None:
            normals[i] = n
    if len(normals) < 3:
        return None
    seen = np.array([T_odom_kf[i][:3, :3] @ n for i, n in normals.items()])
    up = seen.mean(axis=0)
    for _ in range(3):  # the majority: keyframes tracked with a tilt lean away from it
        up /= np.linalg.norm(up)
        near = seen @ up >= np.cos(np.radians(params.max_tilt_deg / 2))
        up = seen[near].mean(axis=0) if near.any() else up
    return FloorAttitudes(up / np.linalg.norm(up), normals)


@dataclass(frozen=True)
class WallAttitudeParams:
    """Without an IMU, the walls each keyframe sees set its heading in the bundle adjustment
    (yowo_ego.refine). Most buildings stand on two perpendicular horizontal axes (a Manhattan
    world), so a keyframe whose largest wall turns against the axes the map's walls share was
    tracked with a turn: dense odometry along bare walls turns by degrees where nothing else
    sees it, and neither the floor nor the agent track observes a turn about the vertical.
    Not the paper's (an extension, like the floor's tilt). Whether the building is one is seen
    within single views, whatever the tracking's turns: where a view holds two walls that are
    not parallel, they are perpendicular in at least ``min_share`` of such views; otherwise no
    keyframe gets one."""

    enabled: bool = True  # without an IMU, hold each keyframe's heading to the walls it sees
    sigma_deg: float = 1.0  # sigma of a keyframe's largest wall's normal (a plane fit to its own depth)
    turn_prior_deg: float = 5.0  # the map may turn this much (the first keyframe's prior)
    max_tilt_deg: float = 10.0  # a wall's normal from horizontal (across the up direction)
    max_turn_deg: float = 20.0  # a keyframe's wall from the nearest axis, as tracked
    perpendicular_deg: float = 5.0  # two walls of one view are perpendicular within this
    # Share of the views with two non-parallel walls in which they are perpendicular, for a
    # Manhattan building [share].
    min_share: float = 0.7
    min_corners: int = 3  # views holding two walls that are not parallel, at least [count]
    max_planes: int = 3  # planes tried per view, largest first [count]
    distance_m: float = 0.02  # RANSAC inlier distance of each plane fit
    min_points: int = 3000  # inliers (of the 320x240 depth) for a plane to count [count]
    stride: int = 2  # every stride-th pixel each way [px]


def wall_normals_in_view(
    depth_mm: np.ndarray, K: np.ndarray, up_cam: np.ndarray, params: WallAttitudeParams = WallAttitudeParams()
) -> list[np.ndarray]:
    """The normals (camera frame, either sign) of the walls in one depth image (intrinsics
    K), largest first: of up to ``max_planes`` planes (RANSAC, then least squares over its
    inliers, largest first) those whose normal lies within ``max_tilt_deg`` of horizontal
    (across ``up_cam``, the up direction the keyframe's pose predicts)."""
    s = params.stride
    P, valid = depth_points(depth_mm, K, s)
    P = P[valid]
    o3d.utility.random.seed(0)  # the same recording gives the same map
    walls = []
    for _ in range(params.max_planes):
        if len(P) * s * s < params.min_points:
            break
        n, inliers = _plane(P, params.distance_m)
        if len(inliers) * s * s < params.min_points:
            break
        if abs(n @ up_cam) <= np.sin(np.radians(params.max_tilt_deg)):
            walls.append(n)
        P = np.delete(P, inliers, axis=0)
    return walls


@dataclass
class WallAttitudes:
    """The building's horizontal axes in the odometry frame (the keyframes' walls' consensus:
    ``axis_odom`` and its turn by 90 deg about ``up_odom``) and, by keyframe index, each
    keyframe's largest wall (normal in the camera frame, the axis direction it belongs to in
    the odometry frame)."""

    up_odom: np.ndarray
    axis_odom: np.ndarray
    walls: dict[int, tuple[np.ndarray, np.ndarray]]


def _fold(angle: np.ndarray) -> np.ndarray:
    """An angle [rad] as the turn from the nearest multiple of 90 deg, in [-45, 45) deg."""
    return (angle + np.pi / 4) % (np.pi / 2) - np.pi / 4


def wall_attitudes(
    keyframes: list[Keyframe],
    T_odom_kf: list[np.ndarray],
    K: np.ndarray,
    up_odom: np.ndarray,
    params: WallAttitudeParams = WallAttitudeParams(),
) -> WallAttitudes | None:
    """The keyframes' walls (``wall_normals_in_view``, K of their depth images) and the two
    axes most of their largest walls agree on (mod 90 deg); None unless the building is a
    Manhattan world by its views' corners (``WallAttitudeParams``). Each largest wall within
    ``max_turn_deg`` of an axis, as tracked, belongs to it."""
    up = np.asarray(up_odom, float) / np.linalg.norm(up_odom)
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    largest, headings, corners = {}, [], []
    for i, (kf, T) in enumerate(zip(keyframes, T_odom_kf)):
        walls = wall_normals_in_view(kf.depth_mm, K, T[:3, :3].T @ up, params)
        if not walls:
            continue
        seen = np.array(walls) @ T[:3, :3].T
        h = np.arctan2(seen @ e2, seen @ e1)
        largest[i] = walls[0]
        headings.append(h[0])
        d = (h[1:] - h[0]) % np.pi
        between = np.degrees(np.minimum(d, np.pi - d))  # the walls' lines: 0 parallel, 90 deg square
        corners += [abs(b - 90.0) <= params.perpendicular_deg for b in between if b > params.max_turn_deg]
    if len(corners) < params.min_corners or np.mean(corners) < params.min_share:
        return None
    heading = np.array(headings)
    # Headings fold onto one axis mod 90 deg: the axis is a quarter of the mean of 4 x heading.
    axis = np.angle(np.exp(4j * heading).mean()) / 4
    for _ in range(3):  # the majority: keyframes tracked with a turn lean away from it
        near = np.abs(_fold(heading - axis)) <= np.radians(params.max_turn_deg / 2)
        axis = np.angle(np.exp(4j * heading[near]).mean()) / 4 if near.any() else axis
    turn = _fold(heading - axis)
    snapped = heading - turn
    walls = {
        i: (n, np.cos(a) * e1 + np.sin(a) * e2)
        for (i, n), a, t in zip(largest.items(), snapped, turn)
        if abs(t) <= np.radians(params.max_turn_deg)
    }
    return WallAttitudes(up, np.cos(axis) * e1 + np.sin(axis) * e2, walls) if walls else None
