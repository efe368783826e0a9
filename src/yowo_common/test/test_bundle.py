import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.bundle import BundleProblem, Observations, robust_sigma, solve
from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at, se3


def scene(seed=0, n_cams=5, n_pts=150):
    rng = np.random.default_rng(seed)
    cams = [CameraModel.from_fov(640, 480, 70) for _ in range(n_cams)]
    poses = [look_at([4 * np.cos(a), 4 * np.sin(a), 2.5], [0, 0, 1]) for a in np.linspace(0, 2.5, n_cams)]
    pts = rng.uniform([-1.5, -1.5, 0], [1.5, 1.5, 2], (n_pts, 3))
    cam_idx, pt_idx, uv = [], [], []
    for c, (cam, T) in enumerate(zip(cams, poses)):
        p, ok = cam.project_world(T, pts)
        ok &= cam.in_image(p)
        cam_idx += [c] * ok.sum()
        pt_idx += list(np.flatnonzero(ok))
        uv.append(p[ok])
    obs = Observations(np.array(cam_idx), np.array(pt_idx), np.vstack(uv), np.ones(len(cam_idx)))
    return cams, poses, pts, obs, rng


def perturbed(poses, pts, rng, rot_deg=1.0, trans_m=0.05, pt_m=0.05):
    P = [
        se3(
            Rotation.from_rotvec(rng.normal(size=3) * np.radians(rot_deg)).as_matrix() @ T[:3, :3],
            T[:3, 3] + rng.normal(size=3) * trans_m,
        )
        for T in poses
    ]
    return P, pts + rng.normal(size=pts.shape) * pt_m


def pose_error(A, B):
    return max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(A, B))


def test_noise_free_ba_recovers_truth():
    cams, poses, pts, obs, rng = scene()
    P0, X0 = perturbed(poses, pts, rng)
    P0[0] = poses[0]
    prob = BundleProblem(cams, P0, X0, obs, fixed_cameras={0}, position_priors={1: (poses[1][:3, 3], 1e-4)})
    res = solve(prob)
    assert pose_error(res.T_world_cam, poses) < 1e-4
    assert np.abs(res.residuals_px).max() < 1e-3
    assert res.final_error < res.initial_error


def test_huber_beats_least_squares_with_outliers():
    cams, poses, pts, obs, rng = scene(seed=1)
    obs.uv += rng.normal(size=obs.uv.shape) * 0.5
    bad = rng.random(len(obs)) < 0.05
    obs.uv[bad] += rng.uniform(-40, 40, (bad.sum(), 2))
    P0, X0 = perturbed(poses, pts, rng)
    P0[0] = poses[0]
    kw = dict(fixed_cameras={0}, position_priors={1: (poses[1][:3, 3], 1e-4)})
    robust = solve(BundleProblem(cams, P0, X0, obs, **kw))
    plain = solve(BundleProblem(cams, P0, X0, obs, huber_k=1e9, **kw))
    assert pose_error(robust.T_world_cam, poses) < 0.5 * pose_error(plain.T_world_cam, poses)
    assert robust_sigma(robust.residuals_px[~bad]) == pytest.approx(0.5, rel=0.25)
