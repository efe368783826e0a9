"""Initial ego motion (paper: ICP with multiway registration, first half): dense
RGB-D odometry of every frame against the current keyframe, checked, with
fall-backs, and keyframe selection.

Tracking is frame-to-keyframe with Open3D's tensor ``rgbd_odometry_multi_scale``
at half resolution. Hybrid (point-to-plane depth term + photometric term) is
tried first: the depth term alone cannot see sliding along a flat wall. Open3D
reports convergence even when it settled in a wrong minimum, so every result is
checked: overlap (fitness), inlier RMSE and a plausible motion since the
previous frame. A rejected attempt is retried with point-to-plane first (wider
basin), then from the zero-motion instead of the constant-velocity guess, then
against the previous frame (which becomes a keyframe), then from a feature guess
(SIFT + depth + PnP RANSAC), which survives head turns of 40 deg between
frames and stands on its own where dense odometry cannot refine it. An accepted result is polished by a few point-to-plane iterations
(removes the photometric term's mm-level bias where geometry allows). When all
fails, the frame is placed in the map of the recent keyframes by its depth
(``yowo_ego.maploc``: a whip turn along bare walls), a keyframe joined by a "map"
edge; if that fails too, it starts a new segment (a "break"), joined to the last by a
weak edge that loop closures may override.

With IMU samples (``imu``, ``OdometryParams.use_imu``) the gyro rotation since the
previous frame, with the constant-velocity translation, is the first initial guess;
a result whose rotation disagrees with the gyro by more than
``max_gyro_disagreement_deg`` is implausible; and a frame no visual attempt tracks
(a bare wall, darkness) is bridged for up to ``max_bridge_s``: the gyro rotation and
the velocity of the last visual step give its pose, it becomes a keyframe joined by
an "imu" edge (same segment) and the next frame is tracked against it. Without IMU
samples every path is the visual one alone.

Motion-adaptive frame rate (``OdometryParams.skip``, issue #19): with the IMU, a frame
whose motion since the last tracked frame is small (the gyro's rotation; the translation
from the last tracked step's velocity) is not tracked: it is *skipped* (``skip``), never a
keyframe, and its pose is interpolated (the gyro's rotation, linear translation) between the
tracked frames either side once the next is tracked (at the end of the walk the position
from a cubic through the two tracked frames either side). Frames are skipped only after a frame
tracked at the first attempt with good overlap, at most ``max_frames`` in a row and
``max_interval_s`` after the last tracked frame. Should the next frame fail its first dense
attempts against the keyframe (the motion was larger than predicted), the skipped frames'
images are made after all (the caller hands ``skip`` a function for that) and tracked
first, then the frame again: skipping never costs a frame. Without the IMU every frame is
tracked.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import gtsam
import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from yowo_common.geometry import inv_se3, rotation_angle_deg, se3

from .degeneracy import DegeneracyParams, motion_information, remap_degenerate
from .features import FeatureExtractor, FeatureParams, pose_from_images
from .frames import RgbdFrame
from .imu import ImuBuffer
from .maploc import MapLocParams, MapLocResult, map_cloud, relocalise, up_direction

_odo = o3d.t.pipelines.odometry
TRACKED, RECOVERED, LOST, IMU_BRIDGED = "tracked", "recovered", "lost", "imu_bridged"
MAP_RELOCALISED = "map_relocalised"  # untracked, placed in the map of the recent keyframes
# Not tracked (slow motion, OdometryParams.skip): the pose interpolated between the tracked
# frames either side, both densely tracked; SKIPPED until the next frame is tracked.
INTERPOLATED, SKIPPED = "interpolated", "skipped"
# Edges whose motion the tracking measured (dense odometry, a gyro bridge, the map); the
# others (breaks, loops) are uncertain to the pose graph's line process.
TRACKING_KINDS = ("odometry", "imu", "map")
# Frame statuses whose pose was measured by vision (not a guess, not the gyro alone); an
# interpolated frame lies between a frame tracked at its first attempt and a densely tracked one.
MEASURED = (TRACKED, RECOVERED, MAP_RELOCALISED, INTERPOLATED)


@dataclass(frozen=True)
class SkipParams:
    """Motion-adaptive frame rate (issue #19): which frames dense odometry may leave out."""

    # Dense odometry (~33 ms a frame on one core) is the ego stage's long pole. Leaving out
    # frames where the gyro sees a slow head halves its CPU with the same bundle-adjusted ATE
    # (BENCHMARKS, issue #19). Without the IMU the last step's rate is no safe prediction: on
    # small dim_light s0 the 2-frame steps then converged to wrong minima (ATE 0.008 -> 0.71 m),
    # so without it every frame is tracked.
    enabled: bool = True
    # Gyro rotation since the last tracked frame above which a frame is tracked: 4 deg per
    # 15 Hz frame is 60 deg/s, a look around; the next tracked step then spans ~8 deg, well
    # inside the dense odometry's basin (2 deg skipped a third fewer frames, no more accurate).
    max_rotation_deg: float = 4.0
    # Predicted translation (last tracked step's velocity x interval): 1 m/s walking is 6.7 cm a frame.
    max_translation_m: float = 0.08
    max_frames: int = 1  # skipped frames in a row (1: every 2nd frame at least)
    max_interval_s: float = 0.2  # from the last tracked frame (a gap in the stream: track)
    # The last tracked frame's overlap with its keyframe below this: weak, track every frame.
    min_fitness: float = 0.5


@dataclass(frozen=True)
class OdometryParams:
    scale: int = 2  # image downsampling for dense odometry (2: 320x240 from VGA)
    depth_max_m: float = 6.0  # Open3D defaults to 3-4 m; indoor rooms need more
    # Method cascades tried in turn from each initial guess. Hybrid alone is the
    # most accurate and cheapest; point-to-plane first has the wider basin but
    # slides along degenerate geometry (two walls), so it is the second choice.
    cascades: tuple[tuple[str, ...], ...] = (("Hybrid",), ("PointToPlane", "Hybrid"))
    # Per pyramid level, coarse to fine, at most; a level stops once fitness and inlier
    # RMSE change by less than relative_tolerance. Textured views converge in a few
    # iterations from the constant-velocity guess; along bare walls the photometric
    # term pulls weakly and (6, 3, 2) stopped short, 1-19 cm off per frame (small
    # texture_poor s0, frames 90-240: mean step error 19 mm -> 3 mm, tracking no slower
    # since Open3D's default tolerance, 1e-6, ran every level to its maximum).
    iterations: tuple[int, ...] = (20, 10, 5)
    relative_tolerance: float = 1e-4
    polish_iterations: int = 1  # point-to-plane at the finest level after an accepted result
    polish_max_m: float = 0.005
    polish_max_deg: float = 0.2
    min_fitness: float = 0.2  # fraction of pixels with a correspondence (fast turns: little overlap)
    # An accepted result whose inlier RMSE exceeds suspect_rmse_ratio x the median of the last
    # rmse_window accepted ones is suspect: the other cascades run from the same guess and the
    # result with the most overlap is kept. On bare walls Hybrid settles in wrong minima 6-44 cm
    # off at 5-15x the RMSE the right answer has (small texture_poor s2 without IMU: bundle ATE
    # 0.559 -> 0.193 m at the same CPU; running both cascades on every frame costs 30-70 % more).
    suspect_rmse_ratio: float = 3.0
    rmse_window: int = 15
    # Hybrid residual RMSE (Open3D's mixed depth/intensity units): converged
    # results stay below ~4e-4, wrong minima lie above ~1e-3 on the synthetic data.
    max_inlier_rmse: float = 6e-4
    max_speed_mps: float = 3.0  # motion plausibility between consecutive frames
    max_turn_dps: float = 900.0  # head turns reach several hundred deg/s
    # A result with little overlap that turns far from the motion prediction is ambiguous:
    # in a whip turn on bare walls dense odometry settles near zero motion at fitness ~0.3,
    # tens of degrees off. Such a result is not accepted without the feature guess agreeing;
    # otherwise the frame is lost and relocalisation joins what follows.
    ambiguous_fitness: float = 0.4
    max_prediction_disagreement_deg: float = 15.0
    keyframe_fitness: float = 0.65  # a new keyframe when the overlap with the last falls below
    keyframe_translation_m: float = 0.5
    keyframe_rotation_deg: float = 20.0
    info_distance_m: float = 0.07  # correspondence distance for edge information matrices
    # Open3D's fitness is a share of all pixels, and the fitness thresholds above hold for frames
    # with depth almost everywhere. A frame with depth in fewer than this share of its pixels
    # (a Kinect: ~70 %) has its fitness scaled up by this share over its own: unscaled, TUM
    # fr1_rpy never reached keyframe_fitness and every one of its 694 frames became a keyframe.
    full_depth_fraction: float = 0.9
    # Re-tracking after a fast turn accepts weaker evidence than loop closures:
    # the dense check that follows rejects a wrong guess.
    recovery_features: FeatureParams = FeatureParams(ratio=0.9, pnp_min_inliers=15)
    # IMU (when the recording has one): gyro rotation as first guess and check, bridging.
    use_imu: bool = True
    max_gyro_disagreement_deg: float = 5.0  # between consecutive frames; the gyro is off ~0.02 deg there
    max_bridge_s: float = 1.0  # longest stretch of frames bridged by the gyro alone
    # Uncertainty of a bridged step (its "imu" edge): rotation from the gyro (bias and noise),
    # translation from the constant velocity of the last visual step (a walk's speed changes).
    bridge_rotation_sigma_dps: float = 1.0
    bridge_translation_sigma_mps: float = 0.5
    gyro_bias_time_constant_s: float = 10.0  # running mean of the bias tracked frames imply
    # Offline reader: a frame waits this long (the recording's time) for IMU samples covering it.
    # (The graph's node waits until the end of the stream: its topics arrive in no common order.)
    imu_wait_s: float = 0.5
    # Directions an accepted result's depth and intensity terms do not constrain take the
    # motion prediction (yowo_ego.degeneracy).
    degeneracy: DegeneracyParams = DegeneracyParams()
    # A frame no attempt tracks: its pose from the recent keyframes' depth (yowo_ego.maploc).
    maploc: MapLocParams = MapLocParams()
    # Frames not tracked where the motion is slow, their poses interpolated (SkipParams).
    skip: SkipParams = SkipParams()
    # Keyframe images PNG-compressed in memory (Keyframe): lossless, half the memory of the
    # walk's keyframes (a 25-minute floor: -0.9 GB) for ~10 ms per keyframe.
    compress_keyframes: bool = True


class PackedImage:
    """An image kept losslessly PNG-compressed in memory (level 1: a VGA/2 keyframe's colour
    and depth take ~half their bytes for ~8 ms to pack and ~3 ms to read), or as is."""

    __slots__ = ("_data", "_compressed")

    def __init__(self, image: np.ndarray, compress: bool):
        self._compressed = compress
        self._data = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1] if compress else image

    def array(self) -> np.ndarray:
        return cv2.imdecode(self._data, cv2.IMREAD_UNCHANGED) if self._compressed else self._data

    @property
    def nbytes(self) -> int:
        return self._data.nbytes


class Keyframe:
    """A keyframe of the odometry; its images at the odometry resolution, ``compress``ed
    (PackedImage) since the whole walk's keyframes stay in memory until the cloud is
    fused: a 25-minute floor's 4,500 hold 1.7 GB as arrays. ``color`` / ``depth_mm``
    unpack them on each use."""

    __slots__ = ("index", "frame_index", "stamp_ns", "T_odom_cam", "segment", "_color", "_depth")

    def __init__(
        self,
        index: int,
        frame_index: int,
        stamp_ns: int,
        T_odom_cam: np.ndarray,
        color: np.ndarray | None,
        depth_mm: np.ndarray | None,
        segment: int,
        compress: bool = False,
    ):
        self.index, self.frame_index, self.stamp_ns = index, frame_index, stamp_ns
        self.T_odom_cam = T_odom_cam  # chained odometry pose (odom = first camera frame)
        self.segment = segment  # increases after every tracking break
        self._color = None if color is None else PackedImage(color, compress)
        self._depth = None if depth_mm is None else PackedImage(depth_mm, compress)

    @property
    def color(self) -> np.ndarray | None:
        """h x w x 3 uint8, downsampled."""
        return None if self._color is None else self._color.array()

    @property
    def depth_mm(self) -> np.ndarray | None:
        """h x w uint16 mm, 0 = invalid, downsampled."""
        return None if self._depth is None else self._depth.array()

    @property
    def image_bytes(self) -> int:
        return sum(im.nbytes for im in (self._color, self._depth) if im is not None)

    def moved(self, T_odom_cam: np.ndarray) -> "Keyframe":
        """The same keyframe (its images shared, not unpacked) at another pose."""
        kf = Keyframe(self.index, self.frame_index, self.stamp_ns, T_odom_cam, None, None, self.segment)
        kf._color, kf._depth = self._color, self._depth
        return kf


@dataclass
class OdometryEdge:
    """Relative pose between two keyframes: T_target_source maps source points to target."""

    source: int
    target: int
    T_target_source: np.ndarray
    information: np.ndarray  # 6x6 (Open3D order: rotation, translation)
    kind: str  # "odometry" | "loop" | "break" | "imu" | "map"
    R_gyro: np.ndarray | None = None  # tracking edges with the IMU: the gyro's R_target_source


@dataclass
class TrackResult:
    frame_index: int
    stamp_ns: int
    keyframe: int  # reference keyframe index
    T_kf_cam: np.ndarray
    T_odom_cam: np.ndarray
    fitness: float  # overlap with the keyframe (the map's share within ICP reach when placed)
    status: str  # tracked | recovered | lost | imu_bridged | map_relocalised | interpolated
    new_keyframe: bool


# Makes a skipped frame's images after all (the frame after it did not track at its first
# attempts); None when the frame turns out unusable.
FrameSource = Callable[[], "tuple[RgbdFrame, OdometryImages] | None"]


def orthonormalize(T: np.ndarray) -> np.ndarray:
    """Project the rotation block onto SO(3): Open3D returns float32-accurate
    rotations whose errors otherwise grow without bound when chained."""
    T = np.array(T, dtype=float)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    T[:3, :3] = R
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return T


def scaled_K(K: np.ndarray, scale: int) -> np.ndarray:
    """K of an image downsampled by ``scale`` (pixel centres at integer coordinates)."""
    Ks = np.array(K, dtype=float)
    Ks[0, 0] /= scale
    Ks[1, 1] /= scale
    Ks[0, 1] /= scale
    Ks[:2, 2] = (Ks[:2, 2] + 0.5) / scale - 0.5
    return Ks


def downsample(frame: RgbdFrame, scale: int, edge_ratio: float = 0.03) -> tuple[np.ndarray, np.ndarray]:
    """(colour uint8, depth uint16 mm) at 1/scale resolution: block means, so both
    stay centred where ``scaled_K`` puts the pixel. Depth averages the valid
    pixels of a block (isolated dropouts must not spread: Open3D's normals need
    valid neighbours) and drops blocks spanning a depth edge rather than blending
    two surfaces."""
    if scale == 1:
        depth, color = frame.depth, frame.color
    else:
        h, w = (s // scale * scale for s in frame.depth.shape)
        parts = [frame.depth[dy:h:scale, dx:w:scale] for dy in range(scale) for dx in range(scale)]
        valid = [np.isfinite(q) for q in parts]
        count = np.add.reduce(valid, dtype=np.float32)
        with np.errstate(invalid="ignore", divide="ignore"):
            depth = np.add.reduce([np.where(v, q, 0.0) for q, v in zip(parts, valid)]) / count
            spread = np.fmax.reduce(parts) - np.fmin.reduce(parts)
            depth[(count == 0) | ~(spread <= edge_ratio * depth)] = np.nan
        color = cv2.resize(frame.color[:h, :w], (w // scale, h // scale), interpolation=cv2.INTER_AREA)
    mm = np.nan_to_num(depth * 1000.0, nan=0.0, posinf=0.0)
    return np.ascontiguousarray(color), np.clip(np.round(mm), 0, 65535).astype(np.uint16)


# Open3D 0.20's Gaussian filter (its image pyramid's) differs by 1 ulp within 2 px of the
# image border from one process to the next (measured: two outcomes, chosen at random per
# process). The dense odometry sees the images inside a border of invalid depth, 2 px at
# its coarsest level, so those pixels never count and a recording gives the same poses in
# every run. `RgbdOdometry` shifts K's principal point to match.
ODOMETRY_PAD_PX = 8


def o3d_rgbd(color: np.ndarray, depth_mm: np.ndarray) -> o3d.t.geometry.RGBDImage:
    """Tensor RGBD image (float colour in [0, 1], float depth in mm) inside a border of
    ODOMETRY_PAD_PX (replicated colour, no depth); copies the arrays."""
    pad = ODOMETRY_PAD_PX
    color = np.pad(np.asarray(color, dtype=np.float32) / 255.0, ((pad, pad), (pad, pad), (0, 0)), mode="edge")
    depth = np.pad(np.asarray(depth_mm, dtype=np.float32), pad)
    return o3d.t.geometry.RGBDImage(
        o3d.t.geometry.Image(o3d.core.Tensor(color)), o3d.t.geometry.Image(o3d.core.Tensor(depth))
    )


@dataclass
class OdometryImages:
    """A frame's images as the tracker takes them: at the odometry resolution (also as
    Open3D's RGBD image) and the full-resolution grey image the feature fall-back matches.
    Made by ``of`` on any thread (the ego mapper node makes the next frame's while the last
    is tracked)."""

    color: np.ndarray
    depth_mm: np.ndarray
    rgbd: o3d.t.geometry.RGBDImage
    full_gray: np.ndarray

    @classmethod
    def of(cls, frame: RgbdFrame, scale: int) -> "OdometryImages":
        color, depth_mm = downsample(frame, scale)
        return cls(color, depth_mm, o3d_rgbd(color, depth_mm), cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY))


@dataclass
class _Level:
    """The odometry-resolution images of one frame plus what the feature fall-back needs."""

    frame_index: int
    stamp_ns: int
    color: np.ndarray
    depth_mm: np.ndarray
    rgbd: o3d.t.geometry.RGBDImage
    full_gray: np.ndarray
    full_depth: np.ndarray


class RgbdOdometry:
    """Dense RGB-D odometry between pairs of images at one resolution."""

    def __init__(self, K: np.ndarray, params: OdometryParams = OdometryParams()):
        self.params = params
        self.K_full = np.asarray(K, dtype=float)
        self.K = scaled_K(self.K_full, params.scale)
        K_padded = self.K.copy()
        K_padded[:2, 2] += ODOMETRY_PAD_PX
        self._K = o3d.core.Tensor(K_padded)  # of the images o3d_rgbd makes
        self._K_depth = o3d.core.Tensor(self.K)  # of the plain depth images `information` takes
        self._criteria = [
            _odo.OdometryConvergenceCriteria(n, params.relative_tolerance, params.relative_tolerance)
            for n in params.iterations
        ]
        self._polish_criteria = [_odo.OdometryConvergenceCriteria(params.polish_iterations)]

    def register(
        self,
        source: o3d.t.geometry.RGBDImage,
        target: o3d.t.geometry.RGBDImage,
        init_target_source: np.ndarray,
        cascade: tuple[str, ...] = ("Hybrid",),
    ) -> tuple[np.ndarray, float, float]:
        """(T_target_source, fitness, inlier RMSE) after running the methods of
        ``cascade`` in turn (fitness scaled for a source with little depth, full_depth_fraction);
        fitness 0 when Open3D gives up."""
        T = init_target_source
        for method in cascade:
            try:
                r = _odo.rgbd_odometry_multi_scale(
                    source,
                    target,
                    self._K,
                    o3d.core.Tensor(T),
                    1000.0,
                    self.params.depth_max_m,
                    self._criteria,
                    getattr(_odo.Method, method),
                )
            except RuntimeError:  # "Singular 6x6 linear system": nothing to track
                return init_target_source, 0.0, np.inf
            T = r.transformation.numpy()
            if not np.isfinite(T).all():
                return init_target_source, 0.0, np.inf
            T = orthonormalize(T)
        return T, float(r.fitness) * self._fitness_scale(source), float(r.inlier_rmse)

    def _fitness_scale(self, source: o3d.t.geometry.RGBDImage) -> float:
        """full_depth_fraction over the source's share of pixels with depth (inside the padding), at least 1."""
        depth = source.depth.as_tensor().numpy()[ODOMETRY_PAD_PX:-ODOMETRY_PAD_PX, ODOMETRY_PAD_PX:-ODOMETRY_PAD_PX]
        return max(1.0, self.params.full_depth_fraction * depth.size / max(np.count_nonzero(depth), 1))

    def polish(
        self, source: o3d.t.geometry.RGBDImage, target: o3d.t.geometry.RGBDImage, T_target_source: np.ndarray
    ) -> np.ndarray:
        """A few point-to-plane iterations at full odometry resolution from an
        accepted result. The photometric term leaves a bias of 1-3 mm (texture
        filtering differs between views); the depth term alone is unbiased
        where geometry constrains all six degrees of freedom. Where it does not
        (one wall, two walls), point-to-plane slides, so a polish that moves
        further than ``polish_max_m`` / ``polish_max_deg`` is discarded."""
        p = self.params
        try:
            r = _odo.rgbd_odometry_multi_scale(
                source,
                target,
                self._K,
                o3d.core.Tensor(T_target_source),
                1000.0,
                p.depth_max_m,
                self._polish_criteria,
                _odo.Method.PointToPlane,
            )
        except RuntimeError:
            return T_target_source
        T = r.transformation.numpy()
        if not np.isfinite(T).all():
            return T_target_source
        T = orthonormalize(T)
        if (
            np.linalg.norm(T[:3, 3] - T_target_source[:3, 3]) > p.polish_max_m
            or rotation_angle_deg(T[:3, :3], T_target_source[:3, :3]) > p.polish_max_deg
        ):
            return T_target_source
        return T

    def information(
        self, source_depth_mm: np.ndarray, target_depth_mm: np.ndarray, T_target_source: np.ndarray
    ) -> np.ndarray:
        info = _odo.compute_odometry_information_matrix(
            o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(source_depth_mm, dtype=np.float32))),
            o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(target_depth_mm, dtype=np.float32))),
            self._K_depth,
            o3d.core.Tensor(T_target_source),
            self.params.info_distance_m,
            1000.0,
            self.params.depth_max_m,
        ).numpy()
        return np.asarray(info, dtype=float)


class KeyframeTracker:
    """Streams frames through frame-to-keyframe odometry; collects keyframes and
    the odometry edges between consecutive keyframes."""

    def __init__(
        self, K: np.ndarray, params: OdometryParams = OdometryParams(), on_keyframe=None, imu: ImuBuffer | None = None
    ):
        """``on_keyframe(keyframe, edge, gray, depth)`` sees every new keyframe with
        the edge from the previous keyframe (None for the first) and its
        full-resolution grey image and depth (for feature extraction). ``imu``: the
        ego IMU's samples (used when ``params.use_imu``), filled as frames arrive."""
        self.params = params
        self.imu = imu if params.use_imu else None
        self.odometry = RgbdOdometry(K, params)
        self.on_keyframe = on_keyframe
        self.keyframes: list[Keyframe] = []
        self.edges: list[OdometryEdge] = []
        self.results: list[TrackResult] = []
        self.breaks = 0
        self._kf: _Level | None = None
        self._prev: _Level | None = None
        self._prev_result: TrackResult | None = None
        # Twist per second (rotation, translation; Pose3 log / dt) of the last step: a step over a
        # gap (rejected frames) is not repeated frame by frame.
        self._velocity = np.zeros(6)
        self._features = FeatureExtractor(params.recovery_features)
        self._gyro: np.ndarray | None = None  # R_prev_cur of the frame being tracked
        self._velocity_odom = np.zeros(3)  # odom-frame velocity of the last visual step [m/s]
        self._anchor_ns = 0  # stamp of the last frame not bridged
        self.imu_frames = 0  # frames tracked with a gyro rotation
        self.degenerate_frames = 0  # accepted results remapped along unobserved directions
        self.suspect_frames = 0  # results checked by the other cascades (suspect_rmse_ratio)
        self._rmse: deque[float] = deque(maxlen=params.rmse_window)  # of the last accepted results
        self._chain: list[Keyframe] = []  # recent keyframes with poses in one consistent frame
        self.map_relocalised = 0  # breaks whose pose the map gave
        self.map_failures: list[str] = []  # why the others' did not
        self.skipped = 0  # frames not tracked (SkipParams), interpolated
        self.backfilled = 0  # of them tracked after all (the next frame did not track)
        self._skipped: list[tuple[TrackResult, FrameSource | None]] = []  # waiting for the next tracked frame
        self._easy = False  # the last frame tracked at its first attempt (may skip after)

    # --- public -----------------------------------------------------------------
    def track(self, frame: RgbdFrame, images: OdometryImages | None = None) -> TrackResult:
        """``images``: the frame's OdometryImages at ``params.scale`` when already made."""
        return self._process(self._level(len(self.results), frame, images))

    def skips(self, stamp_ns: int, before: tuple[int, ...] = ()) -> bool:
        """Whether the frame at ``stamp_ns`` is to be skipped (SkipParams): the decision
        ``track``/``skip`` follow. ``before``: stamps of frames still to come ahead of it,
        taken as decided here, each tracked one as leaving the state as it is (a
        prediction, for preparing frames ahead)."""
        prev = self._prev_result
        if not self.params.skip.enabled or prev is None:
            return False
        last, run, skip = prev.stamp_ns, len(self._skipped), False
        for stamp in (*before, stamp_ns):
            skip = self._slow(last, stamp, run)
            last, run = (last, run + 1) if skip else (stamp, 0)
        return skip

    def skip(self, stamp_ns: int, source: FrameSource | None = None) -> TrackResult:
        """Leave the frame out of dense odometry: its result (status SKIPPED, the last
        tracked pose) gets its interpolated pose (INTERPOLATED) once the next frame is
        tracked. ``source`` makes its images should that frame not track at its first
        attempts (or should it end the walk, ``flush``)."""
        prev = self._prev_result
        result = TrackResult(
            len(self.results),
            stamp_ns,
            prev.keyframe,
            prev.T_kf_cam.copy(),
            prev.T_odom_cam.copy(),
            prev.fitness,
            SKIPPED,
            False,
        )
        self.results.append(result)
        self._skipped.append((result, source))
        self.skipped += 1
        return result

    def flush(self) -> None:
        """At the end of the walk: skipped frames at its end are tracked (the last; those
        before it are interpolated), or dropped when their images cannot be made."""
        while self._skipped:
            result, source = self._skipped.pop()
            made = source() if source is not None else None
            self.skipped -= 1
            if made is None:
                del self.results[result.frame_index]  # the last result: nothing refers to it
                continue
            self.backfilled += 1
            self._process(self._level(result.frame_index, *made))
        self._smooth_interpolated()

    # --- internals --------------------------------------------------------------
    def _smooth_interpolated(self) -> None:
        """Once the walk is over: each interpolated frame's position from the cubic (in time)
        through the two tracked frames either side of it, where those four and every frame
        between them were measured. Linear between the two nearest was off by 1.8 mm on
        average on the simulator's walks (every 2nd frame of their ground truth, up to 2 cm
        where the pace changes), this cubic by 0.5 mm."""
        res = self.results
        tracked = np.array([i for i, r in enumerate(res) if r.status in (TRACKED, RECOVERED)])
        for k in (i for i, r in enumerate(res) if r.status == INTERPOLATED):
            j = int(np.searchsorted(tracked, k))
            if j < 2 or j + 1 >= len(tracked):
                continue
            around = tracked[j - 2 : j + 2]
            if any(r.status not in (TRACKED, RECOVERED, INTERPOLATED) for r in res[around[0] : around[-1] + 1]):
                continue
            t = np.array([res[i].stamp_ns for i in around], dtype=float) * 1e-9 - res[k].stamp_ns * 1e-9
            # Lagrange weights of the four stamps at the frame's (t = 0).
            w = [np.prod([t[n] / (t[n] - t[m]) for n in range(4) if n != m]) for m in range(4)]
            r = res[k]
            r.T_odom_cam = r.T_odom_cam.copy()
            r.T_odom_cam[:3, 3] = sum(wm * res[i].T_odom_cam[:3, 3] for wm, i in zip(w, around))
            r.T_kf_cam = inv_se3(self.keyframes[r.keyframe].T_odom_cam) @ r.T_odom_cam

    def _level(self, index: int, frame: RgbdFrame, images: OdometryImages | None) -> _Level:
        im = images if images is not None else OdometryImages.of(frame, self.params.scale)
        return _Level(index, frame.stamp_ns, im.color, im.depth_mm, im.rgbd, im.full_gray, frame.depth)

    def _slow(self, last_ns: int, stamp_ns: int, run: int) -> bool:
        """The motion predicted from the last tracked frame (at ``last_ns``, ``run`` frames
        skipped since) to ``stamp_ns`` is small enough to leave the frame out."""
        s, prev = self.params.skip, self._prev_result
        dt_s = (stamp_ns - last_ns) * 1e-9
        if (
            run >= s.max_frames
            or not 0.0 < dt_s <= s.max_interval_s
            or not self._easy
            or prev.status != TRACKED
            or prev.fitness < s.min_fitness
        ):
            return False
        R = self._gyro_rotation(last_ns, stamp_ns) if self.imu is not None else None
        if R is None:  # no IMU, or it does not cover the interval: track
            return False
        return (
            rotation_angle_deg(np.eye(3), R) <= s.max_rotation_deg
            and np.linalg.norm(self._velocity[3:]) * dt_s <= s.max_translation_m
        )

    def _process(self, level: _Level) -> TrackResult:
        """Track ``level`` into its place in ``results`` (appended, or a skipped frame's)."""
        if self._kf is None:
            result = TrackResult(level.frame_index, level.stamp_ns, 0, np.eye(4), np.eye(4), 1.0, TRACKED, True)
            self._add_keyframe(level, np.eye(4), None, None)
        else:
            result = self._track(level)
        if level.frame_index == len(self.results):
            self.results.append(result)
        else:
            self.results[level.frame_index] = result
        prev = self._prev_result
        # A lost frame's pose is a guess: the motion before the loss stays the
        # prediction (a whip turn goes on), rather than zero motion.
        if prev is not None and result.status != LOST:
            dt_s = max((result.stamp_ns - prev.stamp_ns) * 1e-9, 1e-3)
            step = orthonormalize(inv_se3(prev.T_odom_cam) @ result.T_odom_cam)
            self._velocity = gtsam.Pose3.Logmap(gtsam.Pose3(step)) / dt_s
        if self.imu is not None:
            self._imu_bookkeeping(prev, result)
        if self._skipped:
            self._interpolate(prev, result)
        self._prev, self._prev_result = level, result
        return result

    def _interpolate(self, a: TrackResult, b: TrackResult) -> None:
        """The skipped frames between the tracked results ``a`` and ``b``: the rotation the
        gyro measured from ``a`` (its small disagreement with the tracked ``b`` spread by
        time; a slerp where the gyro does not cover it), the translation linear in time;
        each against the last keyframe before it (``frames_between_keyframes`` spreads the
        optimised keyframes' corrections over them as over tracked frames)."""
        Ta, Tb = a.T_odom_cam, b.T_odom_cam
        R_ab = Ta[:3, :3].T @ Tb[:3, :3]
        R_ab_gyro = self._gyro_rotation(a.stamp_ns, b.stamp_ns)
        for r, _ in self._skipped:
            alpha = (r.stamp_ns - a.stamp_ns) / (b.stamp_ns - a.stamp_ns)
            R_as_gyro = self._gyro_rotation(a.stamp_ns, r.stamp_ns) if R_ab_gyro is not None else None
            if R_as_gyro is None:
                R_as = Rotation.from_rotvec(alpha * Rotation.from_matrix(R_ab).as_rotvec()).as_matrix()
            else:
                # A head turn is not uniform in 2 frames (a slerp was off by up to 1.8 deg on tiny s0).
                correction = Rotation.from_matrix(R_ab_gyro.T @ R_ab).as_rotvec()
                R_as = R_as_gyro @ Rotation.from_rotvec(alpha * correction).as_matrix()
            T = orthonormalize(se3(Ta[:3, :3] @ R_as, (1.0 - alpha) * Ta[:3, 3] + alpha * Tb[:3, 3]))
            kf = next(k for k in reversed(self.keyframes) if k.stamp_ns < r.stamp_ns)
            r.keyframe, r.T_kf_cam, r.T_odom_cam = kf.index, inv_se3(kf.T_odom_cam) @ T, T
            r.fitness, r.status = b.fitness, INTERPOLATED
        self._skipped = []

    def _backfill(self) -> bool:
        """Track the skipped frames whose images can still be made (the frame after them
        did not track at its first attempts); False when there are none."""
        if not any(source is not None for _, source in self._skipped):
            return False
        pending, self._skipped = self._skipped, []
        for result, source in pending:
            made = source() if source is not None else None
            if made is None:  # unusable after all: interpolated between its neighbours
                self._skipped.append((result, None))
                continue
            self.skipped -= 1
            self.backfilled += 1
            self._process(self._level(result.frame_index, *made))
        return True

    def _imu_bookkeeping(self, prev: TrackResult | None, result: TrackResult) -> None:
        """After a frame with the IMU: the velocity a bridge continues, the bridge's
        start, and the gyro bias from a densely tracked step."""
        if result.status == IMU_BRIDGED:
            return
        self._anchor_ns = result.stamp_ns
        if prev is None or result.status == LOST:
            self._velocity_odom = np.zeros(3)
            return
        dt_s = (result.stamp_ns - prev.stamp_ns) * 1e-9
        self._velocity_odom = (result.T_odom_cam[:3, 3] - prev.T_odom_cam[:3, 3]) / dt_s
        if result.status == TRACKED and self._gyro is not None:
            R = prev.T_odom_cam[:3, :3].T @ result.T_odom_cam[:3, :3]
            self.imu.update_bias(R, prev.stamp_ns, result.stamp_ns, self.params.gyro_bias_time_constant_s)

    def _gyro_rotation(self, t0_ns: int, t1_ns: int) -> np.ndarray | None:
        """R_prev_cur from the gyro, None without IMU samples covering the interval."""
        if self.imu is None:
            return None
        try:
            return self.imu.rotation_between(t0_ns, t1_ns)
        except ValueError:  # not calibrated, or a gap in the samples: vision alone
            return None

    def _predicted_step(self, dt_s: float) -> np.ndarray:
        """T_prev_cur at the last step's velocity (constant velocity) over dt_s."""
        return gtsam.Pose3.Expmap(self._velocity * dt_s).matrix()

    def _plausible(self, T_prev_cur: np.ndarray, dt_s: float) -> bool:
        p = self.params
        dt = max(dt_s, 1e-3)
        return (
            np.linalg.norm(T_prev_cur[:3, 3]) <= p.max_speed_mps * dt
            and rotation_angle_deg(np.eye(3), T_prev_cur[:3, :3]) <= p.max_turn_dps * dt
            and (
                self._gyro is None or rotation_angle_deg(self._gyro, T_prev_cur[:3, :3]) <= p.max_gyro_disagreement_deg
            )
        )

    def _ambiguous(self, T_ref_cur: np.ndarray, fitness: float, T_ref_pred: np.ndarray) -> bool:
        """Little overlap, and far from the prediction or with none (right after a lost
        frame, whose guessed pose predicts nothing)."""
        p = self.params
        return fitness < p.ambiguous_fitness and (
            (self._prev_result is not None and self._prev_result.status == LOST)
            or rotation_angle_deg(T_ref_pred[:3, :3], T_ref_cur[:3, :3]) > p.max_prediction_disagreement_deg
        )

    def _attempts(self, level: _Level, ref: _Level, T_ref_prev: np.ndarray, dt_s: float):
        """The first acceptable T_ref_cur of the method cascades from the gyro guess
        (with the IMU), the constant-velocity and the zero-motion guess: (T, fitness)
        or None; a suspect one (``_suspect``) is checked by the remaining cascades from the
        same guess and the result with the most overlap kept. Also returns the plausible
        result with the lowest RMSE, for a break edge."""
        odo, fallback = self.odometry, None
        step = self._predicted_step(dt_s)
        inits = [T_ref_prev @ step, T_ref_prev]
        if self._gyro is not None:
            inits.insert(0, T_ref_prev @ se3(self._gyro, step[:3, 3]))
        first_try = False  # accepted from the first guess by the first cascade, not suspect
        for n_init, init in enumerate(inits):
            accepted = []
            for n_cascade, cascade in enumerate(self.params.cascades):
                T, fit, rmse = odo.register(level.rgbd, ref.rgbd, orthonormalize(init), cascade)
                if (
                    fit < self.params.min_fitness
                    or not self._plausible(inv_se3(T_ref_prev) @ T, dt_s)
                    or self._ambiguous(T, fit, inits[0])
                ):
                    continue
                if rmse > self.params.max_inlier_rmse:
                    if fallback is None or rmse < fallback[2]:
                        fallback = (T, fit, rmse)
                    continue
                first_try = n_init == n_cascade == 0 and not self._suspect(rmse)
                accepted.append((T, fit, rmse))
                if not self._suspect(rmse):
                    break
                self.suspect_frames += len(accepted) == 1  # counted once, at the first suspect result
            if accepted:
                T, fit, rmse = max(accepted, key=lambda r: r[1])
                self._rmse.append(rmse)
                remapped = self.degenerate_frames
                T = self._remap(level, ref, odo.polish(level.rgbd, ref.rgbd, T), inits[0])
                # At the first try and observed in every direction: frames after it may be skipped.
                self._easy = first_try and self.degenerate_frames == remapped
                return (T, fit), fallback
        return None, fallback

    def _suspect(self, rmse: float) -> bool:
        """An RMSE far above the recent accepted results' (a wrong minimum, see suspect_rmse_ratio)."""
        return len(self._rmse) >= 5 and rmse > self.params.suspect_rmse_ratio * float(np.median(self._rmse))

    def _remap(self, level: _Level, ref: _Level, T: np.ndarray, T_pred: np.ndarray) -> np.ndarray:
        """T_ref_cur along the directions its images do not constrain replaced by the
        prediction's (yowo_ego.degeneracy)."""
        d = self.params.degeneracy
        if not d.enabled:
            return T
        info = motion_information(level.color, level.depth_mm, ref.color, ref.depth_mm, self.odometry.K, T, d)
        T, k = remap_degenerate(T, orthonormalize(T_pred), info, d)
        self.degenerate_frames += k > 0
        return orthonormalize(T) if k else T

    def _track(self, level: _Level) -> TrackResult:
        p = self.params
        prev, prev_res = self._prev, self._prev_result
        dt_s = (level.stamp_ns - prev.stamp_ns) * 1e-9
        kf = self.keyframes[-1]
        T_kf_prev = inv_se3(kf.T_odom_cam) @ prev_res.T_odom_cam
        status = TRACKED
        self._gyro = self._gyro_rotation(prev.stamp_ns, level.stamp_ns)
        self.imu_frames += self._gyro is not None
        self._easy = False
        best, fallback = self._attempts(level, self._kf, T_kf_prev, dt_s)
        if best is None and self._skipped:
            # The motion since the last tracked frame was more than predicted: the skipped
            # frames are tracked after all, then this one again from the last of them.
            self.imu_frames -= self._gyro is not None
            if self._backfill():
                return self._track(level)
            self.imu_frames += self._gyro is not None
        if best is None and prev.frame_index != kf.frame_index:
            # Lost the keyframe (fast turn): the previous frame overlaps more.
            self._add_keyframe(prev, prev_res.T_odom_cam, kf, T_kf_prev)
            kf, T_kf_prev = self.keyframes[-1], np.eye(4)
            prev_res.keyframe, prev_res.T_kf_cam, prev_res.new_keyframe = kf.index, np.eye(4), True
            best, fallback = self._attempts(level, self._kf, T_kf_prev, dt_s)
            self._easy = False
        if best is None:
            guess = pose_from_images(
                level.full_gray, level.full_depth, prev.full_gray, prev.full_depth, self.odometry.K_full, self._features
            )
            if guess is not None and self._plausible(guess, dt_s):
                status = RECOVERED
                for cascade in p.cascades:
                    T, fit, rmse = self.odometry.register(level.rgbd, self._kf.rgbd, guess, cascade)
                    if fit >= p.min_fitness and rmse <= p.max_inlier_rmse and self._plausible(T, dt_s):
                        best = (T, fit)
                        break
                else:
                    # Dense odometry cannot refine it (degenerate geometry: a corner of two
                    # walls); the feature pose stands, as a keyframe (fitness 0) whose edge
                    # the multiway registration checks again.
                    best = (guess, 0.0)
        if best is None and self._gyro is not None and (level.stamp_ns - self._anchor_ns) * 1e-9 <= p.max_bridge_s:
            return self._bridge(level, prev_res, dt_s)
        if best is None:
            # Break: a new keyframe and segment, joined to the last by a weak edge
            # from the least bad attempt (or the constant-velocity prediction);
            # loop closures may tie the segments together properly later.
            placed = self._map_pose(level, prev_res, dt_s)
            if placed is not None:
                T_odom_cam, m = placed.T_odom_cam, p.maploc
                info = np.diag([np.radians(m.sigma_deg) ** -2] * 3 + [m.sigma_m**-2] * 3)
                self._add_keyframe(level, T_odom_cam, kf, inv_se3(kf.T_odom_cam) @ T_odom_cam, ("map", info))
                return TrackResult(
                    level.frame_index,
                    level.stamp_ns,
                    len(self.keyframes) - 1,
                    np.eye(4),
                    T_odom_cam,
                    placed.fitness,
                    MAP_RELOCALISED,
                    True,
                )
            T_kf_cur = fallback[0] if fallback is not None else T_kf_prev @ self._predicted_step(dt_s)
            T_odom_cam = kf.T_odom_cam @ orthonormalize(T_kf_cur)
            self.breaks += 1
            self._add_keyframe(level, T_odom_cam, kf, None)
            return TrackResult(
                level.frame_index, level.stamp_ns, len(self.keyframes) - 1, np.eye(4), T_odom_cam, 0.0, LOST, True
            )
        T_kf_cur, fitness = best
        T_odom_cam = kf.T_odom_cam @ T_kf_cur
        new_kf = (
            fitness < p.keyframe_fitness
            or np.linalg.norm(T_kf_cur[:3, 3]) > p.keyframe_translation_m
            or rotation_angle_deg(np.eye(3), T_kf_cur[:3, :3]) > p.keyframe_rotation_deg
        )
        if new_kf:
            self._add_keyframe(level, T_odom_cam, kf, T_kf_cur)
            return TrackResult(
                level.frame_index, level.stamp_ns, len(self.keyframes) - 1, np.eye(4), T_odom_cam, fitness, status, True
            )
        return TrackResult(level.frame_index, level.stamp_ns, kf.index, T_kf_cur, T_odom_cam, fitness, status, False)

    def _map_pose(self, level: _Level, prev_res: TrackResult, dt_s: float) -> MapLocResult | None:
        """The frame's placement in the map of the chain's keyframes (yowo_ego.maploc), None
        when it is not found with confidence (the reason kept in map_failures)."""
        p = self.params
        if not p.maploc.enabled or not self._chain:
            return None
        poses = [k.T_odom_cam for k in self._chain]
        cloud = map_cloud([k.depth_mm for k in self._chain], poses, self.odometry.K, p.maploc)
        found = relocalise(
            level.depth_mm,
            self.odometry.K,
            cloud,
            up_direction(cloud, poses, p.maploc),
            prev_res.T_odom_cam,
            p.max_speed_mps * dt_s + p.maploc.reach_margin_m,
            p.maploc,
        )
        if found.T_odom_cam is None:
            self.map_failures.append(f"frame {level.frame_index}: {found.reason}")
            return None
        self.map_relocalised += 1
        found.T_odom_cam = orthonormalize(found.T_odom_cam)
        return found

    def _bridge(self, level: _Level, prev_res: TrackResult, dt_s: float) -> TrackResult:
        """No visual attempt tracked the frame: its pose from the gyro rotation and the
        last visual step's velocity, as a keyframe (the previous keyframe's view may be
        gone when vision returns) joined by an "imu" edge with the bridge's uncertainty."""
        p = self.params
        T_odom_cam = se3(
            prev_res.T_odom_cam[:3, :3] @ self._gyro, prev_res.T_odom_cam[:3, 3] + self._velocity_odom * dt_s
        )
        kf = self.keyframes[-1]
        sigma_rot = np.radians(p.bridge_rotation_sigma_dps) * dt_s
        sigma_t = p.bridge_translation_sigma_mps * dt_s
        info = np.diag([sigma_rot**-2] * 3 + [sigma_t**-2] * 3)
        self._add_keyframe(level, T_odom_cam, kf, inv_se3(kf.T_odom_cam) @ T_odom_cam, ("imu", info))
        return TrackResult(
            level.frame_index, level.stamp_ns, len(self.keyframes) - 1, np.eye(4), T_odom_cam, 0.0, IMU_BRIDGED, True
        )

    def _add_keyframe(
        self,
        level: _Level,
        T_odom_cam: np.ndarray,
        previous: Keyframe | None,
        T_prev_cur: np.ndarray | None,
        given: tuple[str, np.ndarray] | None = None,
    ) -> None:
        """``T_prev_cur`` None: a break. ``given``: the edge's kind and information when
        they are not dense tracking's (a gyro bridge's "imu", a map relocalisation's "map")."""
        segment = 0 if previous is None else previous.segment + (T_prev_cur is None)
        kf = Keyframe(
            len(self.keyframes),
            level.frame_index,
            level.stamp_ns,
            T_odom_cam,
            level.color,
            level.depth_mm,
            segment,
            self.params.compress_keyframes,
        )
        self.keyframes.append(kf)
        # A break's guessed pose is not consistent with the keyframes before: the map restarts.
        self._chain = (self._chain + [kf])[-self.params.maploc.keyframes :] if T_prev_cur is not None else [kf]
        edge = None
        if previous is not None:
            if given is not None:
                edge = OdometryEdge(kf.index, previous.index, T_prev_cur, given[1], given[0])
            else:
                R_gyro = self._gyro_rotation(previous.stamp_ns, level.stamp_ns)
                if T_prev_cur is not None:
                    info = self.odometry.information(level.depth_mm, previous.depth_mm, T_prev_cur)
                    edge = OdometryEdge(kf.index, previous.index, T_prev_cur, info, "odometry", R_gyro)
                else:
                    # Unknown motion: a weak edge keeps the graph connected (1 m, ~30 deg sigma).
                    T = inv_se3(previous.T_odom_cam) @ T_odom_cam
                    edge = OdometryEdge(kf.index, previous.index, T, np.diag([1.0] * 6), "break", R_gyro)
            self.edges.append(edge)
        if self.on_keyframe is not None:
            self.on_keyframe(kf, edge, level.full_gray, level.full_depth)
        self._kf = level
