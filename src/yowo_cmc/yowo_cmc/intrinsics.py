"""Intrinsics of a CMC without CameraInfo, estimated from the agent it sees: one focal
length (square pixels, principal point at the image centre, no skew) and optionally the
radial distortion k1. The initial focal comes from a pair's two-view geometry or from a
PnP over a range of focal lengths; the group bundle adjustment refines it with a
calibration variable per such camera (GTSAM's GeneralSFMFactor2Cal3Bundler)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import gtsam
import numpy as np
from gtsam.symbol_shorthand import K as CAL
from gtsam.symbol_shorthand import L, X

from yowo_common.bundle import FIXED_SIGMA, BundleProblem, BundleResult, optimize, problem_graph
from yowo_common.camera import CameraModel
from yowo_common.pnp import sqpnp_ransac


@dataclass
class EstimatedCamera(CameraModel):
    """Intrinsics estimated by the group SfM (not from CameraInfo), with their sigmas."""

    focal_sigma_px: float = float("nan")
    k1_sigma: float = float("nan")  # nan: k1 was not estimated (held at 0)
    k2_sigma: float = float("nan")  # nan: k2 was not estimated (held at 0)

    @classmethod
    def of(
        cls, camera: CameraModel, focal_sigma_px: float, k1_sigma: float = float("nan"), k2_sigma: float = float("nan")
    ) -> EstimatedCamera:
        """`camera`'s intrinsics marked as estimated, with their sigmas."""
        return cls(
            camera.width,
            camera.height,
            camera.K,
            camera.D,
            camera.distortion_model,
            focal_sigma_px=focal_sigma_px,
            k1_sigma=k1_sigma,
            k2_sigma=k2_sigma,
        )


def centred(width: int, height: int, f: float, k1: float = 0.0, k2: float = 0.0) -> CameraModel:
    """The estimated model: focal f (px) for both axes, principal point at the image centre."""
    K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return CameraModel(width, height, K, np.array([k1, k2, 0.0, 0.0, 0.0]))


def focal_range(width: int, hfov_deg: tuple[float, float], steps: int) -> np.ndarray:
    """Focal lengths (px) evenly spaced in log between the horizontal fields of view."""
    f = [0.5 * width / np.tan(np.radians(h) / 2.0) for h in sorted(hfov_deg, reverse=True)]
    return np.geomspace(f[0], f[1], steps)


def essential_cost(F: np.ndarray, Ka: np.ndarray, Kb: np.ndarray) -> float:
    """How far E = Kb^T F Ka is from an essential matrix (two equal singular values):
    (s1 - s2) / s2 (Mendonca-Cipolla)."""
    s = np.linalg.svd(Kb.T @ F @ Ka, compute_uv=False)
    return float((s[0] - s[1]) / max(s[1], 1e-300))


def focal_from_fundamental(
    F: np.ndarray,
    Ka: np.ndarray | None,
    size_a: tuple[int, int],
    size_b: tuple[int, int],
    hfov_deg: tuple[float, float],
    steps: int = 200,
) -> tuple[float, float]:
    """Focal lengths (f_a, f_b) of the pair x_b^T F x_a = 0 from its fundamental matrix:
    camera b's (principal point at the centre) by a 1-D search over the field of view,
    with a's intrinsics Ka; both unknown (Ka None): one focal shared by both, a's in the
    units of its own image width."""

    def K(size, f):
        return centred(size[0], size[1], f).K

    fb = focal_range(size_b[0], hfov_deg, steps)
    if Ka is None:
        cost = [essential_cost(F, K(size_a, f * size_a[0] / size_b[0]), K(size_b, f)) for f in fb]
    else:
        cost = [essential_cost(F, Ka, K(size_b, f)) for f in fb]
    f = float(fb[int(np.argmin(cost))])
    return (f * size_a[0] / size_b[0] if Ka is None else float(Ka[0, 0])), f


def pnp_unknown_focal(
    points: np.ndarray,
    uv: np.ndarray,
    size: tuple[int, int],
    hfov_deg: tuple[float, float],
    steps: int,
    reprojection_px: float,
    min_inliers: int,
    estimate_k1: bool,
    seed: int = 0,
) -> tuple[CameraModel, np.ndarray, np.ndarray, np.ndarray] | None:
    """(intrinsics, rvec, tvec, inlier indices) of a camera with unknown focal (and k1) from
    2D-3D matches: SQPnP RANSAC at each focal of the range, the one with most inliers
    refined with the pose by OpenCV's calibration (principal point and aspect fixed), the
    inliers re-selected under the refined model. None: no focal found min_inliers."""
    best = None
    for f in focal_range(size[0], hfov_deg, steps):
        rvec, tvec, idx = sqpnp_ransac(points, uv, centred(*size, f).K, reprojection_px, seed=seed)
        if len(idx) >= min_inliers and (best is None or len(idx) > len(best[3])):
            best = (f, rvec, tvec, idx)
    if best is None:
        return None
    f, rvec, tvec, idx = best
    cam = centred(*size, f)
    flags = (
        cv2.CALIB_USE_INTRINSIC_GUESS
        | cv2.CALIB_FIX_PRINCIPAL_POINT
        | cv2.CALIB_FIX_ASPECT_RATIO
        | cv2.CALIB_ZERO_TANGENT_DIST
        | cv2.CALIB_FIX_K2
        | cv2.CALIB_FIX_K3
        | (0 if estimate_k1 else cv2.CALIB_FIX_K1)
    )
    obj = np.ascontiguousarray(points, np.float32)
    img = np.ascontiguousarray(uv, np.float32)
    # The inliers at the grid's focal miss the image's distorted rim: refit, re-select, twice.
    for _ in range(3):
        _, K, D, rvecs, tvecs = cv2.calibrateCamera(
            [obj[idx]], [img[idx]], size, cam.K.copy(), cam.D.copy(), flags=flags
        )
        cam = centred(*size, float(K[0, 0]), float(D.ravel()[0]))
        rvec, tvec = rvecs[0], tvecs[0]
        proj = cv2.projectPoints(obj.astype(float), rvec, tvec, cam.K, cam.D)[0].reshape(-1, 2)
        inl = np.flatnonzero(np.linalg.norm(proj - uv, axis=1) <= reprojection_px)
        if len(inl) < min_inliers:
            break
        idx = inl
    return cam, rvec, tvec, idx


def solve_with_intrinsics(
    problem: BundleProblem,
    unknown: dict[int, CameraModel],
    raw_uv: np.ndarray,
    estimate_k1: bool,
    max_iterations: int = 100,
) -> tuple[BundleResult, dict[int, EstimatedCamera]]:
    """yowo_common.bundle.solve with a calibration variable (focal, k1) per camera in
    `unknown` (its current estimate): the observations of those cameras are raw pixels
    (`raw_uv`, parallel to problem.obs). k2 is held at 0, and k1 too unless estimate_k1."""
    graph, values = problem_graph(problem)
    add_calibrations(graph, values, unknown, estimate_k1)
    _add_observations(graph, problem, unknown, raw_uv)
    result, initial_error, final_error, iterations = optimize(graph, values, max_iterations)
    T_out = [result.atPose3(X(i)).matrix() for i in range(len(problem.T_world_cam))]
    points = problem.points.copy()
    for j in np.unique(problem.obs.point):
        points[j] = result.atPoint3(L(int(j)))
    estimated = estimated_cameras(result, unknown, estimate_k1, gtsam.Marginals(graph, result))
    cameras = [estimated.get(i, c) for i, c in enumerate(problem.cameras)]
    obs = problem.obs
    residuals = np.full((len(obs), 2), np.nan)
    for c in np.unique(obs.camera):
        sel = obs.camera == c
        T = T_out[c]
        proj, front = cameras[c].project((points[obs.point[sel]] - T[:3, 3]) @ T[:3, :3])
        res = (raw_uv[sel] if int(c) in unknown else obs.uv[sel]) - proj
        res[~front] = np.nan
        residuals[sel] = res
    return BundleResult(T_out, points, residuals, initial_error, final_error, iterations), estimated


def add_calibrations(
    graph, values, unknown: dict[int, CameraModel], estimate_k1: bool, k2_prior_sigma: float = 0.0
) -> None:
    """A calibration variable K(i) per unknown camera i, from its current estimate (for
    GeneralSFMFactor2Cal3Bundler on its raw pixels). k2 is held at 0 unless k2_prior_sigma > 0:
    then it is estimated with that prior around 0."""
    # Cal3Bundler: (f, k1, k2) with the principal point fixed at the centre; the prior pins
    # what is not estimated (k2, and k1 unless asked) and leaves f free.
    free = 1e6
    for i, cam in unknown.items():
        k1 = cam.D[0] if estimate_k1 else 0.0
        mean = gtsam.Cal3Bundler(cam.K[0, 0], k1, 0.0, cam.K[0, 2], cam.K[1, 2])
        values.insert(
            CAL(i),
            gtsam.Cal3Bundler(cam.K[0, 0], k1, cam.D[1] if k2_prior_sigma > 0 else 0.0, cam.K[0, 2], cam.K[1, 2]),
        )
        sigmas = [free * cam.K[0, 0], free if estimate_k1 else FIXED_SIGMA, k2_prior_sigma or FIXED_SIGMA]
        graph.add(gtsam.PriorFactorCal3Bundler(CAL(i), mean, gtsam.noiseModel.Diagonal.Sigmas(np.array(sigmas))))


def _add_observations(graph, problem: BundleProblem, unknown: dict[int, CameraModel], raw_uv: np.ndarray) -> None:
    """One Huber-robust projection factor per observation: an unknown camera's raw pixel
    through its calibration variable, a known camera's ideal pixel through its K."""
    cals = [gtsam.Cal3_S2(c.K[0, 0], c.K[1, 1], c.K[0, 1], c.K[0, 2], c.K[1, 2]) for c in problem.cameras]
    huber = gtsam.noiseModel.mEstimator.Huber.Create(problem.huber_k)
    models: dict[float, gtsam.noiseModel.Base] = {}
    obs = problem.obs
    for c, j, uv, raw, s in zip(obs.camera, obs.point, obs.uv, raw_uv, obs.sigma_px):
        model = models.get(float(s))
        if model is None:
            model = models[float(s)] = gtsam.noiseModel.Robust.Create(
                huber, gtsam.noiseModel.Isotropic.Sigma(2, float(s))
            )
        c, j = int(c), int(j)
        if c in unknown:
            graph.add(gtsam.GeneralSFMFactor2Cal3Bundler(gtsam.Point2(*raw), model, X(c), L(j), CAL(c)))
        else:
            graph.add(gtsam.GenericProjectionFactorCal3_S2(gtsam.Point2(*uv), model, X(c), L(j), cals[c]))


def estimated_cameras(
    result,
    unknown: dict[int, CameraModel],
    estimate_k1: bool,
    marginals: gtsam.Marginals | None,
    estimate_k2: bool = False,
) -> dict[int, EstimatedCamera]:
    """Each unknown camera's solved intrinsics with their marginal sigmas (NaN without marginals)."""
    estimated = {}
    for i, cam in unknown.items():
        cal = result.atCal3Bundler(CAL(i))
        cov = marginals.marginalCovariance(CAL(i)) if marginals is not None else np.full((3, 3), np.nan)
        base = centred(
            cam.width, cam.height, cal.fx(), cal.k1() if estimate_k1 else 0.0, cal.k2() if estimate_k2 else 0.0
        )
        estimated[i] = EstimatedCamera.of(
            base,
            float(np.sqrt(cov[0, 0])),
            float(np.sqrt(cov[1, 1])) if estimate_k1 else float("nan"),
            float(np.sqrt(cov[2, 2])) if estimate_k2 else float("nan"),
        )
    return estimated
