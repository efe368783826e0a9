"""The head-mounted RGB-D camera's IMU (/ego/imu): gyro and accelerometer of the rendered
ego trajectory (the walk's spline, differentiated analytically), with white noise and
bias random walk (Kalibr's IMU noise model), and its calibration for the recording.

Model, per axis, at the IMU's rate (Kalibr wiki "IMU Noise Model"):
    measured = true + bias + sigma_c * sqrt(rate) * N(0, 1),
    bias_{k+1} = bias_k + sigma_rw * sqrt(1 / rate) * N(0, 1),
with the true angular velocity in the IMU frame and the true specific force
R_imu_world (a_world - g), g = (0, 0, -gravity) in the z-up world. Not modelled:
scale factors, axis misalignment inside the chip, g-sensitivity, quantisation,
saturation, the IMU's low-pass filter, a clock offset to the camera.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import yaml
from geometry_msgs.msg import TransformStamped, Vector3
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu
from std_msgs.msg import Header, String
from tf2_msgs.msg import TFMessage

from yowo_common import topics
from yowo_common.geometry import se3
from yowo_common.rosconv import matrix_to_transform, ns_to_time

from .walk import R_BODY_OPTICAL, Walk

# Default extrinsics after the RealSense D435i: realsense-ros' nominal
# _d435i_imu_modules.urdf.xacro puts the IMU at (-0.01174, -0.00552, 0.0051) m in
# camera_link (x forward, y left, z up), whose origin is the depth camera; the colour
# camera (YOWO's ego camera) is 15 mm along camera_link y. In the colour optical frame
# that is (0.02052, -0.0051, -0.01174) m. The IMU's axes are camera_link's (REP 103,
# x forward, y left, z up; not the optical frame), mounted with a sub-degree tilt.
_MOUNT_TILT_DEG = (0.4, -0.3, 0.5)  # rotation vector in the IMU frame, deg
_Q_CAM_IMU = tuple(
    float(q)
    for q in Rotation.from_matrix(
        R_BODY_OPTICAL.T @ Rotation.from_rotvec(_MOUNT_TILT_DEG, degrees=True).as_matrix()
    ).as_quat()
)


@dataclass(frozen=True)
class ImuParams:
    """The simulated IMU. Noise defaults: the Bosch BMI055 of the RealSense D435i.
    Densities are continuous-time (Kalibr's imu.yaml units); the per-sample white-noise
    std is density * sqrt(rate_hz)."""

    rate_hz: float = 200.0  # D435i gyro: 200 or 400 Hz
    # BMI055 data sheet (BST-BMI055-DS000-08): gyro rate noise density 0.014 deg/s/sqrt(Hz).
    gyro_noise_density: float = 2.44e-4  # rad/s/sqrt(Hz)
    # BMI055 data sheet: accelerometer output noise density 150 ug/sqrt(Hz).
    accel_noise_density: float = 1.47e-3  # m/s^2/sqrt(Hz)
    # Bias random walks are in no data sheet; what users report for D435i units (Kalibr /
    # Allan variance) spans 2.4e-6..1.9e-5 (gyro) and 6.3e-5..3e-3 (accel): VINS-Mono
    # #472 2.4e-6 / 6.3e-5, librealsense #7103 1.7e-5 / 8.3e-4, ORB_SLAM3 #125 1.9e-5 / 3e-3.
    # These are mid-range.
    gyro_random_walk: float = 1.0e-5  # rad/s^2/sqrt(Hz)
    accel_random_walk: float = 2.5e-4  # m/s^3/sqrt(Hz)
    # Turn-on bias, drawn per recording (std per axis): of the order of the biases
    # rs-imu-calibration finds on a D435i (ORB_SLAM3 #125: gyro 0.3e-3..2.8e-3 rad/s,
    # accel 0.03..0.38 m/s^2); BMI055 typical: +-1 deg/s zero-rate, +-70 mg zero-g offset.
    gyro_bias_std: float = 3.0e-3  # rad/s
    accel_bias_std: float = 0.1  # m/s^2
    gravity_mps2: float = 9.81  # |g|; the world is z up
    # T_cam_imu: the IMU's pose in the ego camera's optical frame (maps IMU-frame
    # coordinates to camera coordinates, Kalibr's camchain-imucam convention).
    t_cam_imu_m: tuple[float, float, float] = (0.02052, -0.0051, -0.01174)
    q_cam_imu_xyzw: tuple[float, float, float, float] = field(default=_Q_CAM_IMU)
    frame_id: str = "ego_imu_frame"
    seed_stream: int = 18  # the IMU's random generator: [seed, this]

    @property
    def T_cam_imu(self) -> np.ndarray:
        return se3(Rotation.from_quat(self.q_cam_imu_xyzw).as_matrix(), self.t_cam_imu_m)

    def noise_free(self) -> ImuParams:
        return replace(
            self,
            gyro_noise_density=0.0,
            accel_noise_density=0.0,
            gyro_random_walk=0.0,
            accel_random_walk=0.0,
            gyro_bias_std=0.0,
            accel_bias_std=0.0,
        )

    def white_sigma(self) -> tuple[float, float]:
        """Per-sample white-noise std (gyro [rad/s], accel [m/s^2])."""
        root = np.sqrt(self.rate_hz)
        return self.gyro_noise_density * root, self.accel_noise_density * root


@dataclass(kw_only=True)
class ImuKinematics:
    """Noise-free motion of the IMU frame at times t_s (world frame unless stated)."""

    t_s: np.ndarray  # (n,)
    R_world_imu: np.ndarray  # (n, 3, 3)
    p: np.ndarray  # (n, 3) IMU origin [m]
    v: np.ndarray  # (n, 3) its velocity [m/s]
    omega: np.ndarray  # (n, 3) angular velocity in the IMU frame [rad/s]
    specific_force: np.ndarray  # (n, 3) R_imu_world (a - g) in the IMU frame [m/s^2]


def imu_kinematics(walk: Walk, t_s: np.ndarray, params: ImuParams) -> ImuKinematics:
    """The IMU's true motion: the ego camera's (walk.ego_motion) moved by T_cam_imu.
    A point fixed to the camera at c: p = p_cam + R c, so p'' = p_cam'' + R'' c exactly."""
    m = walk.ego_motion(t_s)
    T = params.T_cam_imu
    R_ci, c = T[:3, :3], T[:3, 3]
    R_wi = m.R @ R_ci
    acc = m.ddp + m.ddR @ c
    g = np.array([0.0, 0.0, -params.gravity_mps2])
    return ImuKinematics(
        t_s=m.t_s,
        R_world_imu=R_wi,
        p=m.p + m.R @ c,
        v=m.dp + m.dR @ c,
        omega=m.omega_ego @ R_ci,
        specific_force=np.einsum("nji,nj->ni", R_wi, acc - g),
    )


@dataclass(kw_only=True)
class ImuData:
    """What /ego/imu records, with the truth behind it."""

    stamps_ns: np.ndarray  # (n,) int64
    gyro: np.ndarray  # (n, 3) measured angular velocity [rad/s], IMU frame
    accel: np.ndarray  # (n, 3) measured specific force [m/s^2], IMU frame
    gyro_bias: np.ndarray  # (n, 3) true bias of each sample
    accel_bias: np.ndarray
    truth: ImuKinematics


def simulate_imu(walk: Walk, params: ImuParams, seed: int, start_ns: int) -> ImuData:
    """IMU samples every 1/rate_hz over the walk. A generator of its own ([seed,
    seed_stream]): recording the IMU changes nothing else of a capture."""
    k = np.arange(int(np.floor(walk.duration_s * params.rate_hz + 1e-9)) + 1)
    t = k / params.rate_hz
    truth = imu_kinematics(walk, t, params)
    rng = np.random.default_rng([seed, params.seed_stream])
    n, dt = len(t), 1.0 / params.rate_hz
    sg, sa = params.white_sigma()

    def bias(init_std, walk_density):
        steps = rng.normal(size=(n, 3)) * walk_density * np.sqrt(dt)
        steps[0] = rng.normal(size=3) * init_std
        return np.cumsum(steps, axis=0)

    bg, ba = bias(params.gyro_bias_std, params.gyro_random_walk), bias(params.accel_bias_std, params.accel_random_walk)
    gyro = truth.omega + bg + rng.normal(size=(n, 3)) * sg
    accel = truth.specific_force + ba + rng.normal(size=(n, 3)) * sa
    stamps = start_ns + np.round(k * (1e9 / params.rate_hz)).astype(np.int64)
    return ImuData(stamps_ns=stamps, gyro=gyro, accel=accel, gyro_bias=bg, accel_bias=ba, truth=truth)


def _vector(v) -> Vector3:
    return Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def imu_message(data: ImuData, i: int, params: ImuParams) -> Imu:
    """Sample i as sensor_msgs/Imu: no orientation (covariance[0] = -1, REP 145), the
    per-sample white-noise variances on the diagonals."""
    sg, sa = params.white_sigma()
    return Imu(
        header=Header(stamp=ns_to_time(int(data.stamps_ns[i])), frame_id=params.frame_id),
        orientation_covariance=[-1.0] + [0.0] * 8,
        angular_velocity=_vector(data.gyro[i]),
        angular_velocity_covariance=list(np.diag([sg**2] * 3).ravel()),
        linear_acceleration=_vector(data.accel[i]),
        linear_acceleration_covariance=list(np.diag([sa**2] * 3).ravel()),
    )


def bias_message(data: ImuData, i: int, params: ImuParams) -> Imu:
    """Ground truth of sample i's biases, in the fields they corrupt: /ego/imu's
    angular_velocity = true + this angular_velocity + white noise (same for
    linear_acceleration)."""
    return Imu(
        header=Header(stamp=ns_to_time(int(data.stamps_ns[i])), frame_id=params.frame_id),
        orientation_covariance=[-1.0] + [0.0] * 8,
        angular_velocity=_vector(data.gyro_bias[i]),
        linear_acceleration=_vector(data.accel_bias[i]),
    )


def calibration_yaml(params: ImuParams, camera_frame: str) -> str:
    """Kalibr's imu.yaml keys plus the camera extrinsics as Kalibr's camchain-imucam
    writes them (T_cam_imu, timeshift_cam_imu: t_imu = t_cam + shift)."""
    doc = {
        "rostopic": topics.EGO_IMU,
        "update_rate": float(params.rate_hz),
        "accelerometer_noise_density": params.accel_noise_density,
        "accelerometer_random_walk": params.accel_random_walk,
        "gyroscope_noise_density": params.gyro_noise_density,
        "gyroscope_random_walk": params.gyro_random_walk,
        "gravity_magnitude": params.gravity_mps2,
        "frame_id": params.frame_id,
        "camera_frame_id": camera_frame,
        "T_cam_imu": [[float(v) for v in row] for row in params.T_cam_imu],
        "timeshift_cam_imu": 0.0,
    }
    return yaml.safe_dump(doc, sort_keys=False)


def read_calibration(text: str) -> tuple[dict, np.ndarray]:
    """(the calibration's fields, T_cam_imu) from /ego/imu/calibration's text."""
    doc = yaml.safe_load(text)
    return doc, np.array(doc["T_cam_imu"], dtype=float)


def calibration_messages(params: ImuParams, camera_frame: str, stamp_ns: int) -> dict[str, object]:
    """Latched topic -> message: /tf_static (camera optical frame -> IMU frame, T_cam_imu)
    and the calibration text on /ego/imu/calibration."""
    tf = TransformStamped(
        header=Header(stamp=ns_to_time(stamp_ns), frame_id=camera_frame),
        child_frame_id=params.frame_id,
        transform=matrix_to_transform(params.T_cam_imu),
    )
    return {
        topics.TF_STATIC: TFMessage(transforms=[tf]),
        topics.EGO_IMU_CALIBRATION: String(data=calibration_yaml(params, camera_frame)),
    }
