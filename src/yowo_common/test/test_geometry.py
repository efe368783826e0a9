import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import (
    Sim3,
    inv_se3,
    look_at,
    quat_xyzw_from_rotation,
    rotation_aligning,
    rotation_angle_deg,
    rotation_from_quat_xyzw,
    se3,
    transform_points,
    umeyama,
)


def random_pose(rng):
    return se3(Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(size=3))


def test_inverse_and_transform_roundtrip():
    rng = np.random.default_rng(0)
    T = random_pose(rng)
    pts = rng.normal(size=(10, 3))
    np.testing.assert_allclose(transform_points(inv_se3(T), transform_points(T, pts)), pts, atol=1e-12)
    np.testing.assert_allclose(inv_se3(T) @ T, np.eye(4), atol=1e-12)


def test_quaternion_roundtrip_is_xyzw():
    R = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    q = quat_xyzw_from_rotation(R)
    np.testing.assert_allclose(q, [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    np.testing.assert_allclose(rotation_from_quat_xyzw(q), R, atol=1e-12)
    with pytest.raises(ValueError, match="not a rotation"):
        rotation_from_quat_xyzw([0, 0, 0, 0])


def test_rotation_angle():
    R = Rotation.from_rotvec([0, 0.3, 0]).as_matrix()
    assert rotation_angle_deg(np.eye(3), R) == pytest.approx(np.degrees(0.3), abs=1e-9)


@pytest.mark.parametrize("v", [[0.1, -0.05, 0.99], [0, 0, -1], [1, 0, 0], [0, 0, 1]])
def test_rotation_aligning_maps_normal_to_z(v):
    R = rotation_aligning(v, [0, 0, 1])
    np.testing.assert_allclose(R @ (np.array(v) / np.linalg.norm(v)), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_look_at_optical_frame():
    T = look_at([0, 0, 3], [2, 0, 0])
    z = T[:3, 2]
    np.testing.assert_allclose(z, np.array([2, 0, -3]) / np.sqrt(13), atol=1e-12)
    assert T[2, 1] < 0  # image y (down) points towards world -z


def test_umeyama_recovers_sim3_exactly():
    rng = np.random.default_rng(1)
    truth = Sim3(2.5, Rotation.random(random_state=3).as_matrix(), np.array([1.0, -2.0, 0.5]))
    src = rng.normal(size=(50, 3))
    est = umeyama(src, truth.apply(src))
    assert est.s == pytest.approx(truth.s, rel=1e-12)
    np.testing.assert_allclose(est.R, truth.R, atol=1e-12)
    np.testing.assert_allclose(est.t, truth.t, atol=1e-12)


def test_umeyama_weights_ignore_zero_weight_outliers():
    rng = np.random.default_rng(2)
    truth = Sim3(0.7, Rotation.random(random_state=4).as_matrix(), np.array([0.0, 3.0, 1.0]))
    src = rng.normal(size=(40, 3))
    dst = truth.apply(src)
    dst[:5] += 10.0
    w = np.ones(40)
    w[:5] = 0.0
    est = umeyama(src, dst, weights=w)
    np.testing.assert_allclose(est.apply(src[5:]), dst[5:], atol=1e-10)
    unweighted = umeyama(src, dst)
    assert np.abs(unweighted.apply(src[5:]) - dst[5:]).max() > 0.1


def test_umeyama_reflection_guard_and_errors():
    rng = np.random.default_rng(5)
    src = rng.normal(size=(20, 3))
    mirrored = src * np.array([1, 1, -1])
    assert np.linalg.det(umeyama(src, mirrored).R) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="one position"):
        umeyama(np.zeros((5, 3)), rng.normal(size=(5, 3)))
    with pytest.raises(ValueError, match=">= 3"):
        umeyama(src[:2], src[:2])


def test_sim3_pose_transform_and_inverse():
    rng = np.random.default_rng(6)
    S = Sim3(1.7, Rotation.random(random_state=7).as_matrix(), rng.normal(size=3))
    T = random_pose(rng)
    moved = S.transform_pose(T)
    np.testing.assert_allclose(moved[:3, 3], S.apply(T[:3, 3]))
    back = S.inverse().transform_pose(moved)
    np.testing.assert_allclose(back, T, atol=1e-12)
    np.testing.assert_allclose(S.compose(S.inverse()).matrix(), np.eye(4), atol=1e-12)
