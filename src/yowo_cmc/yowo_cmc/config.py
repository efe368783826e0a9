"""The root of the `cmc` section of YOWO's configuration tree: what the keypoint trackers
and the group SfM use. Its sections are the dataclasses of params.py."""

from __future__ import annotations

from dataclasses import dataclass, field

from .params import ClockParams, DetectorParams, PoseModelParams, SfmParams


@dataclass(frozen=True)
class CmcParams:
    detector: DetectorParams = field(default_factory=DetectorParams)  # the built-in model-free detector
    pose: PoseModelParams = field(default_factory=PoseModelParams)  # the human-pose model (source pose)
    # A camera uses the pose model once it has seen the agent in this many images; else
    # (nobody it recognises) the model-free detector's keypoints.
    pose_min_frames: int = 5
    sfm: SfmParams = field(default_factory=SfmParams)  # groups, incremental SfM, group BA
    clock: ClockParams = field(default_factory=ClockParams)  # clock offsets from the agent's motion
    # Clock offsets from the agent's motion: reported in cameras.yaml, and applied to the
    # stamps (clock.apply) before the group SfM.
    estimate_clock_offsets: bool = True
    background_period_s: float = 1.0  # recorded images sampled this often for the agent-free background
    max_pending_frames: int = 300  # detector frames that may wait for the camera's CameraInfo
    # A camera without CameraInfo or intrinsics file starts from this horizontal field of view
    # [deg] (a typical CCTV lens) at its first image's size; the group SfM estimates its intrinsics.
    nominal_hfov_deg: float = 90.0
    # A group SfM that fails is tried again without each camera in turn (the one whose data
    # makes it fail is left out with the error) when there are at most this many cameras.
    isolate_failure_max_cameras: int = 12
