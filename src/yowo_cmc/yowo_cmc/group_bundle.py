"""Bundle adjustment of one CMC group (paper eq. cmc_bd) in robust rounds, each
weighting a keypoint class by the residual spread of the previous round (variance
component estimation)."""

from __future__ import annotations

import numpy as np

from yowo_common.bundle import BundleProblem, Observations, robust_sigma, solve

from .incremental_sfm import IncrementalSfm
from .intrinsics import solve_with_intrinsics
from .params import SfmParams
from .scene_graph import MAX_IDS, PERSON_STRIDE, PairGeometry


def robust_rounds(sfm: IncrementalSfm, init: PairGeometry, params: SfmParams) -> tuple[dict, dict[int, float]]:
    """The group's bundle adjustments: after each, every keypoint class's sigma from its
    residuals, until no sigma moves by more than sigma_tolerance. (The last adjustment,
    the sigmas by keypoint id.)"""
    sigma_by_id: dict[int, float] = {}
    for round_ in range(max(params.sigma_rounds, 2) if params.class_sigma else 1):
        if round_:
            # Points rejected under the pre-BA poses get a second chance, at the wider gate.
            sfm.triangulate_new(params.rounds_reproj_px)
        ba = bundle_adjust(sfm, init.a, init.b, sigma_by_id)
        previous, sigma_by_id = sigma_by_id, residual_sigmas(ba, params.sigma_class_bounds, sfm.obs.skeleton)
        if previous and all(abs(sigma_by_id.get(i, v) / v - 1) <= params.sigma_tolerance for i, v in previous.items()):
            break
    return ba, sigma_by_id


def bundle_adjust(sfm: IncrementalSfm, reference: int, second: int, sigma_by_id: dict[int, float]) -> dict:
    """One bundle adjustment of the group's posed cameras and points (the reference fixed,
    the initial pair's baseline held), each observation's sigma from `sigma_by_id` (else
    initial_sigma_px, times the camera's noise scale) and its detection's weight; the
    estimates of unknown intrinsics refined too. Returns the observations ("obs"), their
    residuals px, the cameras ("cams") and the point keys ("keys")."""
    cams = sorted(sfm.poses)
    index = {c: i for i, c in enumerate(cams)}
    keys = np.array(sorted(sfm.points), dtype=np.int64)
    kidx = {int(k): i for i, k in enumerate(keys)}
    cam_i, pt_i, uv, raw, sig = [], [], [], [], []
    for c in cams:
        for k, p in sfm.obs.per_camera[c].items():
            if k in kidx:
                cam_i.append(index[c])
                pt_i.append(kidx[k])
                uv.append(p)
                raw.append(sfm.raw[c][k])
                sig.append(
                    sigma_by_id.get(k % MAX_IDS, sfm.params.initial_sigma_px * sfm.obs.noise_scale[c])
                    * sfm.obs.sigma_factor[c].get(k, 1.0)
                )
    obs = Observations(
        np.array(cam_i, dtype=int),
        np.array(pt_i, dtype=int),
        np.array(uv).reshape(-1, 2),
        np.array(sig, dtype=float),
    )
    baseline = np.linalg.norm(sfm.poses[second][:3, 3])
    problem = BundleProblem(
        [sfm.obs.cameras[c] for c in cams],
        [sfm.poses[c] for c in cams],
        np.array([sfm.points[int(k)] for k in keys]),
        obs,
        fixed_cameras={index[reference]},
        # The scale gauge only (a prior on a centre would also pin the
        # baseline's direction to its noisy initial estimate).
        baseline_prior=(index[reference], index[second], baseline, 1e-4 * baseline),
    )
    unknown = {index[c]: sfm.estimated.get(c, sfm.obs.cameras[c]) for c in cams if c in sfm.unknown}
    if unknown:
        res, estimated = solve_with_intrinsics(problem, unknown, np.array(raw).reshape(-1, 2), sfm.params.estimate_k1)
        for c in cams:
            if index[c] in estimated:
                sfm.set_intrinsics(c, estimated[index[c]])
    else:
        res = solve(problem)
    for c in cams:
        sfm.poses[c] = res.T_world_cam[index[c]]
    for k, i in kidx.items():
        sfm.points[k] = res.points[i]
    return {"obs": obs, "residuals": res.residuals_px, "cams": cams, "keys": keys}


def residual_sigmas(ba: dict, class_bounds: tuple[int, ...], skeleton=None) -> dict[int, float]:
    """{keypoint id: robust sigma px} from a bundle adjustment's residuals, pooled over each
    keypoint class (the declared skeleton's, else ids split at class_bounds; classes with 10
    or more residuals)."""
    kp_ids = ba["keys"][ba["obs"].point] % MAX_IDS
    joints = kp_ids % PERSON_STRIDE  # every person's joint is of its joint's class
    if skeleton is not None:
        ids, where = np.unique(joints, return_inverse=True)
        kinds = [skeleton.noise_class(int(k)) for k in ids]
        order = sorted(set(kinds))
        classes = np.array([order.index(c) for c in kinds], dtype=np.int64)[where]
    else:
        classes = np.searchsorted(np.asarray(class_bounds, dtype=np.int64), joints, side="right")
    sigma = {
        int(k): max(robust_sigma(ba["residuals"][classes == k]), 0.05)
        for k in np.unique(classes)
        if np.sum(classes == k) >= 10
    }
    return {int(i): sigma[int(k)] for i, k in zip(*np.unique(np.stack([kp_ids, classes]), axis=1)) if int(k) in sigma}
