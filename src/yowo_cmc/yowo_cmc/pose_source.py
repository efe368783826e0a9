"""The pose model on one camera's image stream: the agent among the persons of each
image, its keypoints with left and right resolved, and the model-free detector for a
camera whose images hold nobody the model recognises (source `pose`)."""

from __future__ import annotations

import math

import numpy as np

from .keypoint_input import ImageKeypointSource, KeypointFrame
from .params import DetectorParams, PoseModelParams
from .pose_keypoints import PersonPose
from .pose_left_right import LeftRight, lr_pairs
from .pose_model import PoseDetector


def pick_agent(
    people: list[PersonPose], previous_uv: np.ndarray | None, max_jump_px: float = math.inf
) -> PersonPose | None:
    """The agent among the persons of one image: without a previous position
    (start, or the track was lost) the best-scored person; else the person whose
    box centre is nearest to the previous agent position (box centre too), if
    within max_jump_px (None otherwise: the agent is not in this image). The
    nearest rather than the best: bystanders may score higher than the agent."""
    if not people:
        return None
    if previous_uv is None:
        return people[0]
    centres = np.array([(p.box[:2] + p.box[2:]) / 2 for p in people])
    d = np.hypot(*(centres - np.asarray(previous_uv, float)).T)
    k = int(np.argmin(d))
    return people[k] if d[k] <= max_jump_px else None


class PoseKeypointSource:
    """The pose model on one camera's image stream: per image the agent's keypoints
    (pick_agent: the person nearest to where the agent was, so bystanders are counted
    and ignored), left and right made right or absent by LeftRight (frames go out
    lr_window_s / 2 late; `flush` at the end of the stream). `push` returns the frames
    to publish: none until the model has seen the agent in `min_frames` images (a
    camera whose images hold nobody the model recognises falls back to the model-free
    detector; a few false detections must not decide it), then the ones held back and
    every new one."""

    def __init__(
        self,
        name: str,
        params: PoseModelParams = PoseModelParams(),
        min_frames: int = 5,
        max_jump: float = 0.15,
        lost_after: int = 10,
    ):
        """`max_jump`: how far (a fraction of the image diagonal) the agent's box centre may
        move between images with the agent; `lost_after`: images without it before any
        person may start a new track."""
        self.name, self.min_frames, self.max_jump, self.lost_after = name, min_frames, max_jump, lost_after
        self.detector = PoseDetector(params)
        self.left_right = LeftRight(lr_pairs(self.detector.joints), params)
        self.images = self.with_agent = self.others = 0
        self._held: list[KeypointFrame] = []
        self._previous: np.ndarray | None = None
        self._missed = 0
        self._track = 0  # changes where the agent was lost: LeftRight does not carry labels over

    @property
    def committed(self) -> bool:
        return self.with_agent >= self.min_frames

    def push(self, stamp_ns: int, rgb: np.ndarray) -> tuple[list[KeypointFrame], bool]:
        """(frames to publish, whether the model saw the agent in this image)."""
        self.images += 1
        people = self.detector.detect(rgb, refine=False)  # the crop pass on the agent only (its cost)
        agent = pick_agent(people, self._previous, self.max_jump * math.hypot(*rgb.shape[:2]))
        if agent is not None:
            agent = self.detector.refine(rgb, agent)
        if agent is None:
            self._missed += 1
            if self._missed >= self.lost_after and self._previous is not None:  # lost: the next best
                self._previous = None  # person starts a new track
                self._track += 1
            return self._out([]), False
        self.others += len(people) - 1
        self.with_agent += 1
        self._previous, self._missed = (agent.box[:2] + agent.box[2:]) / 2, 0
        return self._out(self.left_right.push(stamp_ns, self._track, agent)), True

    def flush(self) -> list[KeypointFrame]:
        """The frames still held for their left/right window (end of the stream)."""
        return self._out(self.left_right.flush())

    def _out(self, poses: list[tuple[int, PersonPose]]) -> list[KeypointFrame]:
        self._held += [pose.frame(stamp, self.detector.params.min_keypoint_score) for stamp, pose in poses]
        if not self.committed:
            return []
        out, self._held = self._held, []
        return out

    def summary(self) -> str:
        p = self.detector.params
        return (
            f"pose model {p.model}: the agent in {self.with_agent} of {self.images} images"
            + (f", {self.others} other person detections ignored" if self.others else "")
            + f"; {self.left_right.summary()}"
        )


class PoseOrDetectorSource:
    """Source `pose` of a camera: the pose model, and the model-free detector (which
    sees only the images the model found the agent in none of) for a camera whose
    images hold nobody the model recognises. The same calls as ImageKeypointSource;
    the detector's frames come out at `flush` when the model never took over."""

    def __init__(self, name: str, pose: PoseModelParams, min_frames: int, detector: DetectorParams, max_pending: int):
        self.detector = ImageKeypointSource(name, detector, max_pending)
        self.pose: PoseKeypointSource | None = None
        self.problem = ""
        try:
            self.pose = PoseKeypointSource(name, pose, min_frames)
        except (OSError, ValueError, RuntimeError) as exc:  # no model: the model-free detector serves
            self.problem = f"camera '{name}': pose model unavailable ({exc}); using the model-free detector"
        self._fallback: list[KeypointFrame] = []

    @property
    def uses_pose(self) -> bool:
        return self.pose is not None and self.pose.committed

    def set_camera(self, camera) -> list[KeypointFrame]:
        return self._held(self.detector.set_camera(camera))

    def push(self, stamp_ns: int, rgb: np.ndarray) -> list[KeypointFrame]:
        if self.pose is None:
            return self.detector.push(stamp_ns, rgb)
        frames, seen = self.pose.push(stamp_ns, rgb)
        if not self.pose.committed and not seen:
            self._fallback += self.detector.push(stamp_ns, rgb)
        return frames

    def flush(self) -> list[KeypointFrame]:
        if self.uses_pose:
            return self.pose.flush()
        out, self._fallback = self._fallback + self.detector.flush(), []
        return out

    @property
    def background(self) -> np.ndarray | None:
        """The detector's (the pose model needs none; the caller samples one)."""
        return None if self.uses_pose else self.detector.background

    def summary(self) -> str:
        if self.uses_pose:
            return f"source: pose model ({self.pose.summary()})"
        why = self.problem or (f"{self.pose.summary()}: too few to use it" if self.pose is not None else "")
        return f"source: model-free detector ({why}); {self.detector.summary()}"

    def _held(self, frames: list[KeypointFrame]) -> list[KeypointFrame]:
        if self.pose is None:
            return frames
        self._fallback += frames
        return []
