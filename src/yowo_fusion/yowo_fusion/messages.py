"""Fusion results <-> messages: RegisteredCameraArray, /tf_static, layout markers, the
agent fits, and EgoMap (+ its cloud and layout) -> EgoMapData (message classes only, no
rclpy)."""

from __future__ import annotations

import numpy as np
import yaml
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import Point, PoseWithCovariance, TransformStamped
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import ColorRGBA, Header, String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from yowo_cmc.intrinsics import EstimatedCamera
from yowo_common.camera import CameraModel
from yowo_common.rosconv import (
    camera_info_to_model,
    matrix_to_pose,
    matrix_to_transform,
    model_to_camera_info,
    ns_to_time,
    pointcloud2_to_xyz_rgb,
    points_to_array,
    pose_to_matrix,
    stamp_to_ns,
)
from yowo_ego.layout import Layout, LayoutPlane
from yowo_msgs.msg import (
    CameraAgentFit,
    CameraAgentFitArray,
    EgoMap,
    RegisteredCamera,
    RegisteredCameraArray,
    SceneLayout,
)

from .records import FAILED, OK, WEAK, AgentFit, EgoMapData, RegisteredCmc

WORLD_FRAME = "map"
_STATUS = {OK: RegisteredCamera.STATUS_OK, WEAK: RegisteredCamera.STATUS_WEAK, FAILED: RegisteredCamera.STATUS_FAILED}


def optical_frame(name: str) -> str:
    return f"{name}_optical_frame"


def layout_from_msg(msg: SceneLayout) -> Layout:
    return Layout(
        [points_to_array(p.points)[:, :2] for p in msg.floor_polygons],
        msg.floor_height,
        msg.ceiling_height,
        [
            LayoutPlane(p.kind, np.asarray(p.coefficients, float), points_to_array(p.boundary), p.num_points)
            for p in msg.planes
        ],
    )


def ego_map_from_msg(msg: EgoMap, cloud=None, layout: SceneLayout | None = None) -> EgoMapData:
    """The EgoMap message, with the ego stage's cloud (PointCloud2) and layout when given."""
    size = max(int(msg.descriptor_size), 1)
    desc = np.frombuffer(bytes(msg.descriptors), dtype=np.uint8).reshape(-1, size)
    xyz, rgb = pointcloud2_to_xyz_rgb(cloud) if cloud is not None else (np.zeros((0, 3)), None)
    colors = rgb / 255.0 if rgb is not None else np.full((len(xyz), 3), 0.5)
    measured, fitness = _tracking(msg)
    return EgoMapData(
        camera=camera_info_to_model(msg.camera_info),
        stamps_ns=np.array([stamp_to_ns(s) for s in msg.stamps], dtype=np.int64),
        T_world_ego=np.array([pose_to_matrix(p) for p in msg.poses]).reshape(-1, 4, 4),
        landmarks=points_to_array(msg.landmarks),
        descriptor_type=msg.descriptor_type,
        descriptors=desc,
        obs_pose=np.asarray(msg.obs_pose_index, dtype=int),
        obs_landmark=np.asarray(msg.obs_landmark_index, dtype=int),
        obs_uv=np.column_stack([np.asarray(msg.obs_x, float), np.asarray(msg.obs_y, float)]).reshape(-1, 2),
        cloud_points=xyz,
        cloud_colors=colors,
        layout=layout_from_msg(layout) if layout is not None else None,
        tracking_measured=measured,
        tracking_fitness=fitness,
        imu=bool(msg.imu),
        attitude_held=np.asarray(msg.attitude_held, dtype=bool) if len(msg.attitude_held) == len(msg.poses) else None,
    )


def _tracking(msg: EgoMap) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(measured, fitness) per pose, None when the message does not say (or not for every pose)."""
    if len(msg.tracking) != len(msg.poses) or len(msg.tracking_fitness) != len(msg.poses):
        return None, None
    codes = np.asarray(msg.tracking, dtype=int)
    # An interpolated pose lies between two densely tracked ones (the ego stage's MEASURED).
    return (
        np.isin(codes, [EgoMap.TRACKING_DENSE, EgoMap.TRACKING_MAP, EgoMap.TRACKING_INTERPOLATED]),
        np.asarray(msg.tracking_fitness, dtype=float),
    )


def registered_to_msg(cameras: list[RegisteredCmc], stamp_ns: int) -> RegisteredCameraArray:
    out = RegisteredCameraArray(header=Header(stamp=ns_to_time(stamp_ns), frame_id=WORLD_FRAME))
    for c in cameras:
        pose = PoseWithCovariance()
        if c.T_world_cam is not None:
            pose.pose = matrix_to_pose(c.T_world_cam)
            pose.covariance = [float(v) for v in np.asarray(c.covariance).reshape(-1)]
        out.cameras.append(
            RegisteredCamera(
                name=c.name,
                group=c.group,
                method=c.method,
                status=_STATUS[c.status],
                reason=c.reason,
                pose_world_camera=pose,
                k=[float(v) for v in np.asarray(c.K).reshape(-1)],
                camera_info=model_to_camera_info(c.camera) if c.camera is not None else CameraInfo(),
                reprojection_rmse_px=float(c.rmse_px),
                num_agent_observations=int(c.num_agent),
                num_scene_observations=int(c.num_scene),
                clock_offset_s=float("nan") if c.clock_offset_s is None else float(c.clock_offset_s),
                clock_sigma_s=float("nan") if c.clock_sigma_s is None else float(c.clock_sigma_s),
                clock_note=c.clock_note,
                intrinsics_estimated=isinstance(c.camera, EstimatedCamera),
                focal_sigma_px=float(getattr(c.camera, "focal_sigma_px", float("nan"))),
                k1_sigma=float(getattr(c.camera, "k1_sigma", float("nan"))),
                k2_sigma=float(getattr(c.camera, "k2_sigma", float("nan"))),
            )
        )
    return out


def _camera_from_msg(c: RegisteredCamera) -> CameraModel | None:
    """The intrinsics a registration used: its CameraInfo, marked estimated with their sigmas."""
    if not c.camera_info.width:
        return None
    camera = camera_info_to_model(c.camera_info)
    if not c.intrinsics_estimated:
        return camera
    return EstimatedCamera.of(camera, c.focal_sigma_px, c.k1_sigma, c.k2_sigma)


def tf_static(cameras: list[RegisteredCmc], stamp_ns: int) -> TFMessage:
    """All registered cameras in one TFMessage: map -> <name>_optical_frame."""
    return TFMessage(
        transforms=[
            TransformStamped(
                header=Header(stamp=ns_to_time(stamp_ns), frame_id=WORLD_FRAME),
                child_frame_id=optical_frame(c.name),
                transform=matrix_to_transform(c.T_world_cam),
            )
            for c in cameras
            if c.T_world_cam is not None
        ]
    )


def frustum_lines(camera: CameraModel, T_world_cam: np.ndarray, depth_m: float = 0.6) -> np.ndarray:
    """Line-list segments (2N, 3) of a camera frustum drawn at depth_m."""
    w, h = camera.width - 1, camera.height - 1
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], float)
    rays = np.column_stack([corners, np.ones(4)]) @ np.linalg.inv(camera.K).T * depth_m
    world = rays @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    C = T_world_cam[:3, 3]
    segs = [p for i in range(4) for p in (C, world[i])] + [p for i in range(4) for p in (world[i], world[(i + 1) % 4])]
    return np.array(segs)


def layout_markers(cameras: list[RegisteredCmc], floor_polygons: list[np.ndarray], stamp_ns: int) -> MarkerArray:
    header = Header(stamp=ns_to_time(stamp_ns), frame_id=WORLD_FRAME)
    colour = {OK: ColorRGBA(r=0.1, g=0.8, b=0.2, a=1.0), WEAK: ColorRGBA(r=1.0, g=0.6, b=0.0, a=1.0)}
    out = MarkerArray()
    for i, poly in enumerate(floor_polygons):
        pts = [Point(x=float(x), y=float(y), z=0.0) for x, y in np.vstack([poly, poly[:1]])]
        out.markers.append(
            Marker(
                header=header,
                ns="floor",
                id=i,
                type=Marker.LINE_STRIP,
                action=Marker.ADD,
                points=pts,
                color=ColorRGBA(r=0.6, g=0.6, b=0.6, a=1.0),
                lifetime=Duration(),
            )
        )
        out.markers[-1].scale.x = 0.03
        out.markers[-1].pose.orientation.w = 1.0
    for i, c in enumerate(c for c in cameras if c.T_world_cam is not None and c.camera is not None):
        m = Marker(
            header=header,
            ns="cameras",
            id=i,
            type=Marker.LINE_LIST,
            action=Marker.ADD,
            points=[Point(x=float(x), y=float(y), z=float(z)) for x, y, z in frustum_lines(c.camera, c.T_world_cam)],
            color=colour.get(c.status, colour[WEAK]),
        )
        m.scale.x = 0.02
        m.pose.orientation.w = 1.0
        out.markers.append(m)
        label = Marker(
            header=header,
            ns="labels",
            id=i,
            type=Marker.TEXT_VIEW_FACING,
            action=Marker.ADD,
            text=c.name,
            color=ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0),
        )
        label.pose = matrix_to_pose(c.T_world_cam)
        label.pose.position.z += 0.25
        label.scale.z = 0.2
        out.markers.append(label)
    return out


def agent_fits_to_msg(
    fits: list[AgentFit], cameras: dict[str, CameraModel], backgrounds: dict[str, Image], stamp_ns: int
) -> CameraAgentFitArray:
    out = CameraAgentFitArray(header=Header(stamp=ns_to_time(stamp_ns), frame_id=WORLD_FRAME))
    for f in fits:
        cam = cameras[f.name]
        out.cameras.append(
            CameraAgentFit(
                name=f.name,
                width=cam.width,
                height=cam.height,
                keypoint_ids=[int(i) for i in f.keypoint_ids],
                observed_uv=np.asarray(f.observed_uv, np.float32).reshape(-1).tolist(),
                reprojected_uv=np.asarray(f.reprojected_uv, np.float32).reshape(-1).tolist(),
                background=backgrounds.get(f.name, Image()),
            )
        )
    return out


def agent_fits_from_msg(msg: CameraAgentFitArray) -> list[tuple[AgentFit, tuple[int, int], Image | None]]:
    """(fit, (width, height), background image or None) per camera."""
    return [
        (
            AgentFit(
                name=c.name,
                keypoint_ids=np.asarray(c.keypoint_ids, int),
                observed_uv=np.asarray(c.observed_uv, float).reshape(-1, 2),
                reprojected_uv=np.asarray(c.reprojected_uv, float).reshape(-1, 2),
            ),
            (c.width, c.height),
            c.background if c.background.width else None,
        )
        for c in msg.cameras
    ]


def registered_from_msg(msg: RegisteredCameraArray) -> list[RegisteredCmc]:
    status = {v: k for k, v in _STATUS.items()}
    out = []
    for c in msg.cameras:
        failed = c.status == RegisteredCamera.STATUS_FAILED
        out.append(
            RegisteredCmc(
                name=c.name,
                group=c.group,
                method=c.method,
                status=status[c.status],
                reason=c.reason,
                T_world_cam=None if failed else pose_to_matrix(c.pose_world_camera.pose),
                covariance=None if failed else np.asarray(c.pose_world_camera.covariance).reshape(6, 6),
                camera=_camera_from_msg(c),
                rmse_px=c.reprojection_rmse_px,
                num_agent=c.num_agent_observations,
                num_scene=c.num_scene_observations,
                clock_offset_s=float(c.clock_offset_s) if np.isfinite(c.clock_offset_s) else None,
                clock_sigma_s=float(c.clock_sigma_s) if np.isfinite(c.clock_sigma_s) else None,
                clock_note=c.clock_note,
            )
        )
    return out


def weak_places_msg(places) -> String:
    """The walk's weak places (weak_places.WeakPlace) as a YAML list."""
    return String(data=yaml.safe_dump([w.as_dict() for w in places], sort_keys=False))


def weak_places_from_msg(msg: String) -> list[dict]:
    return yaml.safe_load(msg.data) or []
