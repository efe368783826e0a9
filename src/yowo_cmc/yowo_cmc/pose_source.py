"""The pose model on one camera's image stream: every person tracked, the walker's
keypoints with left and right resolved, and the model-free detector for a camera whose
images hold nobody the model recognises (source `pose`)."""

from __future__ import annotations

import numpy as np

from .keypoint_input import ImageKeypointSource, KeypointFrame
from .params import DetectorParams, PeopleParams, PoseModelParams
from .person_tracks import PersonTracker, identities
from .pose_keypoints import PersonPose
from .pose_left_right import LeftRight, lr_pairs
from .pose_model import PoseDetector
from .walker import EgoMotion, WalkerChoice, choose_walker


class PoseKeypointSource:
    """The pose model on one camera's image stream: every person tracked
    (person_tracks.PersonTracker), left and right of each track made right or absent by its
    own LeftRight, and at the end of the stream the walker's tracks chosen (walker) from
    the ego camera's motion. Where another person's box overlaps the walker's, the walker's
    keypoints inside it are left out: they may be the other person's. `committed` once the model has
    seen someone in `min_frames` images (a camera whose images hold nobody the model
    recognises falls back to the model-free detector; a few false detections must not
    decide it)."""

    def __init__(self, name: str, params: PoseModelParams, min_frames: int, people: PeopleParams):
        self.name, self.min_frames, self.people = name, min_frames, people
        self.detector = PoseDetector(params)
        self.tracker = PersonTracker(people)
        self.images = self.with_people = 0
        self.choice: WalkerChoice | None = None
        self._left_right: dict[int, LeftRight] = {}
        self._resolved: dict[int, list[tuple[int, PersonPose]]] = {}  # track -> (stamp, pose) in order
        self._crowded: dict[int, dict[int, np.ndarray]] = {}  # track -> stamp -> others' boxes over it

    @property
    def committed(self) -> bool:
        return self.with_people >= self.min_frames

    def push(self, stamp_ns: int, rgb: np.ndarray) -> bool:
        """Whether the model saw anyone in this image."""
        self.images += 1
        people = [self.detector.refine(rgb, q) for q in self.detector.detect(rgb, refine=False)]
        if not people:
            return False
        self.with_people += 1
        for track, pose, others in self.tracker.update(stamp_ns, rgb, people):
            k = track.track_id
            if k not in self._left_right:
                self._left_right[k] = LeftRight(lr_pairs(self.detector.joints), self.detector.params)
                self._resolved[k], self._crowded[k] = [], {}
            if len(others):
                self._crowded[k][stamp_ns] = others
            self._resolved[k] += self._left_right[k].push(stamp_ns, k, pose)
        return True

    def flush(self, ego: EgoMotion | None) -> list[KeypointFrame]:
        """The walker's frames, in stamp order (the end of the stream): `ego` is the ego
        camera's trajectory, None without one."""
        for k, lr in self._left_right.items():
            self._resolved[k] += lr.flush()
        self.choice = choose_walker(self.tracker.tracks, ego, self.people)
        return self._frames(self.choice.track_ids)

    def others(self) -> dict[int, list[KeypointFrame]]:
        """Every person beside the walker (after `flush`), numbered from 1 in this camera
        (person_tracks.identities: one person's tracks joined), with their frames."""
        walker = set(self.choice.track_ids) if self.choice is not None else set()
        people = [g for g in identities(self.tracker.tracks, self.people) if not walker & {t.track_id for t in g}]
        frames = {n: self._frames([t.track_id for t in g]) for n, g in enumerate(people, start=1)}
        return {n: f for n, f in frames.items() if f}

    def _frames(self, track_ids: list[int]) -> list[KeypointFrame]:
        """The tracks' keypoints in stamp order, those inside other people's boxes left out."""
        min_score = self.detector.params.min_keypoint_score
        frames = [
            _outside(pose.frame(stamp, min_score), self._crowded[k].get(stamp))
            for k in track_ids
            for stamp, pose in self._resolved[k]
        ]
        return sorted((f for f in frames if len(f.ids)), key=lambda f: f.stamp_ns)

    def summary(self) -> str:
        p = self.detector.params
        kept, swapped, dropped = (
            sum(getattr(lr, a) for lr in self._left_right.values()) for a in ("kept", "swapped", "dropped")
        )
        out = (
            f"pose model {p.model}: people in {self.with_people} of {self.images} images, "
            f"{len(self.tracker.tracks)} person tracks"
        )
        if self.choice is not None:
            out += f"; {self.choice.summary()}"
        return out + f"; left/right pairs {kept} kept, {swapped} swapped, {dropped} dropped"


def _outside(frame: KeypointFrame, boxes: np.ndarray | None) -> KeypointFrame:
    """The frame's keypoints outside other people's boxes (inside one, a keypoint may be
    the other person's)."""
    if boxes is None:
        return frame
    u, v = frame.uv[:, 0:1], frame.uv[:, 1:2]
    inside = ((u >= boxes[:, 0]) & (u <= boxes[:, 2]) & (v >= boxes[:, 1]) & (v <= boxes[:, 3])).any(axis=1)
    keep = ~inside
    return KeypointFrame(frame.stamp_ns, frame.ids[keep], frame.uv[keep], frame.confidence[keep])


class PoseOrDetectorSource:
    """Source `pose` of a camera: the pose model, and the model-free detector (which
    sees only the images the model found the agent in none of) for a camera whose
    images hold nobody the model recognises. The same calls as ImageKeypointSource;
    the detector's frames come out at `flush` when the model never took over."""

    def __init__(
        self,
        name: str,
        pose: PoseModelParams,
        min_frames: int,
        detector: DetectorParams,
        max_pending: int,
        people: PeopleParams,
    ):
        self.detector = ImageKeypointSource(name, detector, max_pending)
        self.pose: PoseKeypointSource | None = None
        self.problem = ""
        try:
            self.pose = PoseKeypointSource(name, pose, min_frames, people)
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
        seen = self.pose.push(stamp_ns, rgb)
        if not self.pose.committed and not seen:
            self._fallback += self.detector.push(stamp_ns, rgb)
        return []  # the pose model's frames wait for the walker's choice at the end

    def flush(self, ego: EgoMotion | None = None) -> list[KeypointFrame]:
        """`ego`: the ego camera's trajectory, the evidence of which person is the walker."""
        if self.uses_pose:
            return self.pose.flush(ego)
        out, self._fallback = self._fallback + self.detector.flush(), []
        return out

    def others(self) -> dict[int, list[KeypointFrame]]:
        """The pose model's other people (after `flush`); the model-free detector sees one."""
        return self.pose.others() if self.uses_pose else {}

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
