"""The IMU in the ego bundle adjustment: GTSAM's combined preintegration of the
simulator's IMU between ground-truth keyframe poses (lever arm, gravity, biases), the
accelerometer's up direction, and pose-graph edges as between factors."""

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X
from scipy.spatial.transform import Rotation

from yowo_common.geometry import se3
from yowo_ego.imu import ImuBuffer, ImuCalibration, ImuSamples, keyframe_preintegration, up_from_accelerometer
from yowo_ego.odometry import OdometryEdge
from yowo_ego.refine import BundleParams, edge_factor
from yowo_sim.capture import EGO_FRAME, build_capture
from yowo_sim.imu import ImuParams, calibration_yaml, simulate_imu
from yowo_sim.presets import get_preset


@pytest.fixture(scope="module")
def walk():
    """The tiny preset's walk (seed 3: ~6 s, head turns up to ~300 deg/s)."""
    return build_capture(get_preset("tiny"), 3).walk


def _imu(walk, params: ImuParams):
    data = simulate_imu(walk, params, 3, 0)
    imu = ImuBuffer(ImuCalibration.from_yaml(calibration_yaml(ImuParams(), EGO_FRAME)))
    imu.extend(ImuSamples(data.stamps_ns, data.gyro, data.accel))
    return imu, data


def _frames(walk):
    """15 Hz camera poses in the first camera's frame, and the true up in that frame."""
    t = np.arange(0.05, walk.duration_s - 0.05, 1 / 15)
    T = np.array([walk.ego_pose_at(s) for s in t])
    T0_inv = np.linalg.inv(T[0])
    return (t * 1e9).astype(np.int64), np.einsum("ij,njk->nik", T0_inv, T), T0_inv[:3, :3] @ [0.0, 0.0, 1.0]


def _solve_velocities_and_biases(terms, T_kf):
    """Poses held at the truth: velocities and biases from the IMU factors alone."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for j, T in enumerate(T_kf):
        graph.add(gtsam.PriorFactorPose3(X(j), gtsam.Pose3(T), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        values.insert(X(j), gtsam.Pose3(T))
        values.insert(V(j), np.zeros(3))
        values.insert(B(j), terms.bias)
    graph.add(gtsam.PriorFactorConstantBias(B(0), terms.bias, terms.bias_prior))
    first = graph.size()
    for i, pim in terms.between.items():
        graph.add(gtsam.CombinedImuFactor(X(i), V(i), X(i + 1), V(i + 1), B(i), B(i + 1), pim))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    chi2 = np.array([2 * graph.at(k).error(result) for k in range(first, graph.size())])
    return result, chi2


def test_preintegration_fits_the_true_motion(walk):
    """Between true keyframe poses (every 5th frame, fast head turns), the IMU factors
    fit the motion as their noise model says (noise-free: chi2 well below the 15
    dimensions; GTSAM alone corrects the lever arm's centripetal term only, and the
    angular acceleration's term then left chi2 ~100, up to 2e4), and recover the
    simulated biases from the noisy IMU."""
    stamps, T, up = _frames(walk)
    kf = np.arange(0, len(stamps), 5)
    free, _ = _imu(walk, ImuParams().noise_free())
    terms = keyframe_preintegration(free, stamps[kf], up)
    assert len(terms.between) == len(kf) - 1 and not terms.skipped
    _, chi2 = _solve_velocities_and_biases(terms, T[kf])
    assert np.median(chi2) < 2.0 and chi2.max() < 40.0
    noisy, data = _imu(walk, ImuParams())
    terms = keyframe_preintegration(noisy, stamps[kf], up)
    result, chi2 = _solve_velocities_and_biases(terms, T[kf])
    assert np.median(chi2) < 15.0
    bias = result.atConstantBias(B(0))
    assert np.linalg.norm(data.accel_bias[0]) > 0.03  # a bias worth estimating
    assert np.linalg.norm(bias.accelerometer() - data.accel_bias[0]) < 0.015
    assert np.linalg.norm(bias.gyroscope() - data.gyro_bias[0]) < 5e-4


def test_accelerometer_up_direction(walk):
    """The mean specific force over the walk, rotated by the camera poses, points up:
    exactly (within 0.15 deg) without noise; with a consumer IMU within its
    accelerometer bias' angle (|b| / g ~ 0.5 deg here)."""
    stamps, T, up = _frames(walk)
    free, _ = _imu(walk, ImuParams().noise_free())
    assert np.degrees(np.arccos(up_from_accelerometer(free, stamps, T) @ up)) < 0.15
    noisy, data = _imu(walk, ImuParams())
    bound = np.degrees(np.linalg.norm(data.accel_bias[0]) / 9.81) + 0.2
    assert np.degrees(np.arccos(up_from_accelerometer(noisy, stamps, T) @ up)) < bound
    with pytest.raises(ValueError, match="do not overlap"):
        up_from_accelerometer(noisy, stamps + 10**11, T)


def test_edge_factor_keeps_open3d_information():
    """A pose-graph edge's GTSAM factor weighs a perturbation of T_target_source in
    the target's frame (Open3D's convention) by the edge's information."""
    rng = np.random.default_rng(0)
    T = se3(Rotation.from_rotvec([0.1, -0.3, 0.2]).as_matrix(), [0.4, -0.1, 0.3])
    A = rng.normal(size=(6, 6))
    info = A @ A.T + 6 * np.eye(6)
    edge = OdometryEdge(source=1, target=0, T_target_source=T, information=info, kind="odometry")
    factor = edge_factor(edge, BundleParams(edge_huber_k=1e9))
    delta = rng.normal(scale=1e-3, size=6)  # (rotation, translation), target frame
    perturbed = se3(Rotation.from_rotvec(delta[:3]).as_matrix(), delta[3:]) @ T
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(X(1), gtsam.Pose3(perturbed))
    assert 2 * factor.error(values) == pytest.approx(delta @ info @ delta, rel=1e-2)
