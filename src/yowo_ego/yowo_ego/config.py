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
    odometry: OdometryParams = OdometryParams()
    features: FeatureParams = FeatureParams()
    loops: LoopParams = LoopParams()
    filter: FilterParams = FilterParams()
    bundle: BundleParams = BundleParams()
    cloud: CloudParams = CloudParams()
    layout: LayoutParams = LayoutParams()
    inertial: InertialParams = InertialParams()
    bundle_adjustment: bool = True  # False: stop after multiway registration (ablation)
    # Open3D's parallel reductions (dense odometry, information matrices) sum in a
    # varying order: runs differ by micrometres per frame, which keyframe and loop
    # decisions turn into millimetres. One thread makes a recording map the same
    # every time; on 2 cores it costs nothing measurable, since frames are decoded
    # and features extracted on other threads. 0: Open3D's default (all cores).
    open3d_threads: int = 1
