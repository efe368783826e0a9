"""Per calibrated group, the members' clock offsets refined in one fit with the group's
poses and agent points (yowo_cmc.clock's pair fits each see two cameras only)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from yowo_common.bundle import robust_sigma

from .clock_pairs import SplineTracks
from .group_sfm import CameraGroupResult
from .keypoint_tracks import CameraTracks
from .params import ClockParams, SfmParams
from .scene_graph import PERSON_STRIDE


def triangulate_weighted(
    P: np.ndarray,
    cam_i: np.ndarray,
    pt_i: np.ndarray,
    uv: np.ndarray,
    weight: np.ndarray,
    n_points: int,
    iterations: int = 2,
) -> np.ndarray:
    """Every point from its observations at once: linear (DLT) then Gauss-Newton steps on
    the weighted reprojection error. P: (C, 3, 4) projection matrices."""
    Pc = P[cam_i]
    rows = (
        np.concatenate([uv[:, :1] * Pc[:, 2] - Pc[:, 0], uv[:, 1:] * Pc[:, 2] - Pc[:, 1]])
        * np.r_[weight, weight][:, None]
    )
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    M = np.zeros((n_points, 4, 4))
    np.add.at(M, np.r_[pt_i, pt_i], rows[:, :, None] * rows[:, None, :])
    X = np.linalg.eigh(M)[1][:, :, 0]
    X = X[:, :3] / np.where(np.abs(X[:, 3:]) > 1e-12, X[:, 3:], 1e-12)
    for _ in range(iterations):
        h = np.einsum("nij,nj->ni", Pc[:, :, :3], X[pt_i]) + Pc[:, :, 3]
        r = (h[:, :2] / h[:, 2:] - uv) * weight[:, None]
        J = (Pc[:, :2, :3] - (h[:, :2] / h[:, 2:])[:, :, None] * Pc[:, 2:, :3]) / h[:, 2:, None] * weight[:, None, None]
        H, g = np.zeros((n_points, 3, 3)), np.zeros((n_points, 3))
        np.add.at(H, pt_i, np.einsum("nki,nkj->nij", J, J))
        np.add.at(g, pt_i, np.einsum("nki,nk->ni", J, r))
        X = X - np.linalg.solve(H + 1e-9 * np.eye(3), g[:, :, None])[:, :, 0]
    return X


def refine_group_offsets(
    group: CameraGroupResult, tracks: dict[str, CameraTracks], params: ClockParams, sfm: SfmParams
) -> dict[str, tuple[float, float]]:
    """Corrections to the members' clocks, each against the group's reference camera: one
    robust least-squares fit of every member's pose and correction, the agent points
    triangulated anew at every step (variable projection), each member's observation of
    a point taken from its track at the point's time plus its correction (second-order
    Taylor expansion of the track's spline). `tracks`: the members' tracks on the clock of
    the group's points. Returns name -> (correction [s], sigma [s]) for the members it
    could refine (the reference's correction is 0 by definition); the sigma is the
    correction's marginal, scaled like the pairs' for the smoothed tracks."""
    members = [n for n in group.names if n in tracks]
    if group.reference not in members or len(group.point_stamps_ns) == 0:
        return {}
    origin = int(group.point_stamps_ns.min())
    cams = [SplineTracks(tracks[n], origin, sfm) for n in members]
    found = _track_observations(group, cams, (group.point_stamps_ns - origin) / 1e9, params)
    if found is None:
        return {}
    cam_i, pt_i, pts, taylor = found
    ref = members.index(group.reference)
    free = [k for k in range(len(members)) if k != ref]
    if len(pts) < sfm.min_pnp or any(np.sum(cam_i == k) < params.refine_min_observations for k in free):
        return {}
    weight = (
        1.0 / np.array([group.sigma_px_by_id.get(int(i), sfm.initial_sigma_px) for i in group.point_ids[pts]])[pt_i]
    )
    residuals = _residual_function(group, members, cams, free, cam_i, pt_i, len(pts), taylor, weight)
    w = params.refine_range_s
    x0 = np.zeros(7 * len(free))
    lo, hi = np.full(len(x0), -np.inf), np.full(len(x0), np.inf)
    lo[6::7], hi[6::7] = -w, w
    fit = least_squares(residuals, x0, bounds=(lo, hi), loss="huber", f_scale=1.345, x_scale="jac", method="trf")
    return _corrections(fit, members, free, cams, 2 * len(cam_i), len(pts), params)


def _track_observations(
    group: CameraGroupResult, cams: list[SplineTracks], t_pts: np.ndarray, params: ClockParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]] | None:
    """The members' observations of the group's points (at times t_pts [s]) from their
    tracks, where a track's segment covers the point's time +- refine_range_s: (member
    index, index into `pts`, `pts` (the points seen by two members at least, evenly
    thinned over time), the track's position and its first and second derivatives at
    the point's time). None if no member sees any point."""
    w = params.refine_range_s
    cam_i, pt_i, uv0, uv1, uv2 = [], [], [], [], []
    # One person's track times the clocks: the agent's (others' joints are numbered from
    # PERSON_STRIDE), at the cost of the walker-only refinement.
    ids = np.unique(group.point_ids)
    for ci, c in enumerate(cams):
        for i in ids[ids < PERSON_STRIDE]:
            sel = np.flatnonzero(group.point_ids == i)
            for t0, t1, spline in c.splines.get(int(i), []):
                inside = sel[(t_pts[sel] - w >= t0) & (t_pts[sel] + w <= t1)]
                if len(inside):
                    cam_i.append(np.full(len(inside), ci))
                    pt_i.append(inside)
                    uv0 += [spline(t_pts[inside])]
                    uv1 += [spline(t_pts[inside], 1)]
                    uv2 += [spline(t_pts[inside], 2)]
    if not cam_i:
        return None
    cam_i, pt_i = np.concatenate(cam_i), np.concatenate(pt_i)
    uv0, uv1, uv2 = np.vstack(uv0), np.vstack(uv1), np.vstack(uv2)
    # Points seen by two members at least, evenly thinned over time (deterministic).
    pts = np.flatnonzero(np.bincount(pt_i, minlength=len(t_pts)) >= 2)
    pts = pts[np.argsort(t_pts[pts], kind="stable")]
    pts = pts[np.linspace(0, len(pts) - 1, min(len(pts), params.refine_max_points)).astype(int)] if len(pts) else pts
    keep = np.isin(pt_i, pts)
    return cam_i[keep], np.searchsorted(pts, pt_i[keep]), pts, (uv0[keep], uv1[keep], uv2[keep])


def _residual_function(
    group: CameraGroupResult,
    members: list[str],
    cams: list[SplineTracks],
    free: list[int],
    cam_i: np.ndarray,
    pt_i: np.ndarray,
    n_points: int,
    taylor: tuple[np.ndarray, np.ndarray, np.ndarray],
    weight: np.ndarray,
):
    """x -> the weighted reprojection residuals and the scale gauge; x holds per free
    member a rotation vector and a translation on its pose (camera from local) and its
    clock correction [s]."""
    uv0, uv1, uv2 = taylor
    K = np.array([c.camera.K for c in cams])
    T0 = [np.linalg.inv(group.T_local_cam[n]) for n in members]  # T_cam_local
    ref = members.index(group.reference)
    second = members.index(group.initial_pair[1]) if group.initial_pair[1] in members else free[0]
    baseline = float(np.linalg.norm(group.T_local_cam[members[second]][:3, 3] - group.T_local_cam[members[ref]][:3, 3]))

    def unpack(x):
        T, d = [t.copy() for t in T0], np.zeros(len(members))
        for j, k in enumerate(free):
            T[k][:3, :3] = Rotation.from_rotvec(x[7 * j : 7 * j + 3]).as_matrix() @ T0[k][:3, :3]
            T[k][:3, 3] = T0[k][:3, 3] + x[7 * j + 3 : 7 * j + 6]
            d[k] = x[7 * j + 6]
        return T, d

    def residuals(x):
        T, d = unpack(x)
        P = np.einsum("cij,cjk->cik", K, np.array(T)[:, :3, :])
        dc = d[cam_i][:, None]
        target = uv0 + dc * uv1 + 0.5 * dc**2 * uv2
        X = triangulate_weighted(P, cam_i, pt_i, target, weight, n_points)
        h = np.einsum("nij,nj->ni", P[cam_i][:, :, :3], X[pt_i]) + P[cam_i][:, :, 3]
        r = (h[:, :2] / h[:, 2:] - target) * weight[:, None]
        centres = [-T[k][:3, :3].T @ T[k][:3, 3] for k in (second, ref)]
        # The scale gauge: the initial pair's baseline stays as the group SfM fixed it.
        gauge = (np.linalg.norm(centres[0] - centres[1]) - baseline) / (1e-4 * baseline)
        return np.concatenate([r.ravel(), [gauge]])

    return residuals


def _corrections(
    fit, members: list[str], free: list[int], cams: list[SplineTracks], n_res: int, n_points: int, params: ClockParams
) -> dict[str, tuple[float, float]]:
    """name -> (correction [s], sigma [s]) of the free members whose correction stayed
    inside its range."""
    # The residuals' spread understates the noise by the unknowns fitted to them: each point's
    # 3 coordinates (a point seen twice keeps 1 of its 4 residual dof) and the members' 7.
    dof = max(n_res - 3 * n_points - len(fit.x), 1)
    scale = robust_sigma(fit.fun[:-1].reshape(-1, 2)) ** 2 * n_res / dof
    corr = max(c.correlation for c in cams) if params.correlated_sigma else 1.0
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * scale * corr
    except np.linalg.LinAlgError:
        return {}
    w = params.refine_range_s
    out = {}
    for j, k in enumerate(free):
        delta = float(fit.x[7 * j + 6])
        if min(delta + w, w - delta) < 1e-3 * w:
            continue  # ran to the edge of its range: no clear minimum, keep the pairs' estimate
        out[members[k]] = (delta, max(float(np.sqrt(max(cov[7 * j + 6, 7 * j + 6], 0.0))), params.min_sigma_s))
    return out
