"""Intrinsics of cameras without CameraInfo, estimated from the agent (yowo_cmc.intrinsics)."""

from dataclasses import replace

import cv2
import numpy as np
import pytest

from cmc_synthetic import HEIGHT, ceiling_camera, loop_walk, observe
from yowo_cmc.group_sfm import GroupingResult, calibrate_groups
from yowo_cmc.intrinsics import EstimatedCamera, focal_from_fundamental, pnp_unknown_focal
from yowo_cmc.messages import groups_from_msg, groups_to_msg
from yowo_cmc.params import SfmParams
from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3
from yowo_eval.metrics import relative_pose_errors

WALK = loop_walk((3.0, 2.5), (2.0, 1.5))
HFOV = (20.0, 150.0)


def rig(D=None):
    return {
        "a": ceiling_camera(0.3, 0.3, (3.0, 2.5), D=D),
        "b": ceiling_camera(5.7, 0.4, (3.0, 2.5), z=3.3, D=D),
        "c": ceiling_camera(3.0, 4.8, (3.0, 2.3), z=2.8, hfov=65.0, D=D),
    }


def walk_points(n=200, seed=0):
    """Agent points (head tops and ground points) along the walk."""
    t = np.random.default_rng(seed).uniform(0, 20, n)
    xy = np.array([WALK(tt) for tt in t])
    return np.vstack([np.column_stack([xy, np.full(n, HEIGHT)]), np.column_stack([xy, np.zeros(n)])])


def project(cam, T, X, sigma_px=0.0, seed=1):
    uv, front = cam.project_world(T, X)
    keep = front & cam.in_image(uv)
    return uv[keep] + np.random.default_rng(seed).normal(size=uv[keep].shape) * sigma_px, keep


def test_pair_focal_from_the_fundamental_matrix():
    cams = rig()
    (ca, Ta), (cb, Tb) = cams["a"], cams["c"]
    X = walk_points()
    ua, ka = project(ca, Ta, X, 0.5, seed=1)
    ub, kb = project(cb, Tb, X, 0.5, seed=2)
    both = ka & kb
    ua, ub = project(ca, Ta, X[both], 0.5, seed=1)[0], project(cb, Tb, X[both], 0.5, seed=2)[0]
    cv2.setRNGSeed(0)
    F, _ = cv2.findFundamentalMat(ua, ub, cv2.USAC_MAGSAC, 1.0, 0.9999, 10000)
    fa, fb = focal_from_fundamental(F, ca.K, (640, 480), (640, 480), HFOV)
    assert fa == ca.K[0, 0]
    assert abs(fb / cb.K[0, 0] - 1) < 0.03
    # Exact F (noise-free): the focal to the search's resolution.
    R = (inv_se3(Tb) @ Ta)[:3, :3]
    t = (inv_se3(Tb) @ Ta)[:3, 3]
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R
    F_exact = np.linalg.inv(cb.K).T @ E @ np.linalg.inv(ca.K)
    assert abs(focal_from_fundamental(F_exact, ca.K, (640, 480), (640, 480), HFOV)[1] / cb.K[0, 0] - 1) < 0.01


def test_pnp_with_unknown_focal_and_k1():
    cam, T = ceiling_camera(0.3, 0.3, (3.0, 2.5), hfov=72.0, D=[-0.12, 0, 0, 0, 0])
    X = walk_points(300)
    uv, keep = project(cam, T, X, 0.5)
    found = pnp_unknown_focal(X[keep], uv, (640, 480), HFOV, 24, 4.0, 8, True)
    assert found is not None
    est, rvec, tvec, idx = found
    assert abs(est.K[0, 0] / cam.K[0, 0] - 1) < 0.01
    assert abs(est.D[0] - cam.D[0]) < 0.01
    assert len(idx) > 0.95 * keep.sum()
    T_est = inv_se3(np.vstack([np.column_stack([cv2.Rodrigues(rvec)[0], tvec.ravel()]), [0, 0, 0, 1]]))
    assert np.linalg.norm(T_est[:3, 3] - T[:3, 3]) < 0.02


def nominal(tracks, names):
    """The tracks of `names` as a camera without CameraInfo gives them: a 90 deg nominal model."""
    return [
        replace(t, camera=CameraModel.from_fov(t.camera.width, t.camera.height, 90.0)) if t.name in names else t
        for t in tracks
    ]


def check_relative(group, cams, pos_tol, rot_tol_deg):
    errs, _ = relative_pose_errors(group.T_local_cam, {n: cams[n][1] for n in group.names}, {"g": group.names})
    assert max(e.eps_pos_m for e in errs) < pos_tol
    assert max(e.eps_rot_deg for e in errs) < rot_tol_deg


@pytest.mark.parametrize("unknown", ["a", "c"])
def test_group_estimates_an_unknown_focal_and_k1(unknown):
    # "c" is in the initial pair (its focal from the pair's F), "a" is added by PnP.
    cams = rig(D=[-0.1, 0, 0, 0, 0])
    tracks = observe(cams, WALK, 40.0, sigma_px=1.0, seed=3)
    (group,) = calibrate_groups(nominal(tracks, {unknown}), SfmParams(), estimate=frozenset({unknown})).groups
    assert sorted(group.names) == ["a", "b", "c"]
    est, true = group.cameras[unknown], cams[unknown][0]
    assert isinstance(est, EstimatedCamera)
    assert abs(est.K[0, 0] / true.K[0, 0] - 1) < 0.01
    assert abs(est.D[0] - true.D[0]) < 0.01
    assert 0 < est.focal_sigma_px < 0.01 * true.K[0, 0]
    assert abs(est.K[0, 0] - true.K[0, 0]) < 4 * est.focal_sigma_px
    # The known cameras keep their CameraInfo's intrinsics.
    assert all(not isinstance(group.cameras[n], EstimatedCamera) for n in group.names if n != unknown)
    check_relative(group, cams, 0.03, 0.3)
    # The estimate and its sigma survive the group message.
    back = groups_from_msg(groups_to_msg(GroupingResult([group], {}, []), 0))[0][0]
    assert isinstance(back.cameras[unknown], EstimatedCamera)
    assert back.cameras[unknown].focal_sigma_px == pytest.approx(est.focal_sigma_px)
    assert not isinstance(back.cameras["b"], EstimatedCamera)


def test_a_group_with_no_known_intrinsics_is_not_calibrated():
    cams = rig()
    tracks = observe(cams, WALK, 40.0, sigma_px=1.0, seed=3)
    result = calibrate_groups(nominal(tracks, {"a", "b", "c"}), SfmParams(), estimate=frozenset({"a", "b", "c"}))
    assert not result.groups
    assert sorted(result.ungrouped) == ["a", "b", "c"]
    assert all("no camera of its group has known intrinsics" in why for why in result.ungrouped.values())
