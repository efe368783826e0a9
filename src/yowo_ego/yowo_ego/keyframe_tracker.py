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
(SIFT + depth + PnP RANSAC), which survives head turns of 40 deg between frames and
stands on its own where dense odometry cannot refine it. An accepted result is polished
by a few point-to-plane iterations (removes the photometric term's mm-level bias where
geometry allows). When all fails, the frame is placed in the map of the recent keyframes
by its depth (``yowo_ego.maploc``: a whip turn along bare walls), a keyframe joined by a
"map" edge; if that fails too, it starts a new segment (a "break"), joined to the last by a
weak edge that loop closures may override.

With IMU samples (``imu``, ``OdometryParams.use_imu``) the gyro rotation since the
previous frame, with the constant-velocity translation, is the first initial guess;
a result whose rotation disagrees with the gyro by more than
``max_gyro_disagreement_deg`` is implausible; and a frame no visual attempt tracks
(a bare wall, darkness) is bridged for up to ``max_bridge_s``: the gyro rotation and
the velocity of the last visual step give its pose, it becomes a keyframe joined by
an "imu" edge (same segment) and the next frame is tracked against it. Without IMU
samples every path is the visual one alone.

The fall-backs after dense odometry live in ``recovery``; slow stretches are left out of
dense odometry where the IMU allows (``frame_skipping``).
"""

from __future__ import annotations

from collections import deque

import gtsam
import numpy as np

from yowo_common.geometry import inv_se3, rotation_angle_deg, se3

from .degeneracy import motion_information, remap_degenerate
from .features import FeatureExtractor
from .frame_skipping import FrameSkipping, FrameSource
from .frames import RgbdFrame
from .imu import ImuBuffer
from .odometry import IMU_BRIDGED, LOST, RECOVERED, TRACKED, Keyframe, OdometryEdge, OdometryParams, TrackResult
from .recovery import TrackingRecovery
from .rgbd_odometry import OdometryFrame, OdometryImages, RgbdOdometry, orthonormalize


class KeyframeTracker(FrameSkipping, TrackingRecovery):
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
        self._kf: OdometryFrame | None = None
        self._prev: OdometryFrame | None = None
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

    def track(self, frame: RgbdFrame, images: OdometryImages | None = None) -> TrackResult:
        """``images``: the frame's OdometryImages at ``params.scale`` when already made."""
        return self._process(self._level(len(self.results), frame, images))

    # --- internals --------------------------------------------------------------
    def _level(self, index: int, frame: RgbdFrame, images: OdometryImages | None) -> OdometryFrame:
        im = images if images is not None else OdometryImages.of(frame, self.params.scale)
        return OdometryFrame(
            frame_index=index,
            stamp_ns=frame.stamp_ns,
            color=im.color,
            depth_mm=im.depth_mm,
            rgbd=im.rgbd,
            full_gray=im.full_gray,
            full_depth=frame.depth,
        )

    def _process(self, level: OdometryFrame) -> TrackResult:
        """Track ``level`` into its place in ``results`` (appended, or a skipped frame's)."""
        if self._kf is None:
            self._add_keyframe(level, np.eye(4), None, None)
            result = self._keyframe_result(level, np.eye(4), 1.0, TRACKED)
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

    def _attempts(self, level: OdometryFrame, ref: OdometryFrame, T_ref_prev: np.ndarray, dt_s: float):
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

    def _remap(self, level: OdometryFrame, ref: OdometryFrame, T: np.ndarray, T_pred: np.ndarray) -> np.ndarray:
        """T_ref_cur along the directions its images do not constrain replaced by the
        prediction's (yowo_ego.degeneracy)."""
        d = self.params.degeneracy
        if not d.enabled:
            return T
        info = motion_information(level.color, level.depth_mm, ref.color, ref.depth_mm, self.odometry.K, T, d)
        T, k = remap_degenerate(T, orthonormalize(T_pred), info, d)
        self.degenerate_frames += k > 0
        return orthonormalize(T) if k else T

    def _track(self, level: OdometryFrame) -> TrackResult:
        p = self.params
        prev, prev_res = self._prev, self._prev_result
        dt_s = (level.stamp_ns - prev.stamp_ns) * 1e-9
        kf = self.keyframes[-1]
        T_kf_prev = inv_se3(kf.T_odom_cam) @ prev_res.T_odom_cam
        if dt_s > p.max_track_gap_s:  # no motion model holds, nor the local map's search near the last pose
            self._gyro = None
            return self._break(level, kf, T_kf_prev)
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
            best = self._feature_pose(level, prev, dt_s)
            if best is not None:
                status = RECOVERED
        if best is None and self._gyro is not None and (level.stamp_ns - self._anchor_ns) * 1e-9 <= p.max_bridge_s:
            return self._bridge(level, prev_res, dt_s)
        if best is None:
            return self._untracked(level, prev_res, kf, T_kf_prev, fallback, dt_s)
        T_kf_cur, fitness = best
        T_odom_cam = kf.T_odom_cam @ T_kf_cur
        new_kf = (
            fitness < p.keyframe_fitness
            or np.linalg.norm(T_kf_cur[:3, 3]) > p.keyframe_translation_m
            or rotation_angle_deg(np.eye(3), T_kf_cur[:3, :3]) > p.keyframe_rotation_deg
        )
        if new_kf:
            self._add_keyframe(level, T_odom_cam, kf, T_kf_cur)
            return self._keyframe_result(level, T_odom_cam, fitness, status)
        return TrackResult(
            frame_index=level.frame_index,
            stamp_ns=level.stamp_ns,
            keyframe=kf.index,
            T_kf_cam=T_kf_cur,
            T_odom_cam=T_odom_cam,
            fitness=fitness,
            status=status,
            new_keyframe=False,
        )

    def _keyframe_result(
        self, level: OdometryFrame, T_odom_cam: np.ndarray, fitness: float, status: str
    ) -> TrackResult:
        """The result of a frame that just became the last keyframe."""
        return TrackResult(
            frame_index=level.frame_index,
            stamp_ns=level.stamp_ns,
            keyframe=len(self.keyframes) - 1,
            T_kf_cam=np.eye(4),
            T_odom_cam=T_odom_cam,
            fitness=fitness,
            status=status,
            new_keyframe=True,
        )

    def _add_keyframe(
        self,
        level: OdometryFrame,
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
            T, R_gyro = T_prev_cur, None
            if given is not None:
                kind, info = given
            else:
                R_gyro = self._gyro_rotation(previous.stamp_ns, level.stamp_ns)
                if T_prev_cur is not None:
                    kind, info = "odometry", self.odometry.information(level.depth_mm, previous.depth_mm, T_prev_cur)
                else:
                    # Unknown motion: a weak edge keeps the graph connected (1 m, ~30 deg sigma).
                    kind, info = "break", np.diag([1.0] * 6)
                    T = inv_se3(previous.T_odom_cam) @ T_odom_cam
            edge = OdometryEdge(
                source=kf.index, target=previous.index, T_target_source=T, information=info, kind=kind, R_gyro=R_gyro
            )
            self.edges.append(edge)
        if self.on_keyframe is not None:
            self.on_keyframe(kf, edge, level.full_gray, level.full_depth)
        self._kf = level
