"""The root of the `cmc` section of YOWO's configuration tree: what the keypoint trackers
and the group SfM use. Its sections are the dataclasses of params.py."""

from __future__ import annotations

from dataclasses import dataclass, field

from .params import (
    ClockParams,
    CoverageParams,
    DetectorParams,
    KeypointFormatParams,
    PeopleParams,
    PoseModelParams,
    SfmParams,
)


@dataclass(frozen=True)
class CmcParams:
    # The skeleton of recorded or published agent keypoints (which joint each id is).
    keypoints: KeypointFormatParams = field(default_factory=KeypointFormatParams)
    detector: DetectorParams = field(default_factory=DetectorParams)  # the built-in model-free detector
    pose: PoseModelParams = field(default_factory=PoseModelParams)  # the human-pose model (source pose)
    # Images with the agent after which a camera uses the pose model [count]. Before, and for a
    # camera where the model recognises nobody, the model-free detector's keypoints.
    pose_min_frames: int = 5
    # Every person in view tracked, and the walker among them told by their motion (source pose).
    people: PeopleParams = field(default_factory=PeopleParams)
    sfm: SfmParams = field(default_factory=SfmParams)  # groups, incremental SfM, group BA
    clock: ClockParams = field(default_factory=ClockParams)  # clock offsets from the agent's motion
    # Thresholds of each camera's coverage verdict (yowo_cmc.coverage): `ok`, or what is missing and where.
    coverage: CoverageParams = field(default_factory=CoverageParams)
    # The cameras' clock offsets are estimated from the agent's motion. Reported in cameras.yaml,
    # and applied to the stamps (clock.apply) before the group SfM.
    estimate_clock_offsets: bool = True
    background_period_s: float = 1.0  # recorded images sampled this often for the agent-free background
    max_pending_frames: int = 300  # images that may wait for the camera's CameraInfo [count]
    # Horizontal field of view a camera without CameraInfo or intrinsics file starts from, at its
    # first image's size. A typical CCTV lens; the group SfM estimates its intrinsics.
    nominal_hfov_deg: float = 90.0
    # Most cameras for which a failing group SfM is tried again without each camera in turn
    # [count]. The one whose data makes it fail is left out with the error.
    isolate_failure_max_cameras: int = 12
