"""Initial ego motion (paper: ICP with multiway registration, first half): the parameters
of the tracking (the ``ego.odometry`` section) and what it hands on: keyframes, the edges
between them and each frame's result with its status. The tracking itself:
``keyframe_tracker`` (frame to keyframe, keyframe decisions), ``rgbd_odometry`` (dense
odometry of an image pair), ``recovery`` (frames no dense attempt tracks) and
``frame_skipping`` (motion-adaptive frame rate).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.geometry import inv_se3, se3

from .degeneracy import DegeneracyParams
from .features import FeatureParams
from .maploc import MapLocParams

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


def frames_between_keyframes(
    results: list[TrackResult], edges: list[OdometryEdge], keyframes: list[Keyframe], T_keyframes: list[np.ndarray]
) -> np.ndarray:
    """Every frame's pose from its keyframe's (optimised) pose and its tracked
    offset. Tracking and the optimised keyframes disagree about the next
    keyframe by a correction; frames between two keyframes take that correction
    in proportion to their time (the drift accumulated along the way), so a
    corrected edge does not leave the frames before it behind."""
    tracked = {e.target: e.T_target_source for e in edges if e.source == e.target + 1}
    stamps = np.array([k.stamp_ns for k in keyframes], dtype=np.int64)
    out = np.empty((len(results), 4, 4))
    for i, r in enumerate(results):
        a = r.keyframe
        T = r.T_kf_cam
        if a + 1 < len(keyframes) and a in tracked and stamps[a] < r.stamp_ns < stamps[a + 1]:
            final = inv_se3(T_keyframes[a]) @ T_keyframes[a + 1]
            delta = final @ inv_se3(tracked[a])
            alpha = (r.stamp_ns - stamps[a]) / (stamps[a + 1] - stamps[a])
            partial = se3((Rotation.from_matrix(delta[:3, :3]) ** alpha).as_matrix(), alpha * delta[:3, 3])
            T = partial @ T
        out[i] = T_keyframes[a] @ T
    return out
