"""The ego camera's IMU (/ego/imu) for tracking: its samples, its calibration
(/ego/imu/calibration, Kalibr-style YAML) and the gyro rotation between two camera
stamps in the camera frame.

``ImuBuffer.rotation_between`` integrates the gyro (minus the current bias estimate)
between two stamps: the signal is linear between samples, each piece is integrated at
its midpoint (scipy ``Rotation``), and the IMU-frame rotation is turned into the
camera's by T_cam_imu's rotation. The bias starts at zero (a consumer IMU's turn-on
bias, ~0.2 deg/s, costs 0.2 deg over a 1 s bridge) and follows the visually tracked
rotations as a running mean (``update_bias``): each tracked step's disagreement with
the gyro, divided by its duration, is the bias error it implies; the estimate moves by
that times dt / time_constant (an exponential mean over ``time_constant`` seconds).

Samples are appended as they arrive (by the recording's reader thread or the node)
and read by the tracker: appends go into a pre-allocated array under a lock, and a
rotation only ever uses the samples up to the first one at or after its end stamp,
so it does not depend on how far ahead the appending is once the interval is covered.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field

import gtsam
import numpy as np
import yaml
from scipy.spatial.transform import Rotation, Slerp

from yowo_common.topics import EGO_IMU_CALIBRATION

# Samples further apart than this (or 5 sample periods, if longer) are a gap in the IMU
# stream: no rotation is integrated across it.
MAX_GAP_S = 0.05
# An implied bias error above this is a visual error, not bias: consumer MEMS gyros
# (BMI055, BMI088, ICM-42688) specify turn-on offsets of at most 1-3 deg/s.
MAX_BIAS_ERROR_RADPS = np.radians(2.0)


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples in the IMU's own frame, stamps strictly increasing."""

    stamps_ns: np.ndarray  # (N,) int64
    gyro: np.ndarray  # (N, 3) angular velocity [rad/s]
    accel: np.ndarray  # (N, 3) specific force [m/s^2]

    def __post_init__(self):
        n = len(self.stamps_ns)
        if np.shape(self.gyro) != (n, 3) or np.shape(self.accel) != (n, 3):
            raise ValueError(
                f"IMU samples: {n} stamps but gyro {np.shape(self.gyro)}, accel "
                f"{np.shape(self.accel)} (expected ({n}, 3))"
            )
        if n > 1 and not np.all(np.diff(self.stamps_ns) > 0):
            raise ValueError("IMU samples: stamps are not strictly increasing")


@dataclass(frozen=True, kw_only=True)
class ImuCalibration:
    """/ego/imu/calibration: Kalibr's imu.yaml noise model (continuous-time densities) and
    its camchain-imucam extrinsics. T_cam_imu maps IMU-frame points to the camera's
    optical frame; timeshift_cam_imu: t_imu = t_cam + shift."""

    T_cam_imu: np.ndarray
    gyroscope_noise_density: float  # rad/s/sqrt(Hz)
    gyroscope_random_walk: float  # rad/s^2/sqrt(Hz)
    accelerometer_noise_density: float  # m/s^2/sqrt(Hz)
    accelerometer_random_walk: float  # m/s^3/sqrt(Hz)
    update_rate_hz: float
    timeshift_cam_imu_s: float = 0.0

    @staticmethod
    def from_yaml(text: str, topic: str = EGO_IMU_CALIBRATION) -> ImuCalibration:
        """Parse the calibration text; ValueError naming ``topic`` and the field when it
        is malformed."""
        try:
            doc = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"{topic}: not YAML: {exc}") from exc
        if not isinstance(doc, dict):
            raise ValueError(f"{topic}: expected a YAML mapping, got {type(doc).__name__}")
        missing = [
            k
            for k in (
                "T_cam_imu",
                "gyroscope_noise_density",
                "gyroscope_random_walk",
                "accelerometer_noise_density",
                "accelerometer_random_walk",
                "update_rate",
            )
            if k not in doc
        ]
        if missing:
            raise ValueError(f"{topic}: missing {', '.join(missing)}")
        try:
            T = np.array(doc["T_cam_imu"], dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{topic}: T_cam_imu is not a 4x4 matrix of numbers: {exc}") from exc
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"{topic}: T_cam_imu must be a finite 4x4 matrix, got shape {T.shape}")
        R = T[:3, :3]
        if (
            not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0))
            or not np.allclose(R @ R.T, np.eye(3), atol=1e-6)
            or np.linalg.det(R) < 0
        ):
            raise ValueError(
                f"{topic}: T_cam_imu is not a rigid transform (rotation block not orthonormal "
                "with det +1, or last row not 0 0 0 1)"
            )

        def number(key: str, default=None, positive: bool = False) -> float:
            value = doc.get(key, default)
            try:
                value = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"{topic}: {key} must be a number, got {value!r}") from None
            if not np.isfinite(value) or value < 0 or (positive and value == 0):
                raise ValueError(f"{topic}: {key} must be {'> 0' if positive else '>= 0'}, got {value}")
            return value

        shift = doc.get("timeshift_cam_imu", 0.0)
        try:
            shift = float(shift)
        except (TypeError, ValueError):
            raise ValueError(f"{topic}: timeshift_cam_imu must be a number, got {shift!r}") from None
        return ImuCalibration(
            T_cam_imu=T,
            gyroscope_noise_density=number("gyroscope_noise_density"),
            gyroscope_random_walk=number("gyroscope_random_walk"),
            accelerometer_noise_density=number("accelerometer_noise_density"),
            accelerometer_random_walk=number("accelerometer_random_walk"),
            update_rate_hz=number("update_rate", positive=True),
            timeshift_cam_imu_s=shift,
        )


class ImuUniter:
    """Separate gyro and accelerometer streams (a driver's at different rates) as one: each
    gyro sample with the accelerometer interpolated linearly at its stamp, as
    realsense2_camera's unite_imu_method=linear_interpolation publishes them. A gyro sample
    is released once an accelerometer sample at or after its stamp has arrived; gyro samples
    before the first accelerometer sample have nothing to pair with and are counted."""

    def __init__(self):
        self._gyro: deque[tuple[int, tuple]] = deque()
        self._accel: deque[tuple[int, tuple]] = deque(maxlen=64)
        self.unpaired = 0

    def add_gyro(self, stamp_ns: int, gyro) -> list[tuple[int, tuple, tuple]]:
        self._gyro.append((stamp_ns, tuple(gyro)))
        return self._release()

    def add_accel(self, stamp_ns: int, accel) -> list[tuple[int, tuple, tuple]]:
        if self._accel and stamp_ns <= self._accel[-1][0]:
            return []
        self._accel.append((stamp_ns, tuple(accel)))
        return self._release()

    def _release(self) -> list[tuple[int, tuple, tuple]]:
        out = []
        while self._gyro and self._accel and self._gyro[0][0] <= self._accel[-1][0]:
            t, w = self._gyro.popleft()
            stamps = [s for s, _ in self._accel]
            if t < stamps[0]:
                self.unpaired += 1
                continue
            k = max(1, int(np.searchsorted(stamps, t, side="left")))
            (t0, a0), (t1, a1) = self._accel[k - 1], self._accel[min(k, len(stamps) - 1)]
            f = 0.0 if t1 == t0 else (t - t0) / (t1 - t0)
            out.append((t, w, tuple(float(x0 + f * (x1 - x0)) for x0, x1 in zip(a0, a1))))
        return out


class ImuBuffer:
    """The IMU samples of a walk as they arrive, the calibration (None until known) and
    the running gyro bias estimate (IMU frame, rad/s)."""

    def __init__(self, calibration: ImuCalibration | None = None, capacity: int = 4096):
        self.calibration = calibration
        self.bias = np.zeros(3)
        self.rejected = 0  # samples not after the previous one (dropped)
        self._stamps = np.zeros(capacity, dtype=np.int64)
        self._data = np.zeros((capacity, 6))
        self._n = 0
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return self._n

    def add(self, stamp_ns: int, gyro, accel) -> None:
        with self._lock:
            if self._n and stamp_ns <= self._stamps[self._n - 1]:
                self.rejected += 1
                return
            if self._n == len(self._stamps):  # grow: readers keep views of the old arrays
                self._stamps = np.concatenate([self._stamps, np.zeros_like(self._stamps)])
                self._data = np.concatenate([self._data, np.zeros_like(self._data)])
            self._stamps[self._n] = stamp_ns
            self._data[self._n, :3], self._data[self._n, 3:] = gyro, accel
            self._n += 1

    def extend(self, samples: ImuSamples) -> None:
        for s, g, a in zip(samples.stamps_ns, samples.gyro, samples.accel):
            self.add(int(s), g, a)

    @property
    def samples(self) -> ImuSamples:
        stamps, data = self._view()
        return ImuSamples(stamps.copy(), data[:, :3].copy(), data[:, 3:].copy())

    def _view(self) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            return self._stamps[: self._n], self._data[: self._n]

    def _imu_ns(self, t_cam_ns: int) -> int:
        return int(t_cam_ns + round(self.calibration.timeshift_cam_imu_s * 1e9))

    def covers(self, t_cam_ns: int) -> bool:
        """Calibrated, and a sample at or after camera stamp ``t_cam_ns`` has arrived."""
        if self.calibration is None:
            return False
        stamps, _ = self._view()
        return len(stamps) > 0 and stamps[-1] >= self._imu_ns(t_cam_ns)

    def _interval(self, t0_ns: int, t1_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """(knots [ns], IMU stamps: t0, the samples strictly between, t1; the signal
        (gyro, accel) (n, 6) at the knots, linear between samples) between camera
        stamps t0 < t1. ValueError when uncalibrated, not covered or across a gap."""
        if self.calibration is None:
            raise ValueError(f"no IMU calibration ({EGO_IMU_CALIBRATION}) yet")
        if t1_ns <= t0_ns:
            raise ValueError(f"IMU interval: end stamp {t1_ns} ns not after the start {t0_ns} ns")
        a, b = self._imu_ns(t0_ns), self._imu_ns(t1_ns)
        stamps, data = self._view()
        if not len(stamps) or stamps[0] > a or stamps[-1] < b:
            span = f"{stamps[0]}..{stamps[-1]} ns" if len(stamps) else "none"
            raise ValueError(f"IMU samples do not cover {a}..{b} ns (have {span})")
        i0 = int(np.searchsorted(stamps, a, side="right")) - 1  # last sample at or before a
        i1 = int(np.searchsorted(stamps, b, side="left"))  # first at or after b
        s = stamps[i0 : i1 + 1]
        gap = max(MAX_GAP_S, 5.0 / self.calibration.update_rate_hz) * 1e9
        if np.diff(s).max() > gap:
            raise ValueError(f"IMU samples have a gap of {np.diff(s).max() * 1e-9:.3f} s within {a}..{b} ns")
        knots = np.concatenate([[a], s[(s > a) & (s < b)], [b]])
        return knots, np.column_stack([np.interp(knots, s, data[i0 : i1 + 1, k]) for k in range(6)])

    def _imu_rotation(self, t0_ns: int, t1_ns: int) -> np.ndarray:
        """R_imu0_imu1 from the bias-corrected gyro between camera stamps t0 < t1."""
        knots, signal = self._interval(t0_ns, t1_ns)
        w = signal[:, :3]
        steps = Rotation.from_rotvec((0.5 * (w[1:] + w[:-1]) - self.bias) * (np.diff(knots) * 1e-9)[:, None])
        R = np.eye(3)
        for step in steps.as_matrix():  # matrix products: scipy's per-step composition cost ~1 ms a frame
            R = R @ step
        return R

    def preintegrate(
        self, t0_ns: int, t1_ns: int, params: gtsam.PreintegrationCombinedParams, bias: gtsam.imuBias.ConstantBias
    ) -> gtsam.PreintegratedCombinedMeasurements:
        """GTSAM's combined preintegration between camera stamps t0 < t1 of the motion
        of the camera's origin, in the IMU's orientation (``params``' body_P_sensor is
        T_cam_imu's rotation alone): the specific force is moved along the lever arm r
        (IMU -> camera) by alpha x r + omega x (omega x r) here, as GTSAM corrects the
        centripetal term only and a head turn's angular acceleration (~50 rad/s^2 over
        a 2 cm arm: 1 m/s^2) is not negligible. Each piece between knots enters at its
        midpoint value. ValueError as ``rotation_between``."""
        knots, signal = self._interval(t0_ns, t1_ns)
        t = knots * 1e-9
        w, f = signal[:, :3], signal[:, 3:]
        alpha = np.gradient(w, t - t[0], axis=0) if len(t) > 2 else np.zeros_like(w)
        T = self.calibration.T_cam_imu
        r = -T[:3, :3].T @ T[:3, 3]
        f = f + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
        mid_w, mid_f = 0.5 * (w[1:] + w[:-1]), 0.5 * (f[1:] + f[:-1])
        pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
        for wi, fi, dt in zip(mid_w, mid_f, np.diff(t)):
            if dt > 0:
                pim.integrateMeasurement(fi, wi, dt)
        return pim

    def rotation_between(self, t0_ns: int, t1_ns: int) -> np.ndarray:
        """R_cam0_cam1: the camera's rotation from camera stamp t0 to t1 (maps camera-1
        coordinates to camera-0's), from the gyro with the bias estimate removed.
        ValueError when uncalibrated or the samples do not cover the interval."""
        R = self._imu_rotation(t0_ns, t1_ns)
        R_ci = self.calibration.T_cam_imu[:3, :3]
        return R_ci @ R @ R_ci.T

    def update_bias(self, R_cam0_cam1: np.ndarray, t0_ns: int, t1_ns: int, time_constant_s: float) -> None:
        """Move the bias estimate towards what an observed (visually tracked) rotation
        between t0 and t1 implies; an implied bias error above MAX_BIAS_ERROR_RADPS is
        taken as a visual error and ignored."""
        dt = (t1_ns - t0_ns) * 1e-9
        if dt <= 0 or time_constant_s <= 0:
            return
        R_ci = self.calibration.T_cam_imu[:3, :3]
        R_gyro = self._imu_rotation(t0_ns, t1_ns)
        R_seen = R_ci.T @ R_cam0_cam1 @ R_ci
        # R_gyro = R_true exp(b_error dt) to first order: the residual is the bias error's effect.
        error = Rotation.from_matrix(R_seen.T @ R_gyro).as_rotvec() / dt
        if np.linalg.norm(error) <= MAX_BIAS_ERROR_RADPS:
            self.bias = self.bias + error * min(1.0, dt / time_constant_s)


class CoverageWait:
    """Frames held until the IMU covers their stamp: ``push`` a frame, ``ready`` gives
    those that can be tracked now, in order. A frame goes without the IMU when no IMU
    is to be waited for (``imu`` None), on ``flush`` (the end of the stream), or, with
    ``max_wait_ns``, once a frame more than that newer has arrived (the IMU stalled or
    ended). That bound suits a stream in a fixed order (a recording read in log order);
    where topics arrive in no common order it would depend on timing (None: none)."""

    def __init__(self, imu: ImuBuffer | None, max_wait_ns: int | None):
        self.imu, self.max_wait_ns = imu, max_wait_ns
        self._held: deque = deque()
        self.released_without = 0  # frames that went on before the IMU covered them

    def push(self, stamp_ns: int, item) -> list:
        self._held.append((stamp_ns, item))
        return self.ready()

    def ready(self, flush: bool = False) -> list:
        out = []
        while self._held:
            stamp, item = self._held[0]
            covered = self.imu is None or self.imu.covers(stamp)
            late = self.max_wait_ns is not None and self._held[-1][0] - stamp > self.max_wait_ns
            if not (covered or flush or late):
                break
            self.released_without += not covered
            out.append(self._held.popleft()[1])
        return out


@dataclass(frozen=True)
class InertialParams:
    """The IMU beyond tracking: its factors in the ego bundle adjustment and the
    gravity check of the floor rectification (used when the recording has an IMU and
    ``OdometryParams.use_imu``)."""

    bundle_factors: bool = True  # IMU factors (CombinedImuFactor) between consecutive keyframes
    gravity_mps2: float = 9.81  # gravity's magnitude
    # Sigma of the accelerometer bias prior at each chain's first keyframe. Consumer MEMS
    # turn-on offsets (BMI055/BMI088, ICM-42688 datasheets) reach tens of mg.
    accel_bias_prior_mps2: float = 0.3
    # Sigma of the gyro bias prior at each chain's first keyframe, about the tracker's running
    # estimate. Consumer MEMS gyros are specified to a few deg/s.
    gyro_bias_prior_radps: float = 0.01
    # Preintegration's position integration noise (GTSAM's integration covariance) [m/s/√Hz].
    integration_sigma: float = 1e-4
    # The map may tilt this much (a loose prior) in the bundle adjustment for the IMU's gravity.
    tilt_prior_deg: float = 5.0
    # Angle between the floor rectification's vertical and the accelerometer's gravity above
    # which the run warns. The floor plane or the IMU calibration is then wrong.
    max_gravity_disagreement_deg: float = 2.0


@dataclass(kw_only=True)
class InertialTerms:
    """Preintegrated IMU between consecutive keyframes, for the bundle adjustment."""

    between: dict[int, gtsam.PreintegratedCombinedMeasurements]  # i -> from keyframe i to i + 1
    stamps_s: np.ndarray  # (K,) keyframe stamps
    bias: gtsam.imuBias.ConstantBias  # initial estimate and prior mean (IMU frame)
    bias_prior: gtsam.noiseModel.Base
    up_odom: np.ndarray  # gravity's opposite in the factors' frame (unit)
    tilt_prior_deg: float
    skipped: list[int] = field(default_factory=list)  # intervals the samples do not cover


def up_from_accelerometer(imu: ImuBuffer, stamps_ns: np.ndarray, T_odom_cam: np.ndarray) -> np.ndarray:
    """The up direction in the odometry frame from the accelerometer: the specific
    force rotated into the odometry frame by the (interpolated) camera poses and
    averaged over the walk is gravity's opposite, plus the change of velocity over
    the walk divided by its duration (cm/s over a minute: negligible)."""
    cal = imu.calibration
    samples = imu.samples
    t_imu = stamps_ns + round(cal.timeshift_cam_imu_s * 1e9)
    inside = (samples.stamps_ns >= t_imu[0]) & (samples.stamps_ns <= t_imu[-1])
    if inside.sum() < 2 or len(stamps_ns) < 2:
        raise ValueError("the IMU samples do not overlap the ego frames")
    R = Slerp((t_imu - t_imu[0]) * 1e-9, Rotation.from_matrix(T_odom_cam[:, :3, :3]))(
        (samples.stamps_ns[inside] - t_imu[0]) * 1e-9
    )
    f = R.apply(samples.accel[inside] @ cal.T_cam_imu[:3, :3].T).mean(axis=0)
    return f / np.linalg.norm(f)


def keyframe_preintegration(
    imu: ImuBuffer, stamps_ns: np.ndarray, up_odom: np.ndarray, params: InertialParams = InertialParams()
) -> InertialTerms:
    """GTSAM combined preintegration between each pair of consecutive keyframes, with
    the calibration's noise densities (Kalibr's are GTSAM's continuous-time ones), the
    IMU's orientation in the camera frame (the BA's body; the lever arm is applied in
    ``ImuBuffer.preintegrate``) and gravity along -``up_odom``."""
    cal = imu.calibration
    pim_params = gtsam.PreintegrationCombinedParams(-params.gravity_mps2 * np.asarray(up_odom, float))
    pim_params.setGyroscopeCovariance(cal.gyroscope_noise_density**2 * np.eye(3))
    pim_params.setAccelerometerCovariance(cal.accelerometer_noise_density**2 * np.eye(3))
    pim_params.setBiasOmegaCovariance(cal.gyroscope_random_walk**2 * np.eye(3))
    pim_params.setBiasAccCovariance(cal.accelerometer_random_walk**2 * np.eye(3))
    pim_params.setIntegrationCovariance(params.integration_sigma**2 * np.eye(3))
    pim_params.setBodyPSensor(gtsam.Pose3(gtsam.Rot3(cal.T_cam_imu[:3, :3]), np.zeros(3)))
    bias = gtsam.imuBias.ConstantBias(np.zeros(3), imu.bias)
    between, skipped = {}, []
    for i in range(len(stamps_ns) - 1):
        try:
            between[i] = imu.preintegrate(int(stamps_ns[i]), int(stamps_ns[i + 1]), pim_params, bias)
        except ValueError:
            skipped.append(i)
    prior = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([params.accel_bias_prior_mps2] * 3 + [params.gyro_bias_prior_radps] * 3)
    )
    return InertialTerms(
        between=between,
        stamps_s=np.asarray(stamps_ns) * 1e-9,
        bias=bias,
        bias_prior=prior,
        up_odom=np.asarray(up_odom, float),
        tilt_prior_deg=params.tilt_prior_deg,
        skipped=skipped,
    )
