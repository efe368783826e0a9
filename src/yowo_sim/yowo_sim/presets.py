"""Capture presets: scene, cameras, walk and sensor settings of a synthetic recording."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from .bystanders import BystanderSpec
from .deficient import DeficientSpec
from .detector import DetectorSpec
from .imu import ImuParams
from .rig import CmcSpec
from .scene import SceneSpec
from .walk import WalkSpec


@dataclass(frozen=True)
class DepthNoise:
    """Structured-light style depth model (noise grows with the square of range)."""

    min_m: float = 0.3
    max_m: float = 6.0
    sigma_a_m: float = 0.0012  # sigma(z) = a + b (z - 0.4)^2  (Kinect-like)
    sigma_b: float = 0.0019
    dropout: float = 0.01  # isolated missing pixels
    edge_dropout_m: float = 0.10  # depth jumps larger than this lose their pixels


@dataclass(frozen=True)
class CapturePreset:
    name: str
    scene: SceneSpec
    cmcs_per_room: tuple[int, ...]  # cameras in rooms 0, 1, ... (a room with 1 camera: isolated)
    walk: WalkSpec = field(default_factory=WalkSpec)
    cmc: CmcSpec = field(default_factory=CmcSpec)
    detector: DetectorSpec = field(default_factory=DetectorSpec)
    depth: DepthNoise = field(default_factory=DepthNoise)
    ego_width: int = 640
    ego_height: int = 480
    ego_hfov_deg: float = 70.0
    ego_hz: float = 15.0
    cmc_hz: float = 10.0
    cmc_images: bool = True  # render and record CMC images (else keypoints only)
    cmc_keypoints: bool = True  # record the simulated detector's keypoints
    image_noise: float = 2.0  # sensor noise, grey levels (std)
    jpeg_quality: int = 90
    raw_images: bool = False  # sensor_msgs/Image instead of compressed
    # Unsynchronised CMC clocks: each CMC's clock runs this far at most (s) ahead of or
    # behind the ego camera's (the reference), drawn uniformly in [-max, +max] from the
    # seed; its messages carry its own clock (header stamps and log times). 0: synchronised.
    cmc_clock_offset_s: float = 0.0
    # The ego camera's IMU on /ego/imu (with its calibration and /gt/ego/imu_bias); a
    # generator of its own, so turning it off changes nothing else of the recording.
    imu: bool = True
    imu_params: ImuParams = field(default_factory=ImuParams)
    # Other people walking about (issue #46), from a generator of their own: with count 0
    # the recording is the agent's alone, as before.
    bystanders: BystanderSpec = field(default_factory=BystanderSpec)
    bystanders_in_ego_view: bool = True  # the ego images show the bystanders in view (as a real head camera)
    # A walk deficient on purpose (issue #48: a camera seeing the walker in one corner only, or
    # two rooms joined by one pass through a doorway): off, the walk is the seed's as before.
    deficient: DeficientSpec = field(default_factory=DeficientSpec)  # a deficient walk's kind [-]


PRESETS = {
    "tiny": CapturePreset(
        "tiny",
        SceneSpec(layout="room_4x4", num_furniture=2),
        (3,),
        walk=WalkSpec(pause_s=1.0),
        cmc=CmcSpec(width=320, height=240),
        ego_width=320,
        ego_height=240,
    ),
    "small": CapturePreset("small", SceneSpec(layout="two_rooms"), (3, 2), walk=WalkSpec(pause_s=2.0)),
    "standard": CapturePreset(
        "standard", SceneSpec(layout="office"), (3, 3, 2, 1, 1), walk=WalkSpec(pause_s=4.0, long_pause_s=12.0)
    ),
    "large": CapturePreset(
        "large", SceneSpec(layout="floor_40x20"), (3,) * 14, walk=WalkSpec(speed_mps=0.8, pause_s=30.0)
    ),
    # The scale case of issue #19: 50 CMCs (4 in the corridor, 2-3 per room over 20 rooms)
    # and a walk of about 30 minutes over the whole floor.
    "floor50": CapturePreset(
        "floor50",
        SceneSpec(layout="floor_40x20"),
        (4,) + (3, 2, 2) * 6 + (2, 2),
        walk=WalkSpec(speed_mps=0.8, pause_s=27.0),
    ),
}


def get_preset(name: str, **overrides) -> CapturePreset:
    if name not in PRESETS:
        raise ValueError(f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    return replace(PRESETS[name], **overrides)
