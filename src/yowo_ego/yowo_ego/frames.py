"""Ego RGB-D frames: validation, undistortion, colour/depth pairing by stamp.

Everything downstream works on undistorted images with the pinhole matrix K of
the CameraInfo (distortion removed once here), so Open3D's pinhole odometry,
TSDF fusion and the projection factors of the bundle adjustment all see the
same ideal camera. Observations handed to other stages are mapped back to raw
pixels with ``CameraModel.project``.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np

from yowo_common.camera import EQUIDISTANT, CameraModel

# Depth images with fewer valid pixels than this fraction cannot be tracked.
MIN_VALID_DEPTH_FRACTION = 0.05


class FrameError(ValueError):
    """A frame that cannot be used; the message names the topic and the problem.
    ``key`` (topic and problem, without per-frame numbers) groups repeated errors."""

    def __init__(self, topic: str, problem: str, detail: str = ""):
        super().__init__(f"{topic}: {problem}{detail}")
        self.key = f"{topic}: {problem}"


@dataclass
class RgbdFrame:
    """One undistorted colour + registered depth pair."""

    stamp_ns: int
    color: np.ndarray   # H x W x 3 uint8 RGB
    depth: np.ndarray   # H x W float32 metres, NaN = invalid


def pinhole(camera: CameraModel) -> CameraModel:
    """The distortion-free camera that undistorted frames follow."""
    return CameraModel(camera.width, camera.height, camera.K.copy())


class Undistorter:
    """Removes lens distortion from colour (bilinear) and depth (nearest: no mixing
    of foreground and background depths) while keeping K."""

    def __init__(self, camera: CameraModel):
        self.camera = camera
        self._maps = None
        if camera.has_distortion:
            size = (camera.width, camera.height)
            if camera.distortion_model == EQUIDISTANT:
                self._maps = cv2.fisheye.initUndistortRectifyMap(camera.K, camera.D[:4], np.eye(3), camera.K,
                                                                 size, cv2.CV_32FC1)
            else:
                self._maps = cv2.initUndistortRectifyMap(camera.K, camera.D, np.eye(3), camera.K, size,
                                                         cv2.CV_32FC1)

    def __call__(self, color: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._maps is None:
            return color, depth
        mx, my = self._maps
        color = cv2.remap(color, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        depth = cv2.remap(depth, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        return color, depth


def validate_frame(color: np.ndarray, depth: np.ndarray, camera: CameraModel, color_topic: str = "colour",
                   depth_topic: str = "depth") -> None:
    """Raise FrameError naming the topic when a frame cannot be used."""
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise FrameError(color_topic, "expected an H x W x 3 uint8 image", f", got {color.shape} {color.dtype}")
    if (color.shape[1], color.shape[0]) != (camera.width, camera.height):
        raise FrameError(color_topic, "image size differs from CameraInfo",
                         f": {color.shape[1]}x{color.shape[0]} vs {camera.width}x{camera.height}")
    if depth.shape != color.shape[:2]:
        raise FrameError(depth_topic, "depth size differs from colour (depth must be registered to colour)",
                         f": {depth.shape[1]}x{depth.shape[0]} vs {color.shape[1]}x{color.shape[0]}")
    valid = np.isfinite(depth) & (depth > 0)
    if valid.mean() < MIN_VALID_DEPTH_FRACTION:
        raise FrameError(depth_topic, f"too few valid depth pixels (need {100 * MIN_VALID_DEPTH_FRACTION:.0f} %)",
                         f": {100 * valid.mean():.1f} %")


def make_frame(stamp_ns: int, color: np.ndarray, depth: np.ndarray, camera: CameraModel,
               undistort: Undistorter | None = None, color_topic: str = "colour",
               depth_topic: str = "depth") -> RgbdFrame:
    """Validate and undistort one decoded pair (depth in metres, NaN or 0 = invalid)."""
    depth = np.asarray(depth, dtype=np.float32)
    validate_frame(color, depth, camera, color_topic, depth_topic)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    if undistort is not None:
        color, depth = undistort(color, depth)
    return RgbdFrame(int(stamp_ns), np.ascontiguousarray(color), depth)


class StampPairer:
    """Pairs colour and depth images by header stamp (exact, or nearest within
    ``tolerance_ns``); unpaired images older than ``max_pending`` arrivals are dropped
    and counted."""

    def __init__(self, tolerance_ns: int = 5_000_000, max_pending: int = 30):
        self.tolerance_ns = tolerance_ns
        self.max_pending = max_pending
        self.color: OrderedDict[int, object] = OrderedDict()
        self.depth: OrderedDict[int, object] = OrderedDict()
        self.dropped = 0

    def add_color(self, stamp_ns: int, item) -> list[tuple[int, object, object]]:
        return self._add(self.color, self.depth, stamp_ns, item, color_first=True)

    def add_depth(self, stamp_ns: int, item) -> list[tuple[int, object, object]]:
        return self._add(self.depth, self.color, stamp_ns, item, color_first=False)

    def _add(self, mine: OrderedDict, other: OrderedDict, stamp_ns: int, item, color_first: bool):
        best = min(other, key=lambda s: abs(s - stamp_ns), default=None)
        if best is not None and abs(best - stamp_ns) <= self.tolerance_ns:
            partner = other.pop(best)
            # Anything older than the pair can no longer be matched in order.
            for queue in (mine, other):
                for s in [s for s in queue if s < min(stamp_ns, best)]:
                    del queue[s]
                    self.dropped += 1
            pair = (item, partner) if color_first else (partner, item)
            return [(stamp_ns if color_first else best, *pair)]
        mine[stamp_ns] = item
        while len(mine) > self.max_pending:
            mine.popitem(last=False)
            self.dropped += 1
        return []
