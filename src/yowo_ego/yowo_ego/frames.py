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
# No RGB-D sensor measures a median depth beyond this [m]: such an image holds millimetres
# (a 32FC1 image, which holds metres by REP 118, written from a 16-bit one unscaled).
MAX_MEDIAN_DEPTH_M = 50.0
# Colour images with fewer textured pixels than this fraction (a covered lens, a
# failed exposure, a bare wall close up) give neither photometric odometry nor
# features; indoor views have 10 % and more. They are tracked by their depth alone
# (counted, not rejected): left out, they leave gaps the tracking has to jump (docs/notes/ego.md;
# a single plane's unobserved directions take the motion prediction, yowo_ego.degeneracy).
MIN_TEXTURED_FRACTION = 0.01
TEXTURE_MIN_GRADIENT = 8.0  # grey levels per pixel at 1/4 resolution (sensor noise averages out)


class FrameError(ValueError):
    """A frame that cannot be used; the message names the topic and the problem.
    ``key`` (topic and problem, without per-frame numbers) groups repeated errors."""

    def __init__(self, topic: str, problem: str, detail: str = "", stamp_ns: int | None = None):
        at = "" if stamp_ns is None else f" @ {stamp_ns} ns"
        super().__init__(f"{topic}{at}: {problem}{detail}")
        self.key = f"{topic}: {problem}"


@dataclass
class RgbdFrame:
    """One undistorted colour + registered depth pair."""

    stamp_ns: int
    color: np.ndarray  # H x W x 3 uint8 RGB
    depth: np.ndarray  # H x W float32 metres, NaN = invalid


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
                self._maps = cv2.fisheye.initUndistortRectifyMap(
                    camera.K, camera.D[:4], np.eye(3), camera.K, size, cv2.CV_32FC1
                )
            else:
                self._maps = cv2.initUndistortRectifyMap(camera.K, camera.D, np.eye(3), camera.K, size, cv2.CV_32FC1)

    def __call__(self, color: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._maps is None:
            return color, depth
        mx, my = self._maps
        color = cv2.remap(color, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        depth = cv2.remap(depth, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        return color, depth


def textured_fraction(color: np.ndarray) -> float:
    """Fraction of pixels with a grey-level gradient above TEXTURE_MIN_GRADIENT, on a
    1/4-resolution image (block means suppress sensor noise and JPEG artefacts;
    smooth shading does not count)."""
    gray = cv2.cvtColor(color, cv2.COLOR_RGB2GRAY)
    small = cv2.resize(
        gray, (max(1, gray.shape[1] // 4), max(1, gray.shape[0] // 4)), interpolation=cv2.INTER_AREA
    ).astype(np.float32)
    gx = cv2.Sobel(small, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(small, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return float(np.mean(np.hypot(gx, gy) > TEXTURE_MIN_GRADIENT))


def validate_frame(
    color: np.ndarray,
    depth: np.ndarray,
    camera: CameraModel,
    color_topic: str = "colour",
    depth_topic: str = "depth",
    stamp_ns: int | None = None,
) -> None:
    """Raise FrameError naming the topic (and the frame's stamp) when a frame cannot be used."""
    if color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise FrameError(
            color_topic, "expected an H x W x 3 uint8 image", f", got {color.shape} {color.dtype}", stamp_ns
        )
    if (color.shape[1], color.shape[0]) != (camera.width, camera.height):
        raise FrameError(
            color_topic,
            "image size differs from CameraInfo",
            f": {color.shape[1]}x{color.shape[0]} vs {camera.width}x{camera.height}",
            stamp_ns,
        )
    if depth.shape != color.shape[:2]:
        raise FrameError(
            depth_topic,
            "depth size differs from colour (depth must be registered to colour)",
            f": {depth.shape[1]}x{depth.shape[0]} vs {color.shape[1]}x{color.shape[0]}",
            stamp_ns,
        )
    valid = np.isfinite(depth) & (depth > 0)
    if valid.mean() < MIN_VALID_DEPTH_FRACTION:
        raise FrameError(
            depth_topic,
            f"too few valid depth pixels (need {100 * MIN_VALID_DEPTH_FRACTION:.0f} %)",
            f": {100 * valid.mean():.1f} %",
            stamp_ns,
        )
    median = float(np.median(depth[valid]))
    if median > MAX_MEDIAN_DEPTH_M:
        raise FrameError(
            depth_topic,
            "depth beyond any RGB-D sensor's range (millimetres in an image of metres? 32FC1 depth holds metres)",
            f": median {median:.0f}",
            stamp_ns,
        )


def make_frame(
    stamp_ns: int,
    color: np.ndarray,
    depth: np.ndarray,
    camera: CameraModel,
    undistort: Undistorter | None = None,
    color_topic: str = "colour",
    depth_topic: str = "depth",
) -> RgbdFrame:
    """Validate and undistort one decoded pair (depth in metres, NaN or 0 = invalid)."""
    depth = np.asarray(depth, dtype=np.float32)
    validate_frame(color, depth, camera, color_topic, depth_topic, stamp_ns)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    if undistort is not None:
        color, depth = undistort(color, depth)
    return RgbdFrame(int(stamp_ns), np.ascontiguousarray(color), depth)


class StampPairer:
    """Pairs colour and depth images by header stamp (exact, or nearest within
    ``tolerance_ns``); unpaired images older than ``max_pending`` arrivals are dropped
    and counted (``first_dropped``: which stream and stamp, for the report)."""

    def __init__(self, tolerance_ns: int = 5_000_000, max_pending: int = 30):
        self.tolerance_ns = tolerance_ns
        self.max_pending = max_pending
        self.color: OrderedDict[int, object] = OrderedDict()
        self.depth: OrderedDict[int, object] = OrderedDict()
        self.dropped = 0
        self.first_dropped: tuple[str, int] | None = None

    def add_color(self, stamp_ns: int, item) -> list[tuple[int, object, object]]:
        return self._add(self.color, self.depth, stamp_ns, item, color_first=True)

    def add_depth(self, stamp_ns: int, item) -> list[tuple[int, object, object]]:
        return self._add(self.depth, self.color, stamp_ns, item, color_first=False)

    def problem(self, color_topic: str, depth_topic: str) -> str:
        """The drops for a run's warnings ("" when none), naming both topics and the first dropped image."""
        if not self.dropped:
            return ""
        stream, stamp = self.first_dropped
        return (
            f"{self.dropped} {color_topic} / {depth_topic} image(s) without a partner within "
            f"{self.tolerance_ns / 1e6:g} ms dropped, the first: "
            f"{color_topic if stream == 'colour' else depth_topic} @ {stamp} ns"
        )

    def _drop(self, queue: OrderedDict, stamp_ns: int) -> None:
        del queue[stamp_ns]
        self.dropped += 1
        if self.first_dropped is None:
            self.first_dropped = ("colour" if queue is self.color else "depth", stamp_ns)

    def _add(self, mine: OrderedDict, other: OrderedDict, stamp_ns: int, item, color_first: bool):
        best = min(other, key=lambda s: abs(s - stamp_ns), default=None)
        if best is not None and abs(best - stamp_ns) <= self.tolerance_ns:
            partner = other.pop(best)
            # Anything older than the pair can no longer be matched in order.
            for queue in (mine, other):
                for s in [s for s in queue if s < min(stamp_ns, best)]:
                    self._drop(queue, s)
            pair = (item, partner) if color_first else (partner, item)
            return [(stamp_ns if color_first else best, *pair)]
        mine[stamp_ns] = item
        while len(mine) > self.max_pending:
            self._drop(mine, next(iter(mine)))
        return []
