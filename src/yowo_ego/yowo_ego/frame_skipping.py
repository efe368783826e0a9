"""Motion-adaptive frame rate (``OdometryParams.skip``, issue #19): with the IMU, a frame
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

from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.geometry import inv_se3, rotation_angle_deg, se3

from .frames import RgbdFrame
from .odometry import INTERPOLATED, RECOVERED, SKIPPED, TRACKED, TrackResult
from .rgbd_odometry import OdometryImages, orthonormalize

# Makes a skipped frame's images after all (the frame after it did not track at its first
# attempts); None when the frame turns out unusable.
FrameSource = Callable[[], "tuple[RgbdFrame, OdometryImages] | None"]


class FrameSkipping:
    """The frame skipping of KeyframeTracker, which holds its state: which frames to leave
    out, their interpolated poses, and tracking them after all."""

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
            frame_index=len(self.results),
            stamp_ns=stamp_ns,
            keyframe=prev.keyframe,
            T_kf_cam=prev.T_kf_cam.copy(),
            T_odom_cam=prev.T_odom_cam.copy(),
            fitness=prev.fitness,
            status=SKIPPED,
            new_keyframe=False,
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
                # A head turn is not uniform over two frames: a slerp misses part of it.
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
