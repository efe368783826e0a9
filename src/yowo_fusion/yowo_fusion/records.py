"""The fusion's records: what it takes (the ego map, each camera's keypoints), the agent
track it works on, and what it gives (each camera's registration and verdict)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from yowo_cmc.keypoint_tracks import CameraTracks
from yowo_common.camera import CameraModel
from yowo_common.geometry import Sim3
from yowo_ego.layout import Layout

GROUP_SFM, ISOLATED_PNP, NONE = "group_sfm", "isolated_pnp", "none"
OK, WEAK, FAILED = "ok", "weak", "failed"


@dataclass(kw_only=True)
class EgoMapData:
    camera: CameraModel  # ego intrinsics with distortion
    stamps_ns: np.ndarray  # (F,)
    T_world_ego: np.ndarray  # (F, 4, 4)
    landmarks: np.ndarray  # (P, 3)
    descriptor_type: str
    descriptors: np.ndarray  # (P, D) uint8
    obs_pose: np.ndarray  # (M,)
    obs_landmark: np.ndarray  # (M,)
    obs_uv: np.ndarray  # (M, 2) raw pixels
    cloud_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) world
    cloud_colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) in [0, 1]
    layout: Layout | None = None  # the ego stage's layout of that cloud
    # (F,) per frame: tracked by vision (dense odometry or placed in the map; not a guess or a
    # gyro bridge), and its overlap; None: the ego stage did not say
    tracking_measured: np.ndarray | None = None
    tracking_fitness: np.ndarray | None = None
    imu: bool = False  # the ego stage tracked with the gyro's rotation between frames
    # (F,) the ego stage held the frame's attitude to the building (its walls and floor); None: not said
    attitude_held: np.ndarray | None = None
    # Where recordings read as one meet (each later recording's first stamp [ns]; a second walk)
    joins_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


@dataclass
class CmcInput:
    tracks: CameraTracks  # raw keypoints + camera model with distortion
    background: np.ndarray | None = None  # agent-free RGB image, for scene keypoints
    intrinsics_known: bool = True  # False: the camera model is a nominal one its group SfM estimates


@dataclass(kw_only=True)
class RegisteredCmc:
    name: str
    group: str
    method: str
    status: str
    reason: str
    T_world_cam: np.ndarray | None
    covariance: np.ndarray | None  # 6x6 ROS order (x, y, z, rx, ry, rz), world frame; NaN: unknown
    camera: CameraModel | None  # the intrinsics (with distortion) used; None: no CameraInfo arrived
    rmse_px: float
    num_agent: int
    num_scene: int
    # The camera's clock - the ego clock [s] and its sigma (None: not estimated, see clock_note).
    clock_offset_s: float | None = None
    clock_sigma_s: float | None = None
    clock_note: str = ""

    @property
    def K(self) -> np.ndarray:
        return self.camera.K if self.camera is not None else np.zeros((3, 3))


def unregistered(name: str, reason: str, camera: CameraModel | None = None) -> RegisteredCmc:
    """A camera no pose was found for: failed, with the reason."""
    return RegisteredCmc(
        name=name,
        group="",
        method=NONE,
        status=FAILED,
        reason=reason,
        T_world_cam=None,
        covariance=None,
        camera=camera,
        rmse_px=float("nan"),
        num_agent=0,
        num_scene=0,
    )


@dataclass(kw_only=True)
class AgentFit:
    """The fused agent track against one grouped CMC's observations, in its raw pixels
    (what the report draws over the camera's background)."""

    name: str
    keypoint_ids: np.ndarray  # (M,)
    observed_uv: np.ndarray  # (M, 2)
    reprojected_uv: np.ndarray  # (M, 2), NaN behind the camera


@dataclass
class AgentTrack:
    """The agent's keypoints in the world (parallel arrays, sorted by stamp per id)."""

    stamps_ns: np.ndarray
    ids: np.ndarray
    points: np.ndarray


@dataclass(kw_only=True)
class FusionResult:
    cameras: list[RegisteredCmc]
    T_world_ego: np.ndarray
    landmarks: np.ndarray
    agent: AgentTrack
    head_offset: np.ndarray
    point_cloud: np.ndarray  # (N, 3) the ego map's cloud at the refined ego poses
    point_colors: np.ndarray  # (N, 3) in [0, 1]
    layout: Layout | None  # rebuilt from point_cloud (the ego stage's without JO)
    alignments: dict[str, Sim3] = field(default_factory=dict)
    agent_fits: list[AgentFit] = field(default_factory=list)
    # The walk's weak places (yowo_fusion.weak_places.WeakPlace), for walk guidance.
    weak_places: list = field(default_factory=list)
