"""Validation of agent keypoints from an external detector (any human-pose or robot
detector publishing yowo_msgs/AgentKeypoints) and their accumulation into tracks."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from yowo_common.camera import CameraModel

from .tracks import CameraTracks, KeypointTrack


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
    _last_stamp: int = -1

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
        tracks = {i: KeypointTrack(np.array([s for s, _, _ in rows], dtype=np.int64),
                                   np.array([uv for _, uv, _ in rows]).reshape(-1, 2),
                                   np.array([c for _, _, c in rows], dtype=float))
                  for i, rows in per_id.items()}
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
    return KeypointFrame(int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec),
                         np.array([k.id for k in kps], dtype=int),
                         np.array([[k.x, k.y] for k in kps], dtype=float).reshape(-1, 2),
                         np.array([k.confidence for k in kps], dtype=float))
