"""The `ego` section of YOWO's configuration tree: what the ego mapper uses. Each
sub-section's dataclass lives with its algorithm."""

from __future__ import annotations

from dataclasses import dataclass

from .feature_tracks import FilterParams
from .features import FeatureParams
from .imu import InertialParams
from .layout import LayoutParams
from .odometry import OdometryParams
from .posegraph import LoopParams
from .refine import BundleParams
from .scene import CloudParams


@dataclass(frozen=True)
class EgoParams:
    odometry: OdometryParams = OdometryParams()  # frame-to-keyframe tracking (keyframe_tracker)
    features: FeatureParams = FeatureParams()  # SIFT of the keyframes
    loops: LoopParams = LoopParams()  # multiway registration: edge checks, loops, pose graph (posegraph)
    filter: FilterParams = FilterParams()  # match filters before the bundle adjustment (feature_tracks)
    bundle: BundleParams = BundleParams()  # bundle adjustment (refine)
    cloud: CloudParams = CloudParams()  # TSDF cloud, planar patches and the floor (scene)
    layout: LayoutParams = LayoutParams()  # walls, floor outline and ceiling (layout)
    inertial: InertialParams = InertialParams()  # the IMU in the bundle adjustment and gravity check (imu)
    bundle_adjustment: bool = True  # bundle adjustment after multiway registration; False: stop there (ablation)
    # Threads Open3D may use, 0: its default (all cores) [count]. Its parallel reductions (dense
    # odometry, information matrices) sum in a varying order, and keyframe and loop decisions
    # amplify the difference: one thread makes a recording map the same every time, and costs
    # nothing on 2 cores, where frames are decoded and features extracted on other threads.
    open3d_threads: int = 1
