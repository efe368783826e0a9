"""Bundle adjustment with GTSAM built-in factors (projection factors, Huber loss,
Levenberg-Marquardt), shared by the ego BA (eq. ego_bd), the CMC group BA
(eq. cmc_bd) and the joint optimisation (eq. factor_graph_all)."""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from .camera import CameraModel


def pose3(T: np.ndarray) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(T[:3, :3]), gtsam.Point3(*T[:3, 3]))


def matrix(p: gtsam.Pose3) -> np.ndarray:
    return p.matrix()


def cal3(camera: CameraModel) -> gtsam.Cal3_S2:
    K = camera.K
    return gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])


@dataclass
class Observations:
    """2D observations of points in cameras, in ideal (undistorted) pixels (parallel arrays)."""

    camera: np.ndarray  # (M,) camera index
    point: np.ndarray  # (M,) point index
    uv: np.ndarray  # (M, 2) px
    sigma_px: np.ndarray  # (M,) pixel noise of each observation

    def __len__(self) -> int:
        return len(self.camera)

    def subset(self, keep: np.ndarray) -> "Observations":
        return Observations(self.camera[keep], self.point[keep], self.uv[keep], self.sigma_px[keep])


@dataclass
class BundleProblem:
    cameras: list[CameraModel]  # intrinsics per camera index
    T_world_cam: list[np.ndarray]  # initial poses
    points: np.ndarray  # (P, 3) initial points
    obs: Observations
    fixed_cameras: set[int] = field(default_factory=set)  # held (almost) fixed: gauge
    position_priors: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)  # cam -> (centre, sigma m)
    # (cam a, cam b, distance, sigma): fixes the scale of a reconstruction without fixing a direction
    baseline_prior: tuple[int, int, float, float] | None = None
    point_priors: dict[int, tuple[np.ndarray, float]] = field(default_factory=dict)  # point -> (xyz, sigma m)
    huber_k: float = 1.345


@dataclass
class BundleResult:
    T_world_cam: list[np.ndarray]
    points: np.ndarray
    residuals_px: np.ndarray  # (M, 2) reprojection residuals of every observation
    initial_error: float
    final_error: float
    iterations: int


# A prior tighter than ~1e-8 makes LM return its initial values (shared/ros-pypi/NOTES.md).
FIXED_SIGMA = 1e-6


def problem_graph(problem: BundleProblem) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    """The problem's poses and points with their priors (every factor but the projections)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, T in enumerate(problem.T_world_cam):
        values.insert(X(i), pose3(T))
        if i in problem.fixed_cameras:
            graph.add(gtsam.PriorFactorPose3(X(i), pose3(T), gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA)))
    for i, (centre, sigma) in problem.position_priors.items():
        # A prior on the camera centre only: a GPS-like factor on the pose's translation.
        graph.add(gtsam.GPSFactor(X(i), gtsam.Point3(*centre), gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
    if problem.baseline_prior is not None:
        a, b, dist, sigma = problem.baseline_prior
        graph.add(gtsam.RangeFactorPose3(X(a), X(b), dist, gtsam.noiseModel.Isotropic.Sigma(1, sigma)))
    used = np.unique(problem.obs.point)
    for j in used:
        values.insert(L(int(j)), gtsam.Point3(*problem.points[j]))
    for j, (xyz, sigma) in problem.point_priors.items():
        graph.add(gtsam.PriorFactorPoint3(L(j), gtsam.Point3(*xyz), gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
    return graph, values


def solve(problem: BundleProblem, max_iterations: int = 100) -> BundleResult:
    graph, values = problem_graph(problem)
    add_projection_factors(graph, problem.obs, problem.cameras, X, L, problem.huber_k)
    result, initial_error, final_error, iterations = optimize(graph, values, max_iterations)
    T_out = [result.atPose3(X(i)).matrix() for i in range(len(problem.T_world_cam))]
    points = problem.points.copy()
    for j in np.unique(problem.obs.point):
        points[j] = result.atPoint3(L(int(j)))
    return BundleResult(
        T_out,
        points,
        reprojection_residuals(problem.cameras, T_out, points, problem.obs),
        initial_error,
        final_error,
        iterations,
    )


def add_projection_factors(
    graph, obs: Observations, cameras: list[CameraModel], pose_key, point_key, huber_k: float
) -> None:
    """One Huber-robust projection factor per observation (ideal pixels, Cal3_S2)."""
    cals = [cal3(c) for c in cameras]
    huber = gtsam.noiseModel.mEstimator.Huber.Create(huber_k)
    models: dict[float, gtsam.noiseModel.Base] = {}
    for c, j, uv, s in zip(obs.camera, obs.point, obs.uv, obs.sigma_px):
        model = models.get(float(s))
        if model is None:
            model = models[float(s)] = gtsam.noiseModel.Robust.Create(
                huber, gtsam.noiseModel.Isotropic.Sigma(2, float(s))
            )
        graph.add(
            gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(*uv), model, pose_key(int(c)), point_key(int(j)), cals[c])
        )


def optimize(graph, values, max_iterations: int, relative_error_tol: float = 1e-10):
    """Levenberg-Marquardt: (result values, initial error, final error, iterations). It stops
    when an iteration lowers the error by less than ``relative_error_tol`` (relative and
    absolute). The default converges fully: GTSAM's (1e-5) stops early in the flat valleys of
    weak geometries."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(relative_error_tol)
    params.setAbsoluteErrorTol(relative_error_tol)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    initial_error = graph.error(values)
    result = optimizer.optimize()
    return result, initial_error, graph.error(result), optimizer.iterations()


def reprojection_residuals(
    cameras: list[CameraModel], T_world_cam: list[np.ndarray], points: np.ndarray, obs: Observations
) -> np.ndarray:
    """observed - projected (ideal pixels), (M, 2); NaN for points behind the camera."""
    out = np.full((len(obs), 2), np.nan)
    for c in np.unique(obs.camera):
        sel = obs.camera == c
        T = T_world_cam[c]
        P = (points[obs.point[sel]] - T[:3, 3]) @ T[:3, :3]
        front = P[:, 2] > 1e-9
        uv = P[:, :2] / np.where(front, P[:, 2], 1.0)[:, None] @ cameras[c].K[:2, :2].T + cameras[c].K[:2, 2]
        res = obs.uv[sel] - uv
        res[~front] = np.nan
        out[sel] = res
    return out


def robust_sigma(residuals_px: np.ndarray) -> float:
    """Per-axis pixel sigma from residuals by the median absolute deviation."""
    r = residuals_px[np.isfinite(residuals_px).all(axis=1)].reshape(-1)
    if len(r) < 4:
        return float("nan")
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def pose_covariance(
    camera: CameraModel, T_world_cam: np.ndarray, points: np.ndarray, uv: np.ndarray, sigma_px
) -> np.ndarray:
    """Marginal covariance of one camera pose seen through fixed 3D points (GTSAM Pose3
    tangent order [rotation, translation], body frame)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    values.insert(X(0), pose3(T_world_cam))
    cal = cal3(camera)
    fixed = gtsam.noiseModel.Isotropic.Sigma(3, FIXED_SIGMA)
    sigmas = np.broadcast_to(np.asarray(sigma_px, dtype=float), (len(points),))
    for j, (P, p, s) in enumerate(zip(points, uv, sigmas)):
        values.insert(L(j), gtsam.Point3(*P))
        graph.add(gtsam.PriorFactorPoint3(L(j), gtsam.Point3(*P), fixed))
        graph.add(
            gtsam.GenericProjectionFactorCal3_S2(
                gtsam.Point2(*p), gtsam.noiseModel.Isotropic.Sigma(2, float(s)), X(0), L(j), cal
            )
        )
    return gtsam.Marginals(graph, values).marginalCovariance(X(0))
