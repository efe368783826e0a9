"""EgoMapResult -> messages (EgoMap, Path, PointCloud2, SceneLayout); no rclpy."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point32, Polygon, PoseStamped
from nav_msgs.msg import Path
from std_msgs.msg import Header

from yowo_common.rosconv import (
    array_to_points,
    matrix_to_pose,
    model_to_camera_info,
    ns_to_time,
    xyz_rgb_to_pointcloud2,
)
from yowo_msgs.msg import EgoMap, Plane, SceneLayout

from .layout import Layout
from .odometry import IMU_BRIDGED, INTERPOLATED, LOST, MAP_RELOCALISED, RECOVERED, TRACKED
from .pipeline import EgoMapResult

WORLD_FRAME = "map"
TRACKING_CODES = {
    TRACKED: EgoMap.TRACKING_DENSE,
    RECOVERED: EgoMap.TRACKING_DENSE,
    INTERPOLATED: EgoMap.TRACKING_INTERPOLATED,
    MAP_RELOCALISED: EgoMap.TRACKING_MAP,
    IMU_BRIDGED: EgoMap.TRACKING_IMU_BRIDGE,
    LOST: EgoMap.TRACKING_LOST,
}


def _header(stamp_ns: int) -> Header:
    return Header(stamp=ns_to_time(int(stamp_ns)), frame_id=WORLD_FRAME)


def ego_map_msg(r: EgoMapResult) -> EgoMap:
    """Every tracked frame's pose (the fusion's a2e factor needs the dense trajectory);
    observations indexed by frame (keyframe -> its frame index)."""
    stamp = int(r.stamps_ns[-1])
    return EgoMap(
        header=_header(stamp),
        camera_info=model_to_camera_info(r.camera, _header(stamp)),
        stamps=[ns_to_time(int(s)) for s in r.stamps_ns],
        poses=[matrix_to_pose(T) for T in r.T_world_cam],
        landmarks=array_to_points(r.landmarks),
        descriptor_type="SIFT",
        descriptor_size=int(r.descriptors.shape[1]) if r.descriptors.ndim == 2 else 0,
        descriptors=np.ascontiguousarray(r.descriptors, dtype=np.uint8).tobytes(),
        obs_pose_index=[int(i) for i in r.keyframe_frames[r.obs_keyframe]],
        obs_landmark_index=[int(i) for i in r.obs_landmark],
        obs_x=[float(v) for v in r.obs_uv[:, 0]],
        obs_y=[float(v) for v in r.obs_uv[:, 1]],
        tracking=[TRACKING_CODES[str(s)] for s in r.tracking],
        tracking_fitness=[float(f) for f in r.tracking_fitness],
        imu=bool(r.imu),
        attitude_held=[bool(h) for h in r.attitude_held],
    )


def path_msg(stamps_ns: np.ndarray, T_world_cam: np.ndarray) -> Path:
    return Path(
        header=_header(stamps_ns[-1]),
        poses=[PoseStamped(header=_header(s), pose=matrix_to_pose(T)) for s, T in zip(stamps_ns, T_world_cam)],
    )


def cloud_msg(r: EgoMapResult):
    return points_msg(r.cloud_points, r.cloud_colors, r.stamps_ns[-1])


def points_msg(xyz: np.ndarray, colors: np.ndarray, stamp_ns: int):
    """A world-frame cloud with colours in [0, 1] -> PointCloud2."""
    rgb = np.clip(np.asarray(colors) * 255.0, 0, 255).astype(np.uint8) if len(colors) else None
    return xyz_rgb_to_pointcloud2(xyz, rgb, _header(stamp_ns))


def layout_msg(r: EgoMapResult) -> SceneLayout:
    return scene_layout_msg(r.layout, r.stamps_ns[-1])


def scene_layout_msg(lay: Layout, stamp_ns: int) -> SceneLayout:
    return SceneLayout(
        header=_header(stamp_ns),
        planes=[
            Plane(
                kind=int(p.kind),
                coefficients=[float(v) for v in p.coefficients],
                boundary=array_to_points(p.boundary),
                num_points=int(p.num_points),
            )
            for p in lay.planes
        ],
        floor_polygons=[
            Polygon(points=[Point32(x=float(x), y=float(y), z=float(lay.floor_height)) for x, y in poly])
            for poly in lay.floor_polygons
        ],
        floor_height=float(lay.floor_height),
        ceiling_height=float(lay.ceiling_height),
    )
