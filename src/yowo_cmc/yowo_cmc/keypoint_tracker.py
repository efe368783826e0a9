"""One CMC's keypoint stage without ROS: the source of its agent keypoints (an external
detector's, the human-pose model or the model-free image detector on its images), its
intrinsics (CameraInfo, an intrinsics file, or a nominal model the group SfM estimates),
the agent-free background and the validated frames. The keypoint tracker node feeds it
messages converted to numpy; the offline API feeds it a recording read directly."""

from __future__ import annotations

from typing import Callable

import numpy as np

from yowo_common.camera import CameraModel
from yowo_common.intrinsics_io import intrinsics_from_text

from .background import BackgroundSampler
from .config import CmcParams
from .keypoint_input import ImageKeypointSource, KeypointFrame, TrackAccumulator
from .pose_source import PoseOrDetectorSource
from .skeletons import camera_skeleton
from .walker import EgoMotion

SOURCES = ("keypoints", "pose", "images")


class KeypointTracker:
    """`source`: keypoints, pose or images. `camera_info`: camera_calibration_parsers YAML
    text of an intrinsics file (used instead of CameraInfo); `nominal`: the camera has no
    intrinsics at all, a nominal model (cmc.nominal_hfov_deg) is made at its first image's
    size; `has_images`: its images are played (needed by the image sources and `nominal`).
    Every method that takes input returns the frames it validated, in stamp order."""

    def __init__(
        self,
        *,
        camera: str,
        source: str,
        params: CmcParams,
        has_images: bool,
        camera_info: str = "",
        nominal: bool = False,
    ):
        if source not in SOURCES:
            raise ValueError(f"camera '{camera}': unknown source '{source}' (choose from {', '.join(SOURCES)})")
        if source in ("images", "pose") and not has_images:
            raise ValueError(f"camera '{camera}': source {source} needs the camera's images")
        self.name, self.source, self.nominal_hfov_deg = camera, source, params.nominal_hfov_deg
        self.acc = TrackAccumulator(camera)
        # Raises ValueError naming the camera on a malformed declaration.
        self.skeleton = camera_skeleton(params.keypoints, camera)
        self.pose_params = params.pose
        self.problem = ""  # why the camera has no usable intrinsics
        self.nominal = nominal and not camera_info
        self.detector = (
            ImageKeypointSource(camera, params.detector, params.max_pending_frames)
            if source == "images"
            else PoseOrDetectorSource(
                camera, params.pose, params.pose_min_frames, params.detector, params.max_pending_frames, params.people
            )
            if source == "pose"
            else None
        )
        self.sampler = BackgroundSampler(params.background_period_s)
        if self.nominal and not has_images:
            self.problem = (
                f"camera '{camera}': no CameraInfo, no intrinsics file and no images, so its image "
                "size is unknown: the camera is left out"
            )
        elif camera_info:
            try:
                self.take_camera(intrinsics_from_text(camera_info, f"camera '{camera}': intrinsics file"))
            except ValueError as exc:
                self.problem = str(exc)

    @property
    def camera(self) -> CameraModel | None:
        return self.acc.camera

    @property
    def wants_camera_info(self) -> bool:
        return self.camera is None and not self.problem and not self.nominal

    def take_camera(self, camera: CameraModel) -> list[KeypointFrame]:
        """The camera's intrinsics (the detector starts on the images it kept waiting)."""
        self.acc.camera = camera
        return self._keep(self.detector.set_camera(camera)) if self.detector is not None else []

    def wants_image(self, stamp_ns: int) -> bool:
        """Whether an image needs decoding (the detectors take every one; with recorded
        keypoints only those sampled for the background)."""
        return self.detector is not None or self.sampler.wants(stamp_ns)

    def take_image(
        self, stamp_ns: int, image: Callable[[], np.ndarray]
    ) -> tuple[list[KeypointFrame], CameraModel | None]:
        """An image (`image()` decodes it, only when it is needed): the frames it validated,
        and the nominal model its size gave a camera without intrinsics (None: none now)."""
        rgb, nominal, frames = None, None, []
        if self.nominal and self.camera is None and not self.problem:
            rgb = image()
            nominal = CameraModel.from_fov(rgb.shape[1], rgb.shape[0], self.nominal_hfov_deg)
            frames = self.take_camera(nominal)
        if not self.wants_image(stamp_ns):
            return frames, nominal
        rgb = image() if rgb is None else rgb
        if self.detector is not None:
            frames += self._keep(self.detector.push(stamp_ns, rgb))
        if self.sampler.wants(stamp_ns) and (self.detector is None or self.source == "pose"):
            self.sampler.add(stamp_ns, rgb)  # the pose model needs no background; the scene keypoints do
        return frames, nominal

    def take_keypoints(self, frame: KeypointFrame) -> KeypointFrame | None:
        """An external detector's frame, completed by its declared skeleton (ids 0 and 1
        derived where missing), validated (None: rejected, counted)."""
        if self.skeleton is not None:
            frame = self.skeleton.complete(frame, self.pose_params)
        return self.acc.add(frame)

    @property
    def needs_ego(self) -> bool:
        """Whether `flush` wants the ego camera's trajectory (the pose model tells the walker
        among the people in view by it)."""
        return self.source == "pose"

    def flush(self, ego: EgoMotion | None = None) -> list[KeypointFrame]:
        """The frames the image detectors still hold (at the end of the recording); with the
        pose model the walker's, chosen with `ego`, the ego camera's trajectory (None: none)."""
        if self.detector is None:
            return []
        return self._keep(self.detector.flush(ego) if self.source == "pose" else self.detector.flush())

    def others(self) -> dict[int, list[KeypointFrame]]:
        """Every other person the pose model saw beside the walker (after `flush`), numbered
        from 1, their frames validated as the walker's; {} for the other sources."""
        if self.source != "pose" or self.camera is None:
            return {}
        out = {}
        for person, frames in self.detector.others().items():
            acc = TrackAccumulator(self.name, self.camera)
            kept = [k for k in (acc.add(f) for f in frames) if k is not None]
            if kept:
                out[person] = kept
        return out

    def walker(self) -> dict | None:
        """Which person the pose model's source took for the walker and why (after `flush`);
        None for the other sources."""
        if self.source != "pose":
            return None
        pose = self.detector.pose
        if self.detector.uses_pose and pose.choice is not None:
            return pose.choice.as_dict()
        return {"tracks": [], "clock_offset_s": None, "reason": self.detector.summary(), "people": []}

    def background(self) -> np.ndarray | None:
        """The agent-free background (RGB): the detector's model, else sampled images' median."""
        if self.detector is not None and self.detector.background is not None:
            return self.detector.background
        return self.sampler.image()

    def summary(self) -> str:
        parts = ["source: recorded keypoints", self.acc.summary()]
        if self.detector is not None:
            parts = [
                self.detector.summary()
                if self.source == "pose"
                else f"source: model-free detector; {self.detector.summary()}",
                self.acc.summary(),
            ]
        return "; ".join(p for p in [*parts, self.problem] if p)

    def _keep(self, frames: list[KeypointFrame]) -> list[KeypointFrame]:
        return [k for k in (self.acc.add(f) for f in frames) if k is not None]
