"""The simulated IMU (/ego/imu): consistent with the rendered ego trajectory, with the
noise its parameters state, and recorded with a calibration a consumer can read."""

from dataclasses import replace

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common import topics
from yowo_common.ros.bag import list_topics, read_messages
from yowo_common.rosconv import message_fields, pose_to_matrix, stamp_to_ns, transform_to_matrix
from yowo_sim.capture import EGO_FRAME, START_NS, build_capture, generate
from yowo_sim.imu import ImuParams, imu_kinematics, read_calibration, simulate_imu
from yowo_sim.presets import get_preset


@pytest.fixture(scope="module")
def walk():
    """The ego walk of the tiny preset (seed 3: ~6 s, head turns up to ~300 deg/s)."""
    return build_capture(get_preset("tiny"), 3).walk


def _rot_deg(Ra, Rb) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(Ra.T @ Rb).as_rotvec())))


def _preintegrate(gyro, accel, dt, params: ImuParams, substeps: int):
    """gtsam's combined preintegration of samples gyro[k], accel[k] (k = 0..n), the signal
    taken as linear between samples and fed in `substeps` pieces per sample interval
    (gtsam holds each measurement constant over its step)."""
    pp = gtsam.PreintegrationCombinedParams.MakeSharedU(params.gravity_mps2)
    pp.setGyroscopeCovariance(np.eye(3) * 1e-8)
    pp.setAccelerometerCovariance(np.eye(3) * 1e-6)
    pp.setIntegrationCovariance(np.eye(3) * 1e-8)
    pim = gtsam.PreintegratedCombinedMeasurements(pp, gtsam.imuBias.ConstantBias())
    for k in range(len(gyro) - 1):
        for u in (np.arange(substeps) + 0.5) / substeps:
            pim.integrateMeasurement(
                (1 - u) * accel[k] + u * accel[k + 1], (1 - u) * gyro[k] + u * gyro[k + 1], dt / substeps
            )
    return pim


def test_extrinsics_default_is_not_identity():
    T = ImuParams().T_cam_imu
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert 0.01 < np.linalg.norm(T[:3, 3]) < 0.05  # a D435i-size lever arm
    assert _rot_deg(np.eye(3), T[:3, :3]) > 90.0  # IMU axes are not the optical frame's
    # ... and a sub-degree mounting tilt off camera_link's axes (x forward = optical z).
    assert 0.1 < np.degrees(np.arccos(T[2, 0])) < 1.5


def test_rates_are_the_derivatives_of_the_rendered_pose(walk):
    """Central differences of walk.ego_pose_at (what the renderer uses) moved by T_cam_imu
    against the analytic angular velocity and specific force."""
    params = ImuParams()
    T_ci = params.T_cam_imu
    h = 1e-4
    ts = np.linspace(0.2, walk.duration_s - 0.2, 40)
    kin = imu_kinematics(walk, ts, params)
    for i, t in enumerate(ts):
        A, B, C = (walk.ego_pose_at(s) @ T_ci for s in (t - h, t, t + h))
        W = B[:3, :3].T @ (C[:3, :3] - A[:3, :3]) / (2 * h)
        np.testing.assert_allclose([W[2, 1], W[0, 2], W[1, 0]], kin.omega[i], atol=1e-4)
        acc = (C[:3, 3] - 2 * B[:3, 3] + A[:3, 3]) / h**2
        np.testing.assert_allclose(B[:3, :3].T @ (acc + [0, 0, params.gravity_mps2]), kin.specific_force[i], atol=1e-3)
        np.testing.assert_allclose(kin.R_world_imu[i], B[:3, :3], atol=1e-12)
        np.testing.assert_allclose(kin.p[i], B[:3, 3], atol=1e-12)
        np.testing.assert_allclose(kin.v[i], (C[:3, 3] - A[:3, 3]) / (2 * h), atol=1e-6)
    # The walk moves: a test of a standing agent would prove nothing.
    assert np.abs(kin.omega).max() > 1.0 and np.ptp(kin.specific_force, axis=0).max() > 1.0


def test_noise_free_imu_integrates_back_to_the_ground_truth(walk):
    """2 s windows over the whole walk: gtsam's preintegration of the noise-free samples
    from the true initial state ends at the rendered ego pose moved by T_cam_imu."""
    params = ImuParams().noise_free()
    data = simulate_imu(walk, params, seed=3, start_ns=0)
    dt, n = 1.0 / params.rate_hz, int(2.0 * params.rate_hz)
    np.testing.assert_array_equal(data.gyro, data.truth.omega)
    errors = []
    for i0 in range(0, len(data.stamps_ns) - n, n // 2):
        tr = data.truth
        start = gtsam.NavState(gtsam.Rot3(tr.R_world_imu[i0]), tr.p[i0], tr.v[i0])
        pim = _preintegrate(data.gyro[i0 : i0 + n + 1], data.accel[i0 : i0 + n + 1], dt, params, substeps=8)
        end = pim.predict(start, gtsam.imuBias.ConstantBias())
        T = walk.ego_pose_at((i0 + n) * dt) @ params.T_cam_imu
        errors.append(
            (
                _rot_deg(end.pose().rotation().matrix(), T[:3, :3]),
                np.linalg.norm(end.pose().translation() - T[:3, 3]),
                np.linalg.norm(end.velocity() - tr.v[i0 + n]),
            )
        )
    errors = np.array(errors)
    assert len(errors) >= 4
    assert errors[:, 0].max() < 0.01  # deg
    assert errors[:, 1].max() < 0.002  # m
    assert errors[:, 2].max() < 0.003  # m/s
    # What is left is gtsam's step (first order in it), not the data: 4x finer, ~4x smaller.
    worst = int(np.argmax(errors[:, 1])) * (n // 2)
    start = gtsam.NavState(gtsam.Rot3(data.truth.R_world_imu[worst]), data.truth.p[worst], data.truth.v[worst])
    T = walk.ego_pose_at((worst + n) * dt) @ params.T_cam_imu
    fine = _preintegrate(data.gyro[worst : worst + n + 1], data.accel[worst : worst + n + 1], dt, params, substeps=32)
    assert (
        np.linalg.norm(fine.predict(start, gtsam.imuBias.ConstantBias()).pose().translation() - T[:3, 3])
        < 0.4 * errors[:, 1].max()
    )


def test_noise_and_bias_statistics_match_the_parameters(walk):
    params = ImuParams()
    data = simulate_imu(walk, params, seed=11, start_ns=0)
    sg, sa = params.white_sigma()
    assert sg == pytest.approx(params.gyro_noise_density * np.sqrt(200.0))
    np.testing.assert_allclose(np.std(data.gyro - data.truth.omega - data.gyro_bias, axis=0), sg, rtol=0.1)
    np.testing.assert_allclose(np.std(data.accel - data.truth.specific_force - data.accel_bias, axis=0), sa, rtol=0.1)
    # Bias random walk: increments with std density * sqrt(dt).
    dt = 1.0 / params.rate_hz
    np.testing.assert_allclose(
        np.std(np.diff(data.gyro_bias, axis=0), axis=0), params.gyro_random_walk * np.sqrt(dt), rtol=0.1
    )
    np.testing.assert_allclose(
        np.std(np.diff(data.accel_bias, axis=0), axis=0), params.accel_random_walk * np.sqrt(dt), rtol=0.1
    )
    # Turn-on bias: one draw per recording, so over many seeds.
    first = np.array(
        [
            (d.gyro_bias[0], d.accel_bias[0])
            for d in (simulate_imu(walk, params, seed=s, start_ns=0) for s in range(150))
        ]
    )
    assert np.std(first[:, 0]) == pytest.approx(params.gyro_bias_std, rel=0.1)
    assert np.std(first[:, 1]) == pytest.approx(params.accel_bias_std, rel=0.1)
    # Same seed, same samples; another seed, other noise.
    again = simulate_imu(walk, params, seed=11, start_ns=0)
    np.testing.assert_array_equal(again.gyro, data.gyro)
    assert not np.allclose(simulate_imu(walk, params, seed=12, start_ns=0).gyro, data.gyro)


def test_recording_carries_imu_bias_and_calibration(tiny_bag):
    path, summary = tiny_bag
    params = get_preset("tiny").imu_params
    info = {t.name: t for t in list_topics(path)}
    assert info[topics.EGO_IMU].msgtype == "sensor_msgs/msg/Imu"
    assert info[topics.EGO_IMU_CALIBRATION].latched and info[topics.TF_STATIC].latched
    imu, bias, poses, tf, calib = [], [], {}, None, None
    wanted = [topics.EGO_IMU, topics.GT_EGO_IMU_BIAS, topics.GT_EGO_POSE, topics.TF_STATIC, topics.EGO_IMU_CALIBRATION]
    for topic, log_ns, msg in read_messages(path, wanted):
        if topic == topics.EGO_IMU:
            assert stamp_to_ns(msg.header.stamp) == log_ns and msg.header.frame_id == params.frame_id
            imu.append(msg)
        elif topic == topics.GT_EGO_IMU_BIAS:
            bias.append(msg)
        elif topic == topics.GT_EGO_POSE:
            poses[stamp_to_ns(msg.header.stamp)] = pose_to_matrix(msg.pose)
        elif topic == topics.TF_STATIC:
            tf = msg
        else:
            calib = msg
    stamps = np.array([stamp_to_ns(m.header.stamp) for m in imu])
    assert len(imu) == summary.imu_samples == info[topics.GT_EGO_IMU_BIAS].count
    assert np.all(np.diff(stamps) > 0)
    np.testing.assert_array_equal(np.diff(stamps), 5_000_000)  # 200 Hz
    assert stamps[0] == START_NS and (stamps[-1] - START_NS) / 1e9 == pytest.approx(summary.duration_s, abs=0.005)
    np.testing.assert_array_equal([stamp_to_ns(m.header.stamp) for m in bias], stamps)
    sg, _ = params.white_sigma()
    assert imu[0].orientation_covariance[0] == -1.0
    assert imu[0].angular_velocity_covariance[0] == pytest.approx(sg**2)
    # Calibration: the transform on /tf_static and the Kalibr-style YAML agree with the parameters.
    (t,) = tf.transforms
    assert (t.header.frame_id, t.child_frame_id) == (EGO_FRAME, params.frame_id)
    np.testing.assert_allclose(transform_to_matrix(t.transform), params.T_cam_imu, atol=1e-9)
    doc, T_cam_imu = read_calibration(calib.data)
    np.testing.assert_allclose(T_cam_imu, params.T_cam_imu, atol=1e-12)
    assert doc["rostopic"] == topics.EGO_IMU and doc["update_rate"] == 200.0
    assert doc["gyroscope_noise_density"] == params.gyro_noise_density
    assert doc["accelerometer_random_walk"] == params.accel_random_walk
    # A consumer's check from the recording alone: gyro minus the true bias, integrated
    # between ego frames 1 s apart, is the ground truth's rotation in the IMU frame.
    R_ci = T_cam_imu[:3, :3]
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in imu])
    gyro -= np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in bias])
    frames = sorted(poses)
    checked = 0
    for a, b in zip(frames[::15], frames[15::15]):
        i, j = np.searchsorted(stamps, [a, b])
        assert stamps[i] == a and stamps[j] == b  # frames fall on IMU samples
        R = np.eye(3)
        for k in range(i, j):
            R = R @ Rotation.from_rotvec(0.5 * (gyro[k] + gyro[k + 1]) * 0.005).as_matrix()
        R_true = (poses[a][:3, :3] @ R_ci).T @ poses[b][:3, :3] @ R_ci
        assert _rot_deg(R, R_true) < 0.1
        checked += 1
    assert checked >= 4


def test_recording_without_imu_differs_only_by_the_imu(tmp_path):
    preset = get_preset("tiny", cmc_images=False)
    generate(preset, 4, tmp_path / "with")
    generate(replace(preset, imu=False), 4, tmp_path / "without")
    imu_topics = {topics.EGO_IMU, topics.GT_EGO_IMU_BIAS, topics.EGO_IMU_CALIBRATION, topics.TF_STATIC}
    names = {t.name for t in list_topics(tmp_path / "without")}
    assert not names & imu_topics and topics.EGO_INFO in names
    rest = [
        [(t, s, message_fields(m)) for t, s, m in read_messages(tmp_path / run) if t not in imu_topics]
        for run in ("with", "without")
    ]
    assert len(rest[0]) > 500 and rest[0] == rest[1]
