"""The two sources of a CMC's agent keypoints -- an external detector's messages
(any human-pose or robot detector publishing yowo_msgs/AgentKeypoints) or the
built-in image detector -- their validation and accumulation into tracks."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from yowo_common.camera import CameraModel

from .image_detector import AgentDetection, AgentDetector
from .keypoint_tracks import CameraTracks, KeypointTrack
from .params import DetectorParams


@dataclass
class KeypointFrame:
    """One image's keypoints: ids, raw pixels, confidences (parallel arrays)."""

    stamp_ns: int
    ids: np.ndarray
    uv: np.ndarray
    confidence: np.ndarray


@dataclass
class TrackAccumulator:
    """Collects validated frames of one camera; counts what was rejected and why."""

    name: str
    camera: CameraModel | None = None
    frames: list[KeypointFrame] = field(default_factory=list)
    rejected: Counter = field(default_factory=Counter)
    received: int = 0
    camera_problem: str = ""  # why the CameraInfo received is unusable
    _last_stamp: int = -1

    def take_camera_info(self, msg) -> None:
        """The intrinsics of the first usable CameraInfo; an unusable one's reason is kept."""
        from yowo_common.rosconv import camera_info_to_model

        if self.camera is None:
            try:
                self.camera, self.camera_problem = camera_info_to_model(msg), ""
            except ValueError as exc:
                self.camera_problem = str(exc)

    def unusable_reason(self) -> str:
        return "no usable CameraInfo" + (f": {self.camera_problem}" if self.camera_problem else "")

    def add(self, frame: KeypointFrame) -> KeypointFrame | None:
        """Validate and keep a frame; returns the accepted (possibly reduced) frame or None."""
        self.received += 1
        if frame.stamp_ns <= self._last_stamp:
            self.rejected["stamp not after the previous frame"] += 1
            return None
        ok = np.isfinite(frame.uv).all(axis=1) & np.isfinite(frame.confidence)
        ok &= (frame.confidence >= 0) & (frame.confidence <= 1)
        if self.camera is not None:
            ok &= self.camera.in_image(frame.uv, margin=-0.5 * min(self.camera.width, self.camera.height))
        _, first = np.unique(frame.ids, return_index=True)
        dup = np.ones(len(frame.ids), bool)
        dup[first] = False
        ok &= ~dup
        if (~ok).any():
            self.rejected["keypoints with invalid coordinates, confidence or duplicate id"] += int((~ok).sum())
        self._last_stamp = frame.stamp_ns
        kept = KeypointFrame(frame.stamp_ns, frame.ids[ok], frame.uv[ok], frame.confidence[ok])
        self.frames.append(kept)
        return kept

    def tracks(self, frame_period_ns: int | None = None) -> CameraTracks:
        if self.camera is None:
            raise ValueError(f"camera '{self.name}': no usable CameraInfo received")
        per_id: dict[int, list] = {}
        for f in self.frames:
            for i, uv, c in zip(f.ids, f.uv, f.confidence):
                per_id.setdefault(int(i), []).append((f.stamp_ns, uv, c))
        tracks = {
            i: KeypointTrack(
                np.array([s for s, _, _ in rows], dtype=np.int64),
                np.array([uv for _, uv, _ in rows]).reshape(-1, 2),
                np.array([c for _, _, c in rows], dtype=float),
            )
            for i, rows in per_id.items()
        }
        if frame_period_ns is None:
            stamps = np.array([f.stamp_ns for f in self.frames], dtype=np.int64)
            frame_period_ns = int(np.median(np.diff(stamps))) if len(stamps) > 1 else 100_000_000
        return CameraTracks(self.name, self.camera, tracks, frame_period_ns)

    def summary(self) -> str:
        seen = sum(1 for f in self.frames if len(f.ids))
        text = f"camera '{self.name}': {self.received} frames, agent in {seen}"
        if self.rejected:
            text += "; rejected: " + ", ".join(f"{n} {why}" for why, n in self.rejected.items())
        return text


def frame_from_msg(msg) -> KeypointFrame:
    """yowo_msgs/AgentKeypoints -> KeypointFrame."""
    kps = msg.keypoints
    return KeypointFrame(
        int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec),
        np.array([k.id for k in kps], dtype=int),
        np.array([[k.x, k.y] for k in kps], dtype=float).reshape(-1, 2),
        np.array([k.confidence for k in kps], dtype=float),
    )


def frame_to_msg(frame: KeypointFrame, camera: str, frame_id: str):
    """KeypointFrame -> yowo_msgs/AgentKeypoints, as a tracker publishes it (the offline API
    passes frames through it too, so both compute on the same numbers)."""
    from std_msgs.msg import Header

    from yowo_common.rosconv import ns_to_time
    from yowo_msgs.msg import AgentKeypoints, Keypoint2D

    return AgentKeypoints(
        header=Header(stamp=ns_to_time(frame.stamp_ns), frame_id=frame_id),
        camera_name=camera,
        keypoints=[
            Keypoint2D(id=int(i), x=float(u), y=float(v), confidence=float(c))
            for i, (u, v), c in zip(frame.ids, frame.uv, frame.confidence)
        ],
    )


class ImageKeypointSource:
    """The built-in detector on one camera's image stream: (stamp, RGB) in, keypoint
    frames out in stamp order (delayed: the detector waits for its background and
    vertical). Frames that arrive before the CameraInfo wait for it (at most
    `max_pending`); out-of-order frames are dropped and counted."""

    def __init__(self, name: str, params: DetectorParams = DetectorParams(), max_pending: int = 300):
        self.name, self.params, self.max_pending = name, params, max_pending
        self.detector: AgentDetector | None = None
        self.problem = ""
        self.rejected: Counter = Counter()
        self._pending: list[tuple[int, np.ndarray]] = []
        self._last_stamp = -1

    def set_camera(self, camera: CameraModel) -> list[KeypointFrame]:
        if self.detector is not None or self.problem:
            return []
        try:
            self.detector = AgentDetector(camera, self.params)
        except ValueError as exc:
            self.problem = f"camera '{self.name}': no image detection: {exc}"
            return []
        pending, self._pending = self._pending, []
        return [f for stamp, rgb in pending for f in self._detect(stamp, rgb)]

    def push(self, stamp_ns: int, rgb: np.ndarray) -> list[KeypointFrame]:
        if stamp_ns <= self._last_stamp:
            self.rejected["image stamp not after the previous image"] += 1
            return []
        self._last_stamp = stamp_ns
        if self.detector is None:
            if len(self._pending) < self.max_pending:
                self._pending.append((stamp_ns, rgb))
            else:
                self.rejected["images before any usable CameraInfo"] += 1
            return []
        return self._detect(stamp_ns, rgb)

    def flush(self) -> list[KeypointFrame]:
        return [] if self.detector is None else [_frame(d) for d in self.detector.flush()]

    @property
    def background(self) -> np.ndarray | None:
        return None if self.detector is None else self.detector.background

    def summary(self) -> str:
        parts = [self.problem] if self.problem else []
        if self.detector is not None:
            parts.append("detector: " + self.detector.summary())
        elif not self.problem:
            parts.append(f"detector never started: {len(self._pending)} images and no usable CameraInfo")
        parts += [f"{n} {why}" for why, n in self.rejected.items()]
        return "; ".join(parts)

    def _detect(self, stamp_ns: int, rgb: np.ndarray) -> list[KeypointFrame]:
        try:
            return [_frame(d) for d in self.detector.push(stamp_ns, rgb)]
        except ValueError as exc:  # e.g. an image whose size disagrees with the CameraInfo
            self.rejected[str(exc)] += 1
            return []


def _frame(d: AgentDetection) -> KeypointFrame:
    return KeypointFrame(d.stamp_ns, d.ids, d.uv, d.confidence)
