"""Initial ego motion (paper: ICP with multiway registration, first half): the parameters
of the tracking (the ``ego.odometry`` section) and what it hands on: keyframes, the edges
between them and each frame's result with its status, from which ``frames_between_keyframes``
poses every frame once the keyframes are optimised. The tracking itself: ``keyframe_tracker``
(frame to keyframe, keyframe decisions), ``rgbd_odometry`` (dense odometry of an image pair),
``recovery`` (frames no dense attempt tracks) and ``frame_skipping`` (motion-adaptive frame
rate).
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

    # Leave frames out of dense odometry where the gyro sees a slow head. Dense odometry is the
    # ego stage's long pole; without the IMU the last step's rate is no safe prediction (steps
    # over two frames converged to wrong minima), so without it every frame is tracked.
    enabled: bool = True
    # Gyro rotation since the last tracked frame above which a frame is tracked. At 15 Hz this is
    # a look around; the next tracked step then spans twice it, well inside dense odometry's basin.
    max_rotation_deg: float = 4.0
    # Translation predicted since the last tracked frame above which a frame is tracked. The
    # prediction is that frame's step velocity x the interval; 1 m/s walking is 6.7 cm a 15 Hz frame.
    max_translation_m: float = 0.08
    max_frames: int = 1  # skipped frames in a row at most, 1: every 2nd frame tracked at least [count]
    max_interval_s: float = 0.2  # a frame this long after the last tracked frame is tracked (a gap in the stream)
    # Overlap of the last tracked frame with its keyframe below which no frame is skipped [share].
    min_fitness: float = 0.5


@dataclass(frozen=True)
class OdometryParams:
    scale: int = 2  # image downsampling for dense odometry (2: 320x240 from VGA) [factor]
    # Depth beyond which dense odometry leaves a pixel out. Open3D's default (3-4 m) is short
    # for indoor rooms.
    depth_max_m: float = 6.0
    # Method cascades tried in turn from each initial guess. Hybrid alone is the
    # most accurate and cheapest; point-to-plane first has the wider basin but
    # slides along degenerate geometry (two walls), so it is the second choice.
    cascades: tuple[tuple[str, ...], ...] = (("Hybrid",), ("PointToPlane", "Hybrid"))
    # Iterations per pyramid level, coarse to fine, at most [count]. Textured views converge in
    # a few from the constant-velocity guess; along bare walls the photometric term pulls weakly
    # and fewer stopped centimetres short.
    iterations: tuple[int, ...] = (20, 10, 5)
    # Relative change of fitness and inlier RMSE below which a pyramid level stops [share].
    # Open3D's default (1e-6) runs every level to its maximum.
    relative_tolerance: float = 1e-4
    polish_iterations: int = 1  # point-to-plane iterations at the finest level after an accepted result [count]
    polish_max_m: float = 0.005  # a polish that moves the result further than this is discarded (it slid)
    polish_max_deg: float = 0.2  # a polish that turns the result further than this is discarded
    # Overlap with the keyframe a result needs, as Open3D's fitness: the share of pixels with a
    # correspondence [share]. Low, as fast turns leave little overlap.
    min_fitness: float = 0.2
    # Inlier RMSE, over the median of the last rmse_window accepted results, above which a result
    # is suspect [x]. The other cascades then run from the same guess
    # and the result with the most overlap is kept: on bare walls Hybrid settles in wrong minima
    # centimetres off at several times the RMSE the right answer has, and running every cascade
    # on every frame would cost much more CPU.
    suspect_rmse_ratio: float = 3.0
    rmse_window: int = 15  # last accepted results whose median RMSE the suspect test takes [count]
    # Inlier RMSE above which a result is rejected, in Open3D's mixed depth/intensity units
    # [residual]. It lies between converged results and wrong minima; a rejected result can
    # still serve a break edge as the least bad attempt.
    max_inlier_rmse: float = 6e-4
    max_speed_mps: float = 3.0  # camera speed between consecutive frames above which a result is implausible
    # Head turn rate between consecutive frames above which a result is implausible [deg/s].
    # Head turns reach several hundred deg/s.
    max_turn_dps: float = 900.0
    # Overlap below which a result that turns far from the motion prediction is ambiguous, and
    # not accepted [share]. In a whip turn on bare walls dense odometry settles near zero motion
    # with little overlap, tens of degrees off; the feature guess or relocalisation takes over.
    ambiguous_fitness: float = 0.4
    # A low-overlap result turning further than this from the motion prediction is ambiguous (ambiguous_fitness).
    max_prediction_disagreement_deg: float = 15.0
    keyframe_fitness: float = 0.65  # overlap with the keyframe below which a frame becomes a new keyframe [share]
    keyframe_translation_m: float = 0.5  # a frame this far from its keyframe becomes a new keyframe
    keyframe_rotation_deg: float = 20.0  # a frame turned this far from its keyframe becomes a new keyframe
    info_distance_m: float = 0.07  # correspondence distance of the edges' information matrices
    # Share of pixels with depth that the fitness thresholds assume [share]. Open3D's fitness is a
    # share of all pixels: a frame with depth in fewer (a Kinect's) has its fitness scaled up by
    # this share over its own, or a real sensor's frames would never reach keyframe_fitness.
    full_depth_fraction: float = 0.9
    # Re-tracking after a fast turn accepts weaker evidence than loop closures:
    # the dense check that follows rejects a wrong guess.
    recovery_features: FeatureParams = FeatureParams(ratio=0.9, pnp_min_inliers=15)
    # Track with the IMU when the recording has one. The gyro's rotation is the first guess and a
    # check, and bridges frames vision does not track.
    use_imu: bool = True
    # A result turning further than this from the gyro's rotation between consecutive frames is implausible.
    max_gyro_disagreement_deg: float = 5.0
    max_bridge_s: float = 1.0  # longest stretch of frames bridged by the gyro alone
    # Frames further apart than this are not tracked against each other (a stream that stopped,
    # recordings read as one): the camera may be anywhere, a break that place recognition joins [s].
    max_track_gap_s: float = 5.0
    # Rotation sigma of a gyro-bridged step's "imu" edge per second bridged (the gyro's bias and noise) [deg/s].
    bridge_rotation_sigma_dps: float = 1.0
    # Translation sigma of a bridged step's edge per second bridged (its constant velocity: a walk's speed changes).
    bridge_translation_sigma_mps: float = 0.5
    gyro_bias_time_constant_s: float = 10.0  # time constant of the running gyro bias from tracked steps
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
    # Keep keyframe images PNG-compressed in memory (Keyframe). Lossless: a long walk's
    # keyframes take about half the memory, for milliseconds per keyframe.
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


@dataclass(kw_only=True)
class OdometryEdge:
    """Relative pose between two keyframes: T_target_source maps source points to target."""

    source: int
    target: int
    T_target_source: np.ndarray
    information: np.ndarray  # 6x6 (Open3D order: rotation, translation)
    kind: str  # "odometry" | "loop" | "break" | "imu" | "map"
    R_gyro: np.ndarray | None = None  # tracking edges with the IMU: the gyro's R_target_source


@dataclass(kw_only=True)
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
