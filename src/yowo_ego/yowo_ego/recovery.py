"""Frames dense odometry against the keyframe does not track (``keyframe_tracker``): a
feature guess (SIFT + depth + PnP RANSAC) refined densely or standing on its own; with the
IMU a bridge on the gyro; a placement in the map of the recent keyframes by the frame's depth
(``yowo_ego.maploc``); and at last a tracking break."""

from __future__ import annotations

import numpy as np

from yowo_common.geometry import inv_se3, se3

from .features import pose_from_images
from .maploc import MapLocResult, map_cloud, relocalise, up_direction
from .odometry import IMU_BRIDGED, LOST, MAP_RELOCALISED, Keyframe, TrackResult
from .rgbd_odometry import OdometryFrame, orthonormalize


class TrackingRecovery:
    """The recovery of KeyframeTracker, which holds its state."""

    def _feature_pose(self, level: OdometryFrame, prev: OdometryFrame, dt_s: float) -> tuple[np.ndarray, float] | None:
        """(T_kf_cur, fitness) from the feature guess against the previous frame, refined
        densely where dense odometry accepts it; None without a plausible guess."""
        p = self.params
        guess = pose_from_images(
            level.full_gray, level.full_depth, prev.full_gray, prev.full_depth, self.odometry.K_full, self._features
        )
        if guess is None or not self._plausible(guess, dt_s):
            return None
        for cascade in p.cascades:
            T, fit, rmse = self.odometry.register(level.rgbd, self._kf.rgbd, guess, cascade)
            if fit >= p.min_fitness and rmse <= p.max_inlier_rmse and self._plausible(T, dt_s):
                return T, fit
        # Dense odometry cannot refine it (degenerate geometry: a corner of two
        # walls); the feature pose stands, as a keyframe (fitness 0) whose edge
        # the multiway registration checks again.
        return guess, 0.0

    def _untracked(
        self,
        level: OdometryFrame,
        prev_res: TrackResult,
        kf: Keyframe,
        T_kf_prev: np.ndarray,
        fallback: tuple[np.ndarray, float, float] | None,
        dt_s: float,
    ) -> TrackResult:
        """No attempt tracked the frame: a keyframe placed in the map of the recent keyframes,
        else a break: a new keyframe and segment, joined to the last by a weak edge from the
        least bad attempt (or the constant-velocity prediction); loop closures may tie the
        segments together properly later."""
        p = self.params
        placed = self._map_pose(level, prev_res, dt_s)
        if placed is not None:
            T_odom_cam, m = placed.T_odom_cam, p.maploc
            info = np.diag([np.radians(m.sigma_deg) ** -2] * 3 + [m.sigma_m**-2] * 3)
            self._add_keyframe(level, T_odom_cam, kf, inv_se3(kf.T_odom_cam) @ T_odom_cam, ("map", info))
            return self._keyframe_result(level, T_odom_cam, placed.fitness, MAP_RELOCALISED)
        return self._break(level, kf, fallback[0] if fallback is not None else T_kf_prev @ self._predicted_step(dt_s))

    def _break(self, level: OdometryFrame, kf: Keyframe, T_kf_cur: np.ndarray) -> TrackResult:
        """A new keyframe and segment at the guess T_kf_cur, joined to the last by a weak edge."""
        T_odom_cam = kf.T_odom_cam @ orthonormalize(T_kf_cur)
        self.breaks += 1
        self._add_keyframe(level, T_odom_cam, kf, None)
        return self._keyframe_result(level, T_odom_cam, 0.0, LOST)

    def _map_pose(self, level: OdometryFrame, prev_res: TrackResult, dt_s: float) -> MapLocResult | None:
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

    def _bridge(self, level: OdometryFrame, prev_res: TrackResult, dt_s: float) -> TrackResult:
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
        return self._keyframe_result(level, T_odom_cam, 0.0, IMU_BRIDGED)
