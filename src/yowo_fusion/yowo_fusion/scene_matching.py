"""Scene keypoints in a CMC view matched to the ego map's landmarks with a pose prior
(paper: "integrate CMC 6-DoF pose priors to match these 2D keypoints to 3D scene
keypoints"): features on the CMC's agent-free background image, candidates near each
landmark's projection, descriptor ratio test, then PnP RANSAC verification; kept only where
the prior predicts the verified matches."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, se3
from yowo_ego.features import create_sift


@dataclass(frozen=True)
class SceneMatchParams:
    radius_px: float = 40.0  # search radius around a landmark's predicted pixel
    ratio: float = 0.8  # Lowe's ratio test: best candidate's descriptor distance over the second best's [ratio]
    max_range_m: float = 15.0  # landmarks farther than this from the prior camera centre are not searched
    pnp_px: float = 4.0  # PnP RANSAC inlier threshold of the verification
    min_inliers: int = 12  # verified matches a camera needs at least [count]
    max_features: int = 4000  # features detected on the background image at most [count]
    # Verified matches lying farther than this (median) from where the prior projects their
    # landmarks are refused. They are a consistent set of wrong ones (a repeated pattern one
    # period over, a look-alike wall) or the prior is too far off for the guided search to
    # tell: no match either way.
    max_prior_median_px: float = 20.0


@dataclass
class SceneMatches:
    landmark: np.ndarray  # (M,) landmark index
    uv: np.ndarray  # (M, 2) ideal (undistorted) pixels
    T_world_cam: np.ndarray  # the PnP-verified pose


def detect_features(rgb: np.ndarray, kind: str, max_features: int):
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    detector = create_sift(max_features) if kind == "SIFT" else cv2.ORB_create(nfeatures=max_features)
    kps, desc = detector.detectAndCompute(gray, None)
    uv = np.array([k.pt for k in kps], dtype=float).reshape(-1, 2)
    return uv, desc


def _distances(desc_a: np.ndarray, desc_b: np.ndarray, kind: str) -> np.ndarray:
    if kind == "SIFT":
        return np.linalg.norm(desc_a.astype(np.float32) - desc_b.astype(np.float32), axis=-1)
    return np.unpackbits(np.bitwise_xor(desc_a, desc_b), axis=-1).sum(-1).astype(float)


def match_scene(
    rgb: np.ndarray,
    camera: CameraModel,
    T_world_cam_prior: np.ndarray,
    landmarks: np.ndarray,
    descriptors: np.ndarray,
    kind: str,
    params: SceneMatchParams = SceneMatchParams(),
) -> SceneMatches | None:
    """None when too few verified matches, or the prior does not predict them (the caller
    keeps the prior)."""
    if len(landmarks) == 0 or rgb is None:
        return None
    uv_raw, desc = detect_features(rgb, kind, params.max_features)
    if desc is None or len(uv_raw) < params.min_inliers:
        return None
    uv_feat = camera.undistort_pixels(uv_raw)
    ideal = CameraModel(camera.width, camera.height, camera.K)
    proj, front = ideal.project_world(T_world_cam_prior, landmarks)
    dist = np.linalg.norm(landmarks - T_world_cam_prior[:3, 3], axis=1)
    visible = np.flatnonzero(front & ideal.in_image(proj) & (dist < params.max_range_m))
    tree = cKDTree(uv_feat)
    lm_idx, feat_idx = [], []
    for j in visible:
        cands = tree.query_ball_point(proj[j], params.radius_px)
        if not cands:
            continue
        d = _distances(descriptors[j][None], desc[cands], kind)
        order = np.argsort(d)
        if len(order) > 1 and d[order[0]] > params.ratio * d[order[1]]:
            continue
        lm_idx.append(j)
        feat_idx.append(cands[order[0]])
    lm_idx, feat_idx = np.array(lm_idx, dtype=int), np.array(feat_idx, dtype=int)
    # One feature serves one landmark: keep the first claim.
    _, first = np.unique(feat_idx, return_index=True)
    lm_idx, feat_idx = lm_idx[first], feat_idx[first]
    if len(lm_idx) < params.min_inliers:  # counted after the one-to-one rule (PnP needs 4 or more)
        return None
    T_cam_world = inv_se3(T_world_cam_prior)
    rvec0, _ = cv2.Rodrigues(T_cam_world[:3, :3])
    cv2.setRNGSeed(0)  # deterministic RANSAC: the same recording gives the same cameras
    # The guess as (3, 1): OpenCV takes a (3,) translation guess as given and returns nonsense poses.
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        landmarks[lm_idx],
        uv_feat[feat_idx],
        camera.K,
        None,
        rvec0.copy(),
        T_cam_world[:3, 3].reshape(3, 1).copy(),
        useExtrinsicGuess=True,
        iterationsCount=1000,
        reprojectionError=params.pnp_px,
        confidence=0.999,
        flags=cv2.SOLVEPNP_ITERATIVE,
    )
    if not ok or inliers is None or len(inliers) < params.min_inliers:
        return None
    keep = inliers.ravel()
    if np.median(np.linalg.norm(proj[lm_idx[keep]] - uv_feat[feat_idx[keep]], axis=1)) > params.max_prior_median_px:
        return None
    return SceneMatches(lm_idx[keep], uv_feat[feat_idx[keep]], inv_se3(se3(cv2.Rodrigues(rvec)[0], tvec.ravel())))
