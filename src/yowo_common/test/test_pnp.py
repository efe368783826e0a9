"""PnP shared by the stages: a known pose is recovered, and points without spread
(SQPnP's assertion, which stopped the `large` benchmark) give no pose instead of a crash."""

import cv2
import numpy as np

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, look_at, se3
from yowo_common.pnp import sqpnp_all, sqpnp_ransac

CAMERA = CameraModel.from_fov(640, 480, 80.0)
T_WORLD_CAM = look_at(np.array([0.5, -1.0, 2.6]), np.array([0.0, 1.5, 0.8]))


def _T_world_cam(rvec, tvec):
    return inv_se3(se3(cv2.Rodrigues(rvec)[0], np.asarray(tvec).ravel()))


def test_a_known_pose_is_recovered_with_and_without_ransac():
    rng = np.random.default_rng(0)
    P = np.column_stack([rng.uniform(-2, 2, 60), rng.uniform(0, 3, 60), rng.uniform(0, 1.8, 60)])
    uv, _ = CAMERA.project_world(T_WORLD_CAM, P)
    uv[:6] += 80.0  # outliers for RANSAC
    rvec, tvec, inliers = sqpnp_ransac(P, uv, CAMERA.K, 2.0)
    assert sorted(inliers.tolist()) == list(range(6, 60))
    np.testing.assert_allclose(_T_world_cam(rvec, tvec), T_WORLD_CAM, atol=1e-6)
    rvec, tvec = sqpnp_all(P[6:], uv[6:], CAMERA.K)[0]
    np.testing.assert_allclose(_T_world_cam(rvec, tvec), T_WORLD_CAM, atol=1e-6)


def test_points_without_spread_give_no_pose():
    still = np.tile([[0.3, 1.2, 1.7]], (40, 1))  # an agent's head top, standing still
    uv, _ = CAMERA.project_world(T_WORLD_CAM, still)
    assert sqpnp_all(still, uv, CAMERA.K) == []
    # RANSAC's final fit on the inliers is the same degenerate case, among outliers with spread.
    rng = np.random.default_rng(1)
    P = np.vstack([still, rng.uniform(-2, 2, (10, 3))])
    uv = np.vstack([uv, rng.uniform(0, 640, (10, 2))])
    rvec, tvec, inliers = sqpnp_ransac(P, uv, CAMERA.K, 2.0)
    assert rvec is None and len(inliers) == 0
