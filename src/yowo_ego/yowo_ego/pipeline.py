"""Ego-camera processing end to end (paper "Ego-camera Processing"):

    frames --(RGB-D odometry, keyframes)--> initial poses
           --(loop closures + pose graph: multiway registration)--> keyframe poses
           --(SIFT matches, epipolar + depth-consistency filter, tracks)--> 2D-3D matches
           --(bundle adjustment, eq. ego_bd)--> refined poses + landmarks
           --(TSDF cloud, planar patches, floor, R_rect eq. rot_gp2w)--> world frame (z up)
           --> layout (walls, floor polygon, ceiling)

``EgoMapper`` is streaming: ``add()`` tracks each frame as it arrives (the node
publishes that odometry online); each keyframe's features, edge check and loop
closures run on a worker thread meanwhile; ``finish()`` runs what needs the
whole recording (pose-graph optimisation, bundle adjustment, cloud, layout).
``map_recording()`` is the offline entry for an iterable of decoded frames.

One module above the usual size: ``finish()``'s steps are methods that read and set the
mapper's own state, in the order the docstring's diagram gives; the algorithms they call
live in their own modules (posegraph, visual_refinement, scene, layout).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from yowo_common.camera import CameraModel
from yowo_common.geometry import transform_points

from .config import EgoParams
from .features import FeatureExtractor, KeyframeFeatures, backproject
from .frames import MIN_TEXTURED_FRACTION, FrameError, RgbdFrame, Undistorter, make_frame, pinhole, textured_fraction
from .imu import ImuBuffer, InertialTerms, keyframe_preintegration, up_from_accelerometer
from .keyframe_tracker import KeyframeTracker
from .layout import KIND_WALL, Layout, build_layout
from .odometry import IMU_BRIDGED, LOST, MAP_RELOCALISED, RECOVERED, SKIPPED, TrackResult, frames_between_keyframes
from .posegraph import MultiwayRegistration, MultiwayResult, tied_segment_starts
from .rgbd_odometry import OdometryImages
from .scene import PlanarPatch, Rectification, find_floor, fuse_cloud, planar_patches, rectify, up_from_cameras
from .visual_refinement import SceneMap, refine_keyframes


@dataclass
class PreparedFrame:
    """A frame ready for tracking (EgoMapper.prepare)."""

    frame: RgbdFrame
    images: OdometryImages
    textured: bool  # colour with texture (else tracked by depth alone)


@dataclass(kw_only=True)
class EgoMapResult:
    """Everything in the world frame `map` (z up, floor z = 0) unless noted."""

    camera: CameraModel  # as received, with distortion
    stamps_ns: np.ndarray  # (F,) every frame tracked or skipped (interpolated), none rejected
    T_world_cam: np.ndarray  # (F, 4, 4) final poses
    keyframe_frames: np.ndarray  # (K,) frame index of each keyframe
    T_world_kf: np.ndarray  # (K, 4, 4)
    landmarks: np.ndarray  # (P, 3)
    descriptors: np.ndarray  # (P, 128) uint8 (SIFT)
    obs_keyframe: np.ndarray  # (M,) index into keyframes
    obs_landmark: np.ndarray  # (M,) index into landmarks
    obs_uv: np.ndarray  # (M, 2) raw (distorted) image pixels
    cloud_points: np.ndarray  # (N, 3)
    cloud_colors: np.ndarray  # (N, 3) in [0, 1]
    layout: Layout
    rectification: Rectification
    trajectories: dict[str, np.ndarray]  # stage -> (F, 4, 4) world poses: odometry, multiway, bundle
    stats: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    # (F,) how each frame was tracked (yowo_ego.odometry statuses) and its overlap (TrackResult.fitness)
    tracking: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype="<U16"))
    tracking_fitness: np.ndarray = field(default_factory=lambda: np.zeros(0))
    imu: bool = False  # frames were tracked with the gyro's rotation
    # (F,) the keyframe each frame was tracked from had its attitude held to the building's
    # walls (and floor) in the bundle adjustment (refine.solve_bundle's ``walls``)
    attitude_held: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def keyframe_stamps_ns(self) -> np.ndarray:
        return self.stamps_ns[self.keyframe_frames]


@dataclass
class _Cloud:
    """The fused cloud (odometry frame) and what the floor and the layout are found in."""

    points: np.ndarray  # (N, 3)
    colors: np.ndarray  # (N, 3) in [0, 1]
    cams: np.ndarray  # (K, 3) keyframe camera centres
    patches: list[PlanarPatch]
    small: np.ndarray  # (M, 3) the downsampled cloud the patches were found in
    small_normals: np.ndarray  # (M, 3) oriented towards the nearest camera


class EgoMapper:
    def __init__(
        self,
        camera: CameraModel,
        params: EgoParams = EgoParams(),
        topic: str = "camera_info",
        imu: ImuBuffer | None = None,
    ):
        """``imu``: the ego IMU's samples, appended by the caller as they arrive (each
        frame is tracked with the samples up to its stamp; see ``imu.CoverageWait``)."""
        problems = camera.problems()
        if problems:
            raise ValueError(f"{topic}: unusable ego intrinsics: {'; '.join(problems)}")
        self.camera = camera
        self.params = params
        # Process-wide in Open3D: restored when the map is finished.
        self._open3d_threads = o3d.utility.get_max_threads()
        o3d.utility.set_max_threads(params.open3d_threads)
        self.ideal = pinhole(camera)
        self._undistort = Undistorter(camera)
        self._extractor = FeatureExtractor(params.features)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ego_features")
        self._features: list[Future] = []
        self.tracker = KeyframeTracker(camera.K, params.odometry, on_keyframe=self._on_keyframe, imu=imu)
        self._multiway = MultiwayRegistration(self.tracker.odometry, params.loops)
        self.rejected: dict[str, int] = {}  # problem (topic: what) -> frames
        self.first_rejection: dict[str, str] = {}  # problem -> the first such frame's message
        self.untextured = 0  # frames tracked by depth alone (no texture in colour)
        self._last_stamp = -1
        self._settled = 0  # results handed out by ``settled``
        self._t_track = self._cpu_track = self._cpu_features = self._cpu_loops = 0.0

    def _on_keyframe(self, kf, edge, gray, depth) -> None:
        self._features.append(self._pool.submit(self._keyframe_job, kf, edge, gray, depth))

    def _keyframe_job(self, kf, edge, gray, depth) -> KeyframeFeatures:
        """On the worker thread, in keyframe order: features, then the keyframe's
        edge check and loop closures (multiway registration while frames arrive)."""
        t0 = time.thread_time()
        features = self._extractor(gray, depth)
        t1 = time.thread_time()
        self._multiway.add(kf, features, edge)
        self._cpu_features += t1 - t0
        self._cpu_loops += time.thread_time() - t1
        return features

    @property
    def frames(self) -> int:
        return len(self.tracker.results)

    def reject(self, error: FrameError) -> None:
        """Count an unusable frame (also one the caller could not even decode)."""
        self.rejected[error.key] = self.rejected.get(error.key, 0) + 1
        self.first_rejection.setdefault(error.key, str(error))

    def add(
        self,
        stamp_ns: int,
        color: np.ndarray,
        depth: np.ndarray,
        color_topic: str = "colour",
        depth_topic: str = "depth",
    ) -> TrackResult:
        """Track one decoded frame (RGB uint8, depth in metres with NaN/0 invalid), or skip
        it where the motion is slow (``skips``; its result is completed when the next frame
        is tracked). Raises FrameError (counted in ``rejected``) for frames that cannot be used
        (a skipped frame's images are not looked at unless it is tracked after all)."""
        self.admit(stamp_ns, color_topic)
        if self.skips(stamp_ns):
            return self.skip(
                stamp_ns, lambda: self.prepare(stamp_ns, color, depth, color_topic, depth_topic, admitted=True)
            )
        return self.track(self.prepare(stamp_ns, color, depth, color_topic, depth_topic, admitted=True))

    def admit(self, stamp_ns: int, topic: str = "colour") -> None:
        """The frame's place in the stream: FrameError (counted) unless its stamp follows the last's."""
        if stamp_ns <= self._last_stamp:
            error = FrameError(topic, "stamp not after the previous frame's", f" ({self._last_stamp} ns)", stamp_ns)
            self.reject(error)
            raise error
        self._last_stamp = stamp_ns

    def prepare(
        self,
        stamp_ns: int,
        color: np.ndarray,
        depth: np.ndarray,
        color_topic: str = "colour",
        depth_topic: str = "depth",
        admitted: bool = False,
    ) -> PreparedFrame:
        """The checked, undistorted frame and its odometry images, which ``track`` takes;
        FrameError (counted) for a frame that cannot be used. Frames are admitted (``admit``,
        here unless ``admitted``) in stamp order, and prepared on any one thread (a node
        prepares the next frame while the last is tracked)."""
        if not admitted:
            self.admit(stamp_ns, color_topic)
        try:
            frame = make_frame(stamp_ns, color, depth, self.camera, self._undistort, color_topic, depth_topic)
        except FrameError as exc:
            self.reject(exc)
            raise
        return PreparedFrame(
            frame,
            OdometryImages.of(frame, self.params.odometry.scale),
            textured_fraction(frame.color) >= MIN_TEXTURED_FRACTION,
        )

    def skips(self, stamp_ns: int, before: tuple[int, ...] = ()) -> bool:
        """Whether the next frame, at ``stamp_ns``, is to be skipped (``OdometryParams.skip``);
        ``before``: stamps of admitted frames ahead of it not yet tracked or skipped (a
        prediction, for preparing frames ahead: see ``KeyframeTracker.skips``)."""
        return self.tracker.skips(stamp_ns, before)

    def skip(self, stamp_ns: int, source: Callable[[], PreparedFrame]) -> TrackResult:
        """Leave the next (admitted) frame untracked: its pose is interpolated once the next
        frame is tracked. ``source`` prepares it (FrameError when unusable) should it be
        tracked after all."""

        def made():
            try:
                prepared = source()
            except FrameError:  # counted by prepare
                return None
            self.untextured += not prepared.textured
            return prepared.frame, prepared.images

        c0 = time.thread_time()
        result = self.tracker.skip(stamp_ns, made)
        self._cpu_track += time.thread_time() - c0
        return result

    def track(self, prepared: PreparedFrame) -> TrackResult:
        """Track a prepared frame (frames in the order they were prepared)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self.untextured += not prepared.textured
        result = self.tracker.track(prepared.frame, prepared.images)
        self._t_track += time.perf_counter() - t0
        self._cpu_track += time.thread_time() - c0
        return result

    def settled(self) -> list[TrackResult]:
        """The results completed since the last call, in stamp order (a skipped frame's once
        the frame after it was tracked): what the node publishes as online odometry."""
        results = self.tracker.results
        end = self._settled
        while end < len(results) and results[end].status != SKIPPED:
            end += 1
        out, self._settled = results[self._settled : end], end
        return out

    def finish(self) -> EgoMapResult:
        try:
            return self._finish()
        finally:
            o3d.utility.set_max_threads(self._open3d_threads)

    def _finish(self) -> EgoMapResult:
        """What needs the whole recording, step by step (see the module docstring)."""
        stats = self._finish_tracking()
        c_finish = time.thread_time()
        warnings = self._frame_warnings()
        features = self._wait_for_features(stats)
        self._tracking_stats(stats)
        T_odometry = [k.T_odom_cam for k in self.tracker.keyframes]
        mw = self._finish_multiway(stats, warnings)
        T_kf = mw.T_odom_kf
        T_bundle, scene_map, inertial_up, held = self._adjust(mw, features, T_kf, stats, warnings)
        cloud, rect = self._cloud_and_rectification(T_bundle, inertial_up, stats, warnings)
        W = rect.T_world_odom
        trajectories = self._trajectories(W, T_odometry, T_kf, T_bundle)
        points_w, layout = self._layout(W, cloud, stats)
        stats["finish_cpu_s"] = time.thread_time() - c_finish
        return self._result(
            T_bundle, scene_map, held, rect, points_w, cloud.colors, layout, trajectories, stats, warnings, mw
        )

    def _finish_tracking(self) -> dict[str, float]:
        """Track the skipped frames at the end of the walk; the stats' first entries. ValueError
        with fewer than two usable frames."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self.tracker.flush()  # skipped frames at the end of the walk
        self._t_track += time.perf_counter() - t0
        self._cpu_track += time.thread_time() - c0
        if len(self.tracker.results) < 2:
            raise ValueError(
                f"ego camera: {len(self.tracker.results)} usable RGB-D frame(s); mapping needs at "
                "least 2" + (f" (rejected: {self.rejected})" if self.rejected else "")
            )
        return {
            "frames": self.frames,
            "tracking_s": self._t_track,
            "tracking_cpu_s": self._cpu_track,
        }

    def _frame_warnings(self) -> list[str]:
        """The warnings about the frames: those rejected, those tracked without texture."""
        warnings = [
            f"{n} frame(s) rejected, the first: {self.first_rejection.get(why, why)}"
            for why, n in self.rejected.items()
        ]
        if self.untextured:
            warnings.append(
                f"{self.untextured} frame(s) without texture (covered lens, darkness or a bare wall close "
                "up) tracked by their depth alone"
            )
        return warnings

    def _wait_for_features(self, stats: dict) -> list[KeyframeFeatures]:
        """Every keyframe's features, once the worker thread is through (it is shut down)."""
        t0 = time.perf_counter()
        features: list[KeyframeFeatures] = [f.result() for f in self._features]
        self._features = []  # the list above holds them, until the adjustment
        self._pool.shutdown()
        stats.update(
            feature_wait_s=time.perf_counter() - t0,
            features_cpu_s=self._cpu_features,
            loops_online_cpu_s=self._cpu_loops,
        )
        return features

    def _tracking_stats(self, stats: dict) -> None:
        """The tracker's counts: keyframes, breaks, how frames were tracked, skipped or not."""
        tr = self.tracker
        stats.update(
            keyframes=len(tr.keyframes),
            breaks=tr.breaks,
            recovered=sum(r.status == RECOVERED for r in tr.results),
            imu_bridged=sum(r.status == IMU_BRIDGED for r in tr.results),
            imu_frames=tr.imu_frames,
            degenerate_frames=tr.degenerate_frames,
            suspect_frames=tr.suspect_frames,
            map_relocalised=tr.map_relocalised,
            skipped_frames=tr.skipped,
            backfilled_frames=tr.backfilled,
            untextured_frames=self.untextured,
        )
        if tr.imu is not None:
            stats["imu_samples"] = len(tr.imu)

    def _finish_multiway(self, stats: dict, warnings: list[str]) -> MultiwayResult:
        """The multiway registration's pose-graph optimisation over the whole walk."""
        tr = self.tracker
        t0 = time.perf_counter()
        mw = self._multiway.finish()
        self._multiway = None  # its features and pairs live on in `features` and mw
        if tr.breaks:
            failed = (
                f" (not in the map: {'; '.join(tr.map_failures[:3])}{'; ...' if len(tr.map_failures) > 3 else ''})"
                if tr.map_failures
                else ""
            )
            warnings.append(
                f"odometry lost track {tr.breaks} time(s): {tr.map_relocalised} placed in the map of the "
                f"recent keyframes by their depth{failed}; {mw.relocalised} segment(s) relocalised by "
                "place recognition, the others joined by loop closures or weak constant-velocity edges"
            )
        stats.update(
            multiway_s=time.perf_counter() - t0,
            edges_corrected=mw.edges_corrected,
            loops_tried=mw.loops_tried,
            loops_verified=mw.loops_verified,
            loops_refined=mw.loops_refined,
            loops_kept=mw.loops_kept,
            relocalised=mw.relocalised,
            loops_retrieved=mw.loops_retrieved,
        )
        return mw

    def _adjust(
        self,
        mw: MultiwayResult,
        features: list[KeyframeFeatures],
        T_kf: list[np.ndarray],
        stats: dict,
        warnings: list[str],
    ) -> tuple[list[np.ndarray], SceneMap, np.ndarray | None, np.ndarray]:
        """The visual refinement (``refine_keyframes``, with the IMU's factors where enabled);
        without bundle adjustment the multiway poses, no map and no attitude held."""
        tr, p = self.tracker, self.params
        if not p.bundle_adjustment:
            return T_kf, SceneMap.empty(), None, np.zeros(len(tr.keyframes), bool)
        t0 = time.perf_counter()
        inertial = self._inertial_terms(T_kf, stats, warnings) if p.inertial.bundle_factors else None
        refined = refine_keyframes(
            mw, features, tr.keyframes, T_kf, self.ideal, tr.odometry.K, p, stats, warnings, inertial
        )
        stats["bundle_s"] = time.perf_counter() - t0
        return refined

    def _cloud_and_rectification(
        self, T_bundle: list[np.ndarray], inertial_up: np.ndarray | None, stats: dict, warnings: list[str]
    ) -> tuple[_Cloud, Rectification]:
        """The TSDF cloud and its planar patches, the floor among them and the world frame
        it defines (eq. rot_gp2w), checked against the IMU's gravity."""
        tr, p = self.tracker, self.params
        t0 = time.perf_counter()
        points, colors = fuse_cloud(tr.keyframes, T_bundle, tr.odometry.K, p.cloud)
        cams = np.array([T[:3, 3] for T in T_bundle])
        patches, small, small_normals = planar_patches(points, cams, p.cloud)
        # The IMU's gravity where there is one: a head looking down much of the walk has its mean
        # image-up too far from the vertical for the floor's patches.
        up, up_from = self._up_guess(T_bundle, inertial_up)
        try:
            n, c, support = find_floor(patches, small, small_normals, cams, up, p.cloud)
        except ValueError as exc:
            # No floor plane: fall back to the up direction and the lowest points.
            warnings.append(f"{exc}; using {up_from} instead")
            n = up
            c = small[np.argmin(small @ n)] if len(small) else cams[0] - 1.6 * n
            support = 0
        rect = rectify(n, c, T_bundle[0], support)
        if self._imu_usable():
            self._check_gravity(rect.T_world_odom, T_bundle, inertial_up, stats, warnings)
        stats.update(
            cloud_s=time.perf_counter() - t0,
            cloud_points=len(points),
            patches=len(patches),
            floor_points=support,
            camera_height_m=rect.camera_height_m,
        )
        return _Cloud(points, colors, cams, patches, small, small_normals), rect

    def _trajectories(
        self, W: np.ndarray, T_odometry: list[np.ndarray], T_kf: list[np.ndarray], T_bundle: list[np.ndarray]
    ) -> dict[str, np.ndarray]:
        """Every frame's world pose after each stage: odometry, multiway, bundle (if adjusted)."""
        tr = self.tracker

        def frame_poses(T_keyframes: list[np.ndarray]) -> np.ndarray:
            return W @ frames_between_keyframes(tr.results, tr.edges, tr.keyframes, T_keyframes)

        trajectories = {"odometry": frame_poses(T_odometry), "multiway": frame_poses(T_kf)}
        if self.params.bundle_adjustment:
            trajectories["bundle"] = frame_poses(T_bundle)
        return trajectories

    def _layout(self, W: np.ndarray, cloud: _Cloud, stats: dict) -> tuple[np.ndarray, Layout]:
        """The cloud in the world frame and the layout (walls, floor polygons, ceiling) built from it."""
        points_w = transform_points(W, cloud.points)
        t0 = time.perf_counter()
        layout = build_layout(
            points_w,
            transform_points(W, cloud.small),
            cloud.small_normals @ W[:3, :3].T,
            [q.transformed(W) for q in cloud.patches],
            transform_points(W, cloud.cams),
            self.params.layout,
        )
        stats.update(
            layout_s=time.perf_counter() - t0,
            walls=sum(q.kind == KIND_WALL for q in layout.planes),
            ceiling_height_m=layout.ceiling_height,
        )
        return points_w, layout

    def _result(
        self,
        T_bundle: list[np.ndarray],
        scene_map: SceneMap,
        held: np.ndarray,
        rect: Rectification,
        points_w: np.ndarray,
        colors: np.ndarray,
        layout: Layout,
        trajectories: dict[str, np.ndarray],
        stats: dict[str, float],
        warnings: list[str],
        mw: MultiwayResult,
    ) -> EgoMapResult:
        """The map in the world frame, its observations back in raw pixels for other stages."""
        tr, m, W = self.tracker, scene_map, rect.T_world_odom
        status = np.array([r.status for r in tr.results], dtype="<U16")
        # A frame odometry lost whose segment verified loops tie to the walk (place recognition,
        # loop closures): placed in the map, not a guess.
        starts = tied_segment_starts([k.segment for k in tr.keyframes], mw.edges)
        placed = [tr.keyframes[s0].frame_index for s0 in starts]
        status[placed] = np.where(status[placed] == LOST, MAP_RELOCALISED, status[placed])
        K = self.ideal.K
        raw_uv = self.camera.project(backproject(m.obs_uv, np.ones(len(m.obs_uv)), K))[0] if len(m.obs_uv) else m.obs_uv
        return EgoMapResult(
            camera=self.camera,
            stamps_ns=np.array([r.stamp_ns for r in tr.results], dtype=np.int64),
            T_world_cam=trajectories["bundle" if self.params.bundle_adjustment else "multiway"],
            keyframe_frames=np.array([k.frame_index for k in tr.keyframes], dtype=int),
            T_world_kf=np.array([W @ T for T in T_bundle]),
            landmarks=transform_points(W, m.landmarks) if len(m.landmarks) else m.landmarks,
            descriptors=m.descriptors,
            obs_keyframe=m.obs_keyframe,
            obs_landmark=m.obs_landmark,
            obs_uv=raw_uv,
            cloud_points=points_w,
            cloud_colors=colors,
            layout=layout,
            rectification=rect,
            trajectories=trajectories,
            stats=stats,
            warnings=warnings,
            tracking=status,
            tracking_fitness=np.array([r.fitness for r in tr.results], dtype=float),
            imu=tr.imu_frames > 0,
            attitude_held=held[np.array([r.keyframe for r in tr.results], dtype=int)],
        )

    def _imu_usable(self) -> bool:
        imu = self.tracker.imu
        return imu is not None and imu.calibration is not None and len(imu) >= 2

    def _odom_frames(self, T_kf: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(stamps, odometry-frame poses) of every frame given keyframe poses."""
        tr = self.tracker
        return (
            np.array([r.stamp_ns for r in tr.results], dtype=np.int64),
            frames_between_keyframes(tr.results, tr.edges, tr.keyframes, T_kf),
        )

    def _inertial_terms(self, T_kf: list[np.ndarray], stats: dict, warnings: list[str]) -> InertialTerms | None:
        """The IMU between consecutive keyframes, gravity along the accelerometer's
        mean over the multiway trajectory; None without a usable IMU."""
        if not self._imu_usable():
            return None
        try:
            up = up_from_accelerometer(self.tracker.imu, *self._odom_frames(T_kf))
        except ValueError as exc:
            warnings.append(f"IMU not used in the bundle adjustment: {exc}")
            return None
        terms = keyframe_preintegration(
            self.tracker.imu, np.array([k.stamp_ns for k in self.tracker.keyframes]), up, self.params.inertial
        )
        stats.update(imu_factors=len(terms.between), imu_intervals_skipped=len(terms.skipped))
        return terms

    def _up_guess(self, T_bundle: list[np.ndarray], inertial_up: np.ndarray | None) -> tuple[np.ndarray, str]:
        """The odometry frame's up direction to look for the floor along, and what it is."""
        if self._imu_usable():
            if inertial_up is not None:
                return inertial_up, "the IMU's gravity"
            try:
                return up_from_accelerometer(self.tracker.imu, *self._odom_frames(T_bundle)), "the IMU's gravity"
            except ValueError:
                pass
        return up_from_cameras(T_bundle), "the camera's mean up direction"

    def _check_gravity(
        self, W: np.ndarray, T_bundle: list[np.ndarray], up: np.ndarray | None, stats: dict, warnings: list[str]
    ) -> None:
        """The rectified vertical (the floor's normal) against the IMU's gravity: the
        bundle adjustment's (``up``, its IMU factors' frame: accelerometer bias
        estimated) or else the accelerometer's mean over the final trajectory."""
        if up is None:
            try:
                up = up_from_accelerometer(self.tracker.imu, *self._odom_frames(T_bundle))
            except ValueError as exc:
                warnings.append(f"no gravity check of the floor rectification: {exc}")
                return
        angle = float(np.degrees(np.arccos(np.clip(W[2, :3] @ up, -1.0, 1.0))))
        stats["gravity_imu_angle_deg"] = angle
        limit = self.params.inertial.max_gravity_disagreement_deg
        if angle > limit:
            warnings.append(
                f"the floor rectification's vertical is {angle:.1f} deg from the IMU's gravity (> {limit:g} "
                "deg): the floor plane found may be wrong, or the IMU calibration (T_cam_imu)"
            )


def map_recording(
    frames: Iterable[tuple[int, np.ndarray, np.ndarray]],
    camera: CameraModel,
    params: EgoParams = EgoParams(),
    color_topic: str = "colour",
    depth_topic: str = "depth",
    imu: ImuBuffer | None = None,
) -> EgoMapResult:
    """Offline entry: (stamp_ns, RGB uint8, depth metres) in time order. Unusable
    frames are skipped and reported in the result's warnings. ``imu``: the ego IMU's
    samples, complete or filled while ``frames`` is consumed (up to each frame's stamp
    before the frame is yielded)."""
    mapper = EgoMapper(camera, params, imu=imu)
    t0 = time.perf_counter()
    for stamp_ns, color, depth in frames:
        try:
            mapper.add(stamp_ns, color, depth, color_topic, depth_topic)
        except FrameError:
            pass
    result = mapper.finish()
    result.stats["total_s"] = time.perf_counter() - t0
    return result
