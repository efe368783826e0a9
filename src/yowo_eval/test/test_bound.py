"""The Cramer-Rao bound's covariance (Schur complement of the scene points) against
GTSAM's own marginals on a well-conditioned bundle problem."""

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from yowo_common.bundle import cal3, pose3
from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at
from yowo_eval.bound import _camera_covariance


def _bundle_graph(num_cameras: int = 3, num_points: int = 60):
    rng = np.random.default_rng(3)
    camera = CameraModel.from_fov(640, 480, 70.0)
    points = rng.uniform([-1.5, -1.5, 0.0], [1.5, 1.5, 1.8], (num_points, 3))
    poses = [
        look_at(np.array([3.0 * np.cos(a), 3.0 * np.sin(a), 2.8]), np.zeros(3))
        for a in np.linspace(0, 1.6, num_cameras)
    ]
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, T in enumerate(poses):
        values.insert(X(i), pose3(T))
        uv, _ = camera.project_world(T, points)
        for j, p in enumerate(uv):
            graph.add(
                gtsam.GenericProjectionFactorCal3_S2(
                    gtsam.Point2(*p), gtsam.noiseModel.Isotropic.Sigma(2, 1.5), X(i), L(j), cal3(camera)
                )
            )
    for j, P in enumerate(points):
        values.insert(L(j), gtsam.Point3(*P))
    graph.add(gtsam.PriorFactorPose3(X(0), pose3(poses[0]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-5)))
    base = float(np.linalg.norm(poses[1][:3, 3] - poses[0][:3, 3]))
    graph.add(gtsam.RangeFactorPose3(X(0), X(1), base, gtsam.noiseModel.Isotropic.Sigma(1, 1e-5)))
    return graph, values


def test_schur_covariance_equals_gtsam_marginals():
    graph, values = _bundle_graph()
    cov = _camera_covariance(graph, values, 3)
    keys = gtsam.KeyVector([X(1), X(2)])
    expected = gtsam.Marginals(graph, values).jointMarginalCovariance(keys).fullMatrix()
    assert cov.shape == (12, 12)
    np.testing.assert_allclose(cov, expected, rtol=1e-4, atol=1e-12)


def test_a_camera_without_observations_has_no_bound():
    graph, values = _bundle_graph()
    values.insert(X(3), pose3(np.eye(4)))  # a camera that sees nothing: its information is zero
    assert _camera_covariance(graph, values, 4) is None
