"""A/B of per-frame RGB-D odometry on one recording (issue #47): the ego stage's present
tracker against plain compiled frame-to-frame odometry, on the same frames, one core.

Trackers (``--trackers``, default all that apply):

- ``dense``: the ego stage's ``KeyframeTracker`` as the ego mapper runs it (frame to keyframe,
  checks and fall-backs, polish, degeneracy remapping, gyro prediction and frame skipping with
  the IMU), without keyframe features and loop closures.
- ``dense_every_frame``: the same with frame skipping off (with the IMU only; without it
  every frame is tracked anyway).
- ``o3d_<method>_<scale>``: Open3D's tensor ``rgbd_odometry_multi_scale`` frame to frame,
  10/5/3 iterations and Open3D's default relative tolerance, at 1/scale resolution, chained;
  the initial transform the gyro's rotation (with its running bias) and the last step's
  translation, without the IMU the last step (constant velocity). A frame Open3D gives up on
  takes the initial transform.
- ``cv_rgbd_1``: OpenCV's ``cv.Odometry`` (RGB-D, its default settings) frame to frame at full
  resolution, chained; left out when the installed cv2 has no ``Odometry``.

Per tracker: CPU time of each frame (``time.process_time``; the frame's own image preparation
counts, decoding and undistortion do not), the ATE RMSE of the chained trajectory after an
SE(3) alignment to the ground truth, and the relative pose error between consecutive frames.
Only this evaluation reads the recording's ground truth.

    python -m yowo_eval.odometry_ab BAG [--no-imu] [--trackers dense o3d_hybrid_2] --json OUT
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from dataclasses import replace

import cv2
import numpy as np
import open3d as o3d

from yowo_common.geometry import inv_se3, rotation_angle_deg, se3
from yowo_common.trajectory import Trajectory
from yowo_ego.config import EgoParams
from yowo_ego.frames import FrameError, RgbdFrame, Undistorter, make_frame
from yowo_ego.imu import ImuBuffer
from yowo_ego.keyframe_tracker import KeyframeTracker
from yowo_ego.odometry import OdometryParams
from yowo_ego.recording import EgoRecording, find_ego_topics, read_ego_frames
from yowo_ego.rgbd_odometry import OdometryImages, RgbdOdometry, downsample, o3d_rgbd

from .ground_truth import read_ground_truth
from .metrics import associate, ate

# Open3D's documented example criteria per pyramid level, coarse to fine.
O3D_ITERATIONS = (10, 5, 3)
O3D_RELATIVE_TOLERANCE = 1e-6  # Open3D's default: the levels run to their maximum


class DenseTracker:
    """The ego stage's tracker, fed as ``EgoMapper.add`` feeds it."""

    def __init__(self, K: np.ndarray, params: OdometryParams, imu: ImuBuffer | None):
        self.tracker = KeyframeTracker(K, params, imu=imu)

    def step(self, frame: RgbdFrame) -> None:
        t = self.tracker
        if t.skips(frame.stamp_ns):
            t.skip(frame.stamp_ns, lambda: (frame, OdometryImages.of(frame, t.params.scale)))
        else:
            t.track(frame)

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        self.tracker.flush()
        results = self.tracker.results
        return np.array([r.stamp_ns for r in results]), np.array([r.T_odom_cam for r in results])


class ChainedTracker:
    """Frame-to-frame odometry chained into a trajectory; subclasses give ``images`` and
    ``register`` (T_prev_cur from an initial guess, None when the library gives up). With the
    IMU the gyro's rotation (and a running bias of this tracker's own) seeds each step."""

    def __init__(self, imu: ImuBuffer | None, params: OdometryParams):
        self.imu, self.params = imu, params
        self.bias = np.zeros(3)
        self.failures = 0
        self._prev = None
        self._stamps: list[int] = []
        self._poses: list[np.ndarray] = []
        self._step = np.eye(4)

    def _gyro(self, t0_ns: int, t1_ns: int) -> np.ndarray | None:
        if self.imu is None:
            return None
        shared, self.imu.bias = self.imu.bias, self.bias
        try:
            return self.imu.rotation_between(t0_ns, t1_ns)
        except ValueError:
            return None
        finally:
            self.imu.bias = shared

    def _update_bias(self, R: np.ndarray, t0_ns: int, t1_ns: int) -> None:
        shared, self.imu.bias = self.imu.bias, self.bias
        try:
            self.imu.update_bias(R, t0_ns, t1_ns, self.params.gyro_bias_time_constant_s)
            self.bias = self.imu.bias
        finally:
            self.imu.bias = shared

    def step(self, frame: RgbdFrame) -> None:
        cur = self.images(frame)
        if self._prev is None:
            T = np.eye(4)
        else:
            t0 = self._stamps[-1]
            R_gyro = self._gyro(t0, frame.stamp_ns)
            init = self._step if R_gyro is None else se3(R_gyro, self._step[:3, 3])
            step = self.register(cur, self._prev, init)
            if step is None:
                self.failures += 1
                step = init
            elif R_gyro is not None:
                self._update_bias(step[:3, :3], t0, frame.stamp_ns)
            self._step = step
            T = self._poses[-1] @ step
        self._prev = cur
        self._stamps.append(frame.stamp_ns)
        self._poses.append(T)

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self._stamps), np.array(self._poses)


class Open3dTracker(ChainedTracker):
    """Open3D's tensor multi-scale RGB-D odometry through the ego stage's wrapper (its
    images, padding and intrinsics), one method, no checks."""

    def __init__(self, K: np.ndarray, imu: ImuBuffer | None, params: OdometryParams, method: str, scale: int):
        super().__init__(imu, params)
        self.scale, self.method = scale, method
        self.odometry = RgbdOdometry(
            K, replace(params, scale=scale, iterations=O3D_ITERATIONS, relative_tolerance=O3D_RELATIVE_TOLERANCE)
        )

    def images(self, frame: RgbdFrame):
        return o3d_rgbd(*downsample(frame, self.scale))

    def register(self, cur, prev, init: np.ndarray) -> np.ndarray | None:
        T, fitness, _ = self.odometry.register(cur, prev, init, (self.method,))
        return T if fitness > 0 else None


class OpenCvTracker(ChainedTracker):
    """OpenCV's ``cv.Odometry`` (RGB-D, common algorithm, default settings) at full resolution.
    Its ``compute`` takes no initial transform, so the gyro cannot seed it."""

    def __init__(self, K: np.ndarray, imu: ImuBuffer | None, params: OdometryParams):
        super().__init__(None, params)
        settings = cv2.OdometrySettings()
        settings.setCameraMatrix(np.asarray(K, dtype=np.float32))
        settings.setMaxDepth(params.depth_max_m)
        self.odometry = cv2.Odometry(cv2.OdometryType_RGB_DEPTH, settings, cv2.OdometryAlgoType_COMMON)

    def images(self, frame: RgbdFrame):
        gray = cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY)
        depth = np.nan_to_num(frame.depth, nan=0.0)
        odometry_frame = cv2.OdometryFrame(depth, gray)
        self.odometry.prepareFrame(odometry_frame)
        return odometry_frame, depth, gray  # the frame refers to the arrays' memory, not a copy

    def register(self, cur, prev, init: np.ndarray) -> np.ndarray | None:
        ok, Rt = self.odometry.compute(cur[0], prev[0])  # Rt maps the source frame's points into the destination's
        return np.asarray(Rt, dtype=float) if ok and np.isfinite(Rt).all() else None


def opencv_odometry_available() -> bool:
    return all(hasattr(cv2, n) for n in ("Odometry", "OdometryFrame", "OdometrySettings"))


def make_trackers(names: list[str] | None, K: np.ndarray, imu: ImuBuffer | None, params: OdometryParams) -> dict:
    """name -> tracker; unknown names raise ValueError."""
    factories = {"dense": lambda: DenseTracker(K, params, imu)}
    if imu is not None:
        factories["dense_every_frame"] = lambda: DenseTracker(
            K, replace(params, skip=replace(params.skip, enabled=False)), imu
        )
    for method in ("hybrid", "intensity"):
        for scale in (1, 2, 4):
            factories[f"o3d_{method}_{scale}"] = lambda m=method, s=scale: Open3dTracker(
                K, imu, params, m.capitalize(), s
            )
    if opencv_odometry_available():
        factories["cv_rgbd_1"] = lambda: OpenCvTracker(K, imu, params)
    unknown = sorted(set(names or []) - factories.keys())
    if unknown:
        raise ValueError(f"unknown or unavailable trackers {unknown}; have {sorted(factories)}")
    return {n: f() for n, f in factories.items() if names is None or n in names}


def relative_pose_error(stamps_ns: np.ndarray, poses: np.ndarray, ref: Trajectory) -> dict[str, float]:
    """Error of each consecutive frame pair's relative pose (both frames with a ground-truth
    pose within 10 ms): translation RMSE [m], rotation mean [deg]."""
    i_est, i_ref = associate(stamps_ns, ref.stamps_ns, 10_000_000)
    pairs = np.flatnonzero(np.diff(i_est) == 1)
    trans, rot = [], []
    for k in pairs:
        a, b = i_est[k], i_est[k + 1]
        est = inv_se3(poses[a]) @ poses[b]
        true = inv_se3(ref.T_world_cam[i_ref[k]]) @ ref.T_world_cam[i_ref[k + 1]]
        error = inv_se3(true) @ est
        trans.append(np.linalg.norm(error[:3, 3]))
        rot.append(rotation_angle_deg(np.eye(3), error[:3, :3]))
    return {
        "rpe_trans_rmse_m": float(np.sqrt(np.mean(np.square(trans)))) if trans else float("nan"),
        "rpe_rot_mean_deg": float(np.mean(rot)) if rot else float("nan"),
        "rpe_pairs": len(trans),
    }


def run(
    bag,
    use_imu: bool = True,
    trackers: list[str] | None = None,
    params: EgoParams = EgoParams(),
    max_frames: int | None = None,
) -> dict:
    """Every tracker on the recording's ego frames (the first ``max_frames``), in lockstep
    (one pass over the bag): per tracker its CPU times and trajectory errors."""
    o3d.utility.set_max_threads(params.open3d_threads)
    cv2.setNumThreads(1)  # the same single core as Open3D
    odometry = replace(params.odometry, use_imu=use_imu)
    recording = EgoRecording(find_ego_topics(bag))
    if use_imu and recording.topics.has_imu:
        recording.imu = ImuBuffer()
    frames = read_ego_frames(bag, recording, odometry.imu_wait_s)
    first = next(frames, None)
    if first is None or recording.camera is None:
        raise ValueError(f"{bag}: no usable ego frames")
    camera = recording.camera
    undistort = Undistorter(camera)
    runners = make_trackers(trackers, camera.K, recording.imu, odometry)
    cpu: dict[str, list[float]] = {n: [] for n in runners}
    for stamp_ns, color, depth in itertools.islice(itertools.chain([first], frames), max_frames):
        try:
            frame = make_frame(stamp_ns, color, depth, camera, undistort)
        except FrameError:
            continue
        for name, tracker in runners.items():
            c0 = time.process_time()
            tracker.step(frame)
            cpu[name].append(time.process_time() - c0)
    gt = read_ground_truth(bag).ego
    if gt is None:
        raise ValueError(f"{bag}: no /gt/ego/pose; the A/B needs ground truth")
    out = {"bag": str(bag), "imu": recording.imu is not None, "trackers": {}}
    for name, tracker in runners.items():
        c0 = time.process_time()
        stamps, poses = tracker.finish()
        cpu[name][-1] += time.process_time() - c0
        times = np.array(cpu[name])
        out["trackers"][name] = {
            "frames": len(times),
            "cpu_total_s": float(times.sum()),
            "cpu_ms_median": float(np.median(times) * 1e3),
            "cpu_ms_mean": float(times.mean() * 1e3),
            "ate_m": ate(Trajectory(stamps, poses), gt).rmse_m,
            **relative_pose_error(stamps, poses, gt),
            "failures": getattr(tracker, "failures", 0),
        }
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m yowo_eval.odometry_ab", description=__doc__.split("\n\n")[0])
    parser.add_argument("bag")
    parser.add_argument("--no-imu", action="store_true", help="track without the recording's IMU")
    parser.add_argument("--trackers", nargs="+", help="which trackers (default: every one that applies)")
    parser.add_argument("--max-frames", type=int, help="only the first N frames")
    parser.add_argument("--json", help="write the results to this file")
    args = parser.parse_args(argv)
    if not opencv_odometry_available():
        print("cv2 has no Odometry: OpenCV's RGB-D odometry left out", flush=True)
    result = run(args.bag, not args.no_imu, args.trackers, max_frames=args.max_frames)
    print(f"{args.bag} ({'IMU' if result['imu'] else 'no IMU'}):")
    print("tracker | frames | CPU ms/frame median / mean | total CPU s | ATE m | RPE m / deg | failures")
    for name, m in result["trackers"].items():
        print(
            f"{name} | {m['frames']} | {m['cpu_ms_median']:.1f} / {m['cpu_ms_mean']:.1f} | {m['cpu_total_s']:.1f} | "
            f"{m['ate_m']:.4f} | {m['rpe_trans_rmse_m']:.4f} / {m['rpe_rot_mean_deg']:.3f} | {m['failures']}",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
