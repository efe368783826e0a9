"""Model-free detector of the agent's head top (keypoint 0) and ground point
(keypoint 1) in the images of one static ceiling-mounted camera, for the paper's
setting of a single agent walking through an otherwise people-free scene.

Geometry is done on viewing rays (unit bearings from CameraInfo's K and
distortion), so lens distortion, tilt and roll need no special cases; outputs
are raw (distorted) pixels.

* Background: per-pixel median of frames spread over the first `warmup_s` (a
  walking agent covers each pixel only briefly), then a running average updated
  only away from the tracked agent, so an agent standing still for minutes is
  never absorbed. A blob whose outline is a weaker edge in the frame than both
  the background's edge there and the frame's texture around it is no object
  but a flaw of the background (the ghost of a spot where the agent stood during
  the warm-up, or agent colour blended in) and is healed quickly; the warm-up
  frames are run twice, so that such flaws are healed before detections count.
  Pixels that are a uniformly darker copy of the background are shadows. (An
  agent that stands still for most of the warm-up without ever leaving the spot
  stays in the background: it is missed until it moves away.)
* Silhouette: hysteresis threshold on the colour difference (weak pixels count
  when connected to strong ones), morphology, connected components with size
  gates; the agent's blob is the one nearest to the track's last position (else
  the largest), with nearby fragments merged in.
* Vertical: the world-down direction d in the camera frame, from the agent's
  silhouettes and the background's straight edges (detector_geometry).
* Head top: the outline point farthest from the nadir d; sideways, the middle
  between the head's left and right edges (robust to hair blending into the
  background on one side); corrected for the round head: seen from above, the
  outline's top lies above the projected top point by (r / D) (1 - sin(theta))
  (head radius r, its distance D, theta its angle from the nadir).
* Ground point: with rho = agent height / camera height above the floor, the
  point under the head top lies in the same vertical plane at
  tan(theta_ground) = (1 - rho) tan(theta_head) (the homology between the head
  plane and the floor). rho is the median over frames of the value implied by
  the silhouette's lowest point, which is the sole nearest to the camera and on
  average `foot_reach` agent heights closer to the camera than the point under
  the head. Per frame the ground point so carries the head top's pixel noise
  instead of the feet's decimetre-level gait motion (and survives feet hidden
  behind furniture). With the head cut off by the image border it comes from the
  lowest point alone, at lower confidence.

Frames wait for the background (held JPEG-encoded at quality 95, ~80 kB each at
640x480: 16 MB for the default 20 s warm-up at 10 Hz; processed twice), then
until the estimates of d and rho have settled (held as outlines, ~3 kB per frame
with the agent); both keep being refined, from at most `max_geometry_frames`
distinct silhouettes (~8 kB each).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from yowo_common.camera import CameraModel

from .detector_geometry import SceneGeometry, outline_top, rho_from_feet
from .params import DetectorParams

HEAD_TOP, GROUND = 0, 1


@dataclass
class AgentDetection:
    """Keypoints of one frame (empty arrays when the agent is not seen)."""

    stamp_ns: int
    ids: np.ndarray  # (K,) int: 0 head top, 1 ground point
    uv: np.ndarray  # (K, 2) raw pixels
    confidence: np.ndarray  # (K,) in [0, 1]


@dataclass
class _Silhouette:
    pixels: np.ndarray  # (N, 2) int16 outline pixels (x, y)
    contrast: np.ndarray  # (N,) uint8 colour difference at them
    confidence: float  # of the blob being the agent


def _empty(stamp_ns: int) -> AgentDetection:
    return AgentDetection(stamp_ns, np.zeros(0, int), np.zeros((0, 2)), np.zeros(0))


class AgentDetector:
    """Feed frames in stamp order with `push`; each call returns the detections that
    became final, in frame order (frames wait until the background exists and the
    vertical has settled). `flush` at the end of the stream returns the rest."""

    def __init__(self, camera: CameraModel, params: DetectorParams = DetectorParams()):
        problems = camera.problems()
        if problems:
            raise ValueError("camera model unusable: " + "; ".join(problems))
        self.camera, self.p = camera, params
        self.f = float(0.5 * (camera.K[0, 0] + camera.K[1, 1]))
        self.shape = (camera.height, camera.width)
        self.geometry = SceneGeometry(params, camera, self.f)
        self._held: list[tuple[int, np.ndarray]] = []  # (stamp, JPEG) until the background exists
        self._samples: list[int] = []  # indices into _held for the median
        self._model: np.ndarray | None = None  # float32 RGB background
        self._model_u8: np.ndarray | None = None
        self._waiting: list[tuple[int, _Silhouette | None]] = []
        self._track: dict | None = None  # the agent's last blob
        self.frames = 0
        self.frames_with_agent = 0

    # --- public API -------------------------------------------------------------
    @property
    def background(self) -> np.ndarray | None:
        """Agent-free background image (RGB uint8), once the warm-up is over."""
        return None if self._model_u8 is None else self._model_u8.copy()

    @property
    def down_direction(self) -> np.ndarray | None:
        """World-down as a unit vector in the camera's optical frame (None until estimated)."""
        return None if self.geometry.d is None else self.geometry.d.copy()

    @property
    def vanishing_point(self) -> np.ndarray | None:
        """Vertical vanishing point K d, homogeneous, in undistorted pixels."""
        return None if self.geometry.d is None else self.camera.K @ self.geometry.d

    @property
    def height_ratio(self) -> float | None:
        """Agent height / camera height above the floor (None until estimated)."""
        return self.geometry.rho

    def up_direction(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) unit image directions of world-up at raw pixels uv (the tangent of
        the distorted vertical line through each pixel)."""
        d = self.geometry.d
        if d is None:
            raise ValueError("the vertical direction is not estimated yet")
        uv = np.asarray(uv, float).reshape(-1, 2)
        stepped, _ = self.camera.project(self.camera.bearings(uv) - 1e-3 * d)
        step = stepped - uv
        return step / np.linalg.norm(step, axis=1, keepdims=True)

    def push(self, stamp_ns: int, rgb: np.ndarray) -> list[AgentDetection]:
        if rgb.shape != (*self.shape, 3):
            raise ValueError(f"image has shape {rgb.shape}, the camera model wants {self.shape[1]}x{self.shape[0]} RGB")
        self.frames += 1
        if self._model is None:
            self._hold(stamp_ns, rgb)
            if stamp_ns - self._held[0][0] < self.p.warmup_s * 1e9:
                return []
            return self._start_background()
        return self._accept(stamp_ns, self._silhouette(stamp_ns, rgb))

    def flush(self) -> list[AgentDetection]:
        """End of the stream: the detections of all frames still waiting."""
        out = self._start_background() if self._model is None and self._held else []
        if self._model_u8 is not None:
            self.geometry.update(self.p.min_geometry_frames, self._model_u8, final=True)
        if self.geometry.d is None:
            out += [_empty(s) for s, _ in self._waiting]
        else:
            out += [self._detect(s, sil) for s, sil in self._waiting]
        self._waiting = []
        return out

    def summary(self) -> str:
        g = self.geometry
        text = f"{self.frames} frames, agent silhouette in {self.frames_with_agent}"
        if g.d is None:
            return text + (
                f"; vertical not estimated ({g.count} distinct uncut silhouettes, needs {self.p.min_geometry_frames})"
            )
        return text + f"; vertical from {g.count} silhouettes, agent / camera height {g.rho:.3f}"

    # --- stream handling ----------------------------------------------------------
    def _hold(self, stamp_ns: int, rgb: np.ndarray) -> None:
        _, jpeg = cv2.imencode(
            ".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, self.p.hold_jpeg_quality]
        )
        spacing = self.p.warmup_s * 1e9 / self.p.warmup_samples
        if not self._samples or stamp_ns - self._held[self._samples[-1]][0] >= spacing:
            self._samples.append(len(self._held))
        self._held.append((stamp_ns, jpeg))

    def _start_background(self) -> list[AgentDetection]:
        def decode(jpeg):
            return cv2.cvtColor(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)

        # Samples along the last axis: the median's partition runs over contiguous memory (the same values).
        self._model = np.median(np.stack([decode(self._held[i][1]) for i in self._samples], axis=-1), axis=-1).astype(
            np.float32
        )
        self._model_u8 = np.round(self._model).astype(np.uint8)
        held, self._held, self._samples = self._held, [], []
        # A dry run heals the median where the agent stood for most of the warm-up:
        # frames without it there show that spot as a background flaw.
        for stamp, jpeg in held:
            self._silhouette(stamp, decode(jpeg))
        self._track = None
        out = []
        for stamp, jpeg in held:
            out += self._accept(stamp, self._silhouette(stamp, decode(jpeg)))
        return out

    def _accept(self, stamp_ns: int, sil: _Silhouette | None) -> list[AgentDetection]:
        if sil is not None:
            self.frames_with_agent += 1
            if not self._at_border(sil.pixels).any():
                self.geometry.add(self.camera.bearings(sil.pixels.astype(float)))
        self.geometry.update(self.p.geometry_frames, self._model_u8)
        self._waiting.append((stamp_ns, sil))
        if not self.geometry.settled:
            return []
        out = [self._detect(s, w) for s, w in self._waiting]
        self._waiting = []
        return out

    def _at_border(self, pixels: np.ndarray) -> np.ndarray:
        h, w = self.shape
        return (pixels[:, 0] <= 0) | (pixels[:, 1] <= 0) | (pixels[:, 0] >= w - 1) | (pixels[:, 1] >= h - 1)

    # --- segmentation and tracking -------------------------------------------------
    def _silhouette(self, stamp_ns: int, rgb: np.ndarray) -> _Silhouette | None:
        p = self.p
        channels = cv2.split(cv2.absdiff(rgb, self._model_u8))
        diff = cv2.max(cv2.max(channels[0], channels[1]), channels[2])
        cand = diff > p.diff_low
        cand[cand] = ~self._shadow(rgb, cand)
        mask = cv2.morphologyEx(
            cand.astype(np.uint8),
            cv2.MORPH_OPEN,  # lone noisy pixels
            cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)),
        )
        mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
        n, labels, stats, centres = cv2.connectedComponentsWithStats(mask, connectivity=8)
        seeds = np.bincount(labels[diff > p.diff_high], minlength=n)
        area = stats[:, cv2.CC_STAT_AREA]
        image_area = self.shape[0] * self.shape[1]
        blobs = [
            k
            for k in range(1, n)
            if p.min_area * image_area <= area[k] <= p.max_area * image_area and seeds[k] >= 0.02 * area[k]
        ]
        flaws = [k for k in blobs if self._is_flaw(rgb, labels, stats[k], k)]
        agent = self._associate([k for k in blobs if k not in flaws], stats, centres, stamp_ns)
        protect = np.zeros(self.shape, np.uint8)
        sil = None
        if agent is not None:
            # Fragments near the agent (a camouflaged neck or belt splits the blob) belong to it.
            x, y, w, h = stats[agent, :4]
            pad = int(0.15 * h) + 2
            near = [
                k
                for k in range(1, n)
                if seeds[k] > 0
                and k not in flaws
                and stats[k, 0] < x + w + pad
                and stats[k, 0] + stats[k, 2] > x - pad
                and stats[k, 1] < y + h + pad
                and stats[k, 1] + stats[k, 3] > y - pad
            ]
            body = np.isin(labels, near).astype(np.uint8)
            contours, _ = cv2.findContours(body, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            pixels = np.vstack([c.reshape(-1, 2) for c in contours]).astype(np.int16)
            sil = _Silhouette(pixels, diff[pixels[:, 1], pixels[:, 0]], self._track["confidence"])
            # Undetected agent pixels next to the outline must not leak into the background either.
            protect = cv2.dilate(body, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (15, 15)))
        cv2.accumulateWeighted(rgb, self._model, p.background_rate, mask=1 - protect)
        if flaws:
            cv2.accumulateWeighted(rgb, self._model, p.flaw_rate, mask=np.isin(labels, flaws).astype(np.uint8))
        self._model_u8 = np.round(self._model).astype(np.uint8)
        return sil

    def _shadow(self, rgb: np.ndarray, cand: np.ndarray) -> np.ndarray:
        """Candidate pixels that are a uniformly darker copy of the background."""
        # Per channel (no (N, 3) temporaries; the same float32 operations in the same order).
        (f0, f1, f2), (b0, b1, b2) = rgb[cand].astype(np.float32).T, self._model[cand].T
        ratio = (f0 * b0 + f1 * b1 + f2 * b2) / np.maximum(b0 * b0 + b1 * b1 + b2 * b2, 1.0)
        d0, d1, d2 = f0 - ratio * b0, f1 - ratio * b1, f2 - ratio * b2
        chroma = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        lo, hi = self.p.shadow_ratio
        return (ratio >= lo) & (ratio < hi) & (chroma < self.p.shadow_chroma)

    def _is_flaw(self, rgb: np.ndarray, labels: np.ndarray, stat: np.ndarray, k: int) -> bool:
        """An object's outline is an edge in the frame, stronger than the texture
        around it and than the background's edge there. A background flaw's outline
        is neither (a ghost's outline is an edge of the background; blended-in agent
        colour has no edge). Both must fail, so that a ghost merged with the agent's
        blob is not healed together with the agent."""
        x, y, w, h = stat[:4]
        roi = (slice(max(y - 6, 0), y + h + 6), slice(max(x - 6, 0), x + w + 6))
        blob = (labels[roi] == k).astype(np.uint8)
        outline = blob - cv2.erode(blob, np.ones((3, 3), np.uint8))
        around = (
            cv2.dilate(blob, np.ones((9, 9), np.uint8))
            - cv2.erode(blob, np.ones((9, 9), np.uint8))
            - cv2.dilate(outline, np.ones((3, 3), np.uint8))
        ) > 0
        outline = outline.astype(bool)

        def gradient(img):
            g = cv2.cvtColor(np.ascontiguousarray(img[roi]), cv2.COLOR_RGB2GRAY).astype(np.float32)
            return cv2.magnitude(cv2.Sobel(g, cv2.CV_32F, 1, 0), cv2.Sobel(g, cv2.CV_32F, 0, 1))

        frame = gradient(rgb)
        edge = frame[outline].mean()
        return bool(edge < self.p.flaw_edge_ratio * min(gradient(self._model_u8)[outline].mean(), frame[around].mean()))

    def _associate(self, blobs: list[int], stats: np.ndarray, centres: np.ndarray, stamp_ns: int) -> int | None:
        """The agent's blob: nearest to the live track within the jump gate, else the
        largest (a new track, less trusted for its first frames)."""
        if not blobs:
            return None
        t = self._track
        frames = 1
        if t is not None and (stamp_ns - t["stamp"]) * 1e-9 <= self.p.track_gap_s:
            dist = [np.linalg.norm(centres[k] - t["centre"]) / t["height"] for k in blobs]
            if min(dist) <= self.p.track_jump:
                k, frames = blobs[int(np.argmin(dist))], t["frames"] + 1
        if frames == 1:
            k = max(blobs, key=lambda j: stats[j, cv2.CC_STAT_AREA])
        self._track = dict(
            centre=centres[k],
            height=float(stats[k, cv2.CC_STAT_HEIGHT]),
            stamp=stamp_ns,
            frames=frames,
            confidence=min(1.0, 0.5 + 0.1 * frames),
        )
        return k

    # --- keypoints -------------------------------------------------------------------
    def _detect(self, stamp_ns: int, sil: _Silhouette | None) -> AgentDetection:
        if sil is None:
            return _empty(stamp_ns)
        p, d, rho = self.p, self.geometry.d, self.geometry.rho
        b = self.camera.bearings(sil.pixels.astype(float))
        at_border = self._at_border(sil.pixels)
        top, u, theta = outline_top(b, d, rho, p, self.f)
        near_top = theta > theta.max() - 4 * p.top_band_px / self.f
        near_bottom = theta < theta.min() + 4 * p.top_band_px / self.f
        head_ok, feet_ok = not at_border[near_top].any(), not at_border[near_bottom].any()
        # The silhouette's height against rho: it is too short when furniture hides
        # the head or the feet (which one is unknown) or hair blends in.
        misfit = abs(rho_from_feet(top @ d, theta.min(), p.foot_reach) - rho) if head_ok and feet_ok else 0.0
        if misfit > p.max_height_misfit:
            return _empty(stamp_ns)
        if head_ok:
            contrast = min(1.0, float(np.median(sil.contrast[near_top])) / p.diff_high)
            agree = 1.0 / (1.0 + (misfit / (0.5 * p.max_height_misfit)) ** 2)
            c = sil.confidence * (0.5 + 0.5 * contrast) * (0.5 + 0.5 * agree)
            t_ground = np.arctan((1.0 - rho) * np.tan(np.arccos(np.clip(top @ d, -1.0, 1.0))))
            ids, rays, conf = [HEAD_TOP, GROUND], [top, np.cos(t_ground) * d + np.sin(t_ground) * u], [c, c]
        elif feet_ok:
            # Head cut off: the lowest sole point, moved out by the mean foot reach
            # (the gait's foot motion stays in it: about 10 px median error, so less trusted).
            m = b[near_bottom].mean(axis=0)
            u_f = m - (m @ d) * d
            u_f /= np.linalg.norm(u_f)
            t_ground = np.arctan(np.tan(theta.min()) + p.foot_reach * rho)
            ids, rays, conf = [GROUND], [np.cos(t_ground) * d + np.sin(t_ground) * u_f], [0.3 * sil.confidence]
        else:
            return _empty(stamp_ns)
        uv, in_front = self.camera.project(np.array(rays))
        keep = in_front & self.camera.in_image(uv)
        return AgentDetection(stamp_ns, np.array(ids)[keep], uv[keep], np.clip(np.array(conf)[keep], 0.0, 1.0))
