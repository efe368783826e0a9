"""Hloc/Kapture-style baseline (a labelled reimplementation of the idea of Sarlin et al.
2019 "From coarse to fine" / Humenberger et al. 2020-22, not the authors' code):
classical visual localisation of each CMC against YOWO's ego map, for the paper's
Tables "register_pose_eval_1" (no prior) and "register_pose_eval_2" (with YOWO's prior).

Pipeline per CMC background image:
1. Global retrieval of the k nearest ego keyframes by a global image descriptor.
   Substitute for NetVLAD (no network weights on this machine): VLAD over RootSIFT,
   with a k-means vocabulary trained on the map's own keyframes, intra- and power-
   normalised, compared by cosine similarity.
2. Local matching: SIFT (OpenCV) with Lowe's ratio test and the mutual check between
   the CMC image and each retrieved keyframe's colour image (instead of SuperPoint +
   SuperGlue).
3. 2D-3D: keyframe keypoints lifted to the map with the keyframe's depth and pose
   (the scene model is YOWO's ego map, as in the paper's comparison, not a COLMAP
   reconstruction); the matches of all retrieved keyframes pooled.
4. PnP + RANSAC (SQPnP minimal solver) and Levenberg-Marquardt refinement on the inliers.

With a pose prior (Table "register_pose_eval_2"), step 1 is replaced by the keyframes
whose depth-lifted keypoints fall most into the prior camera's view, and step 2 only
accepts a match whose 3D point projects through the prior within a gate of the CMC
keypoint.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, se3, transform_points
from yowo_common.pnp import sqpnp_ransac
from yowo_ego.features import create_sift, sample_depth

RANSAC_SEED = 0  # OpenCV's RANSAC and k-means draw from a global RNG: seeded for repeatable results


@dataclass(frozen=True)
class HlocParams:
    max_features: int = 4000
    ratio: float = 0.8  # Lowe's ratio test
    vocabulary_size: int = 64  # VLAD clusters
    vocabulary_samples: int = 50000  # descriptors the k-means vocabulary is trained on
    num_retrieved: int = 5  # top-k keyframes (Hloc's retrieval pairs)
    depth_edge_ratio: float = 0.03  # keyframe keypoints on depth edges are not lifted
    pnp_px: float = 8.0  # RANSAC threshold (ideal pixels)
    pnp_iterations: int = 10000
    min_inliers: int = 15
    # Prior mode
    prior_min_overlap: float = 0.05  # fraction of a keyframe's 3D keypoints in the prior's view
    prior_gate_px: float = 40.0  # match accepted only this close to its prior projection
    prior_cell_px: int = 32  # z-buffer cell for the visibility of keyframe points
    prior_depth_tolerance: float = 0.1  # relative depth beyond a cell's nearest point: hidden


@dataclass
class KeyframeImage:
    rgb: np.ndarray  # H x W x 3 uint8
    depth: np.ndarray  # H x W float metres (NaN / 0: missing)


@dataclass(kw_only=True)
class LocalizationResult:
    name: str
    T_world_cam: np.ndarray | None
    reason: str  # why it failed, or "" on success
    num_inliers: int = 0
    num_matches: int = 0
    retrieved: list[int] = field(default_factory=list)  # keyframe indices used


@dataclass
class Features:
    uv: np.ndarray  # (N, 2) raw image pixels
    descriptors: np.ndarray  # (N, 128) float32 RootSIFT


@dataclass(kw_only=True)
class KeyframeDatabase:
    """The map side, built once per ego map: each keyframe's features, their 3D points
    in the map frame (NaN without depth) and VLAD descriptors."""

    indices: list[int]  # keyframe index (into EgoMapResult.T_world_kf) per entry
    features: list[Features]
    points: list[np.ndarray]  # (N, 3) per entry
    vocabulary: np.ndarray  # (V, 128)
    vlad: np.ndarray  # (E, V * 128)


def read_keyframe_images(bag, ego, tolerance_ns: int = 5_000_000) -> dict[int, KeyframeImage]:
    """Colour and depth of every keyframe of ``ego`` (an EgoMapResult) from its recording,
    by stamp: the ego stage pairs colour and depth by stamp and keys the pair by the
    colour stamp. Keyframe index -> images; keyframes missing from the bag are left out."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import decode_color, decode_depth, stamp_to_ns
    from yowo_ego.recording import find_ego_topics

    topics = find_ego_topics(bag)
    index = {int(s): i for i, s in enumerate(ego.keyframe_stamps_ns)}
    if not index:
        return {}
    wanted = np.array(sorted(index), dtype=np.int64)
    colors, depths = {}, {}
    for topic, _, msg in read_messages(bag, [topics.color, topics.depth]):
        stamp = stamp_to_ns(msg.header.stamp)
        if topic == topics.color:
            if stamp in index:
                colors[index[stamp]] = decode_color(msg)
            continue
        j = np.searchsorted(wanted, stamp)
        near = wanted[max(j - 1, 0) : j + 1]
        kf = int(near[np.argmin(np.abs(near - stamp))])
        gap = abs(kf - stamp)
        if gap <= tolerance_ns and gap < depths.get(index[kf], (gap + 1,))[0]:
            depths[index[kf]] = (gap, decode_depth(msg))
    return {i: KeyframeImage(colors[i], depths[i][1]) for i in sorted(colors) if i in depths}


def extract(rgb: np.ndarray, max_features: int) -> Features:
    """SIFT keypoints with RootSIFT descriptors (L1-normalised, square-rooted)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    kps, desc = create_sift(max_features).detectAndCompute(gray, None)
    if desc is None or not kps:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32))
    desc = np.sqrt(desc / np.maximum(desc.sum(axis=1, keepdims=True), 1e-12)).astype(np.float32)
    return Features(np.array([k.pt for k in kps], dtype=float), desc)


def lift(
    camera: CameraModel, T_world_kf: np.ndarray, uv: np.ndarray, depth: np.ndarray, edge_ratio: float
) -> np.ndarray:
    """Raw keyframe pixels -> map points through the z-depth image (NaN rows: no depth)."""
    z = sample_depth(np.where(depth > 0, depth, np.nan).astype(np.float32), uv, edge_ratio)
    rays = camera.bearings(uv)
    return transform_points(T_world_kf, rays / rays[:, 2:3] * z[:, None])


def vlad(descriptors: np.ndarray, vocabulary: np.ndarray) -> np.ndarray:
    """VLAD (Jegou et al.) with intra-normalisation and signed square root, L2-normalised."""
    out = np.zeros_like(vocabulary)
    if len(descriptors):
        d2 = (descriptors**2).sum(1)[:, None] - 2 * descriptors @ vocabulary.T + (vocabulary**2).sum(1)[None]
        nearest = d2.argmin(axis=1)
        np.add.at(out, nearest, descriptors - vocabulary[nearest])
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
    out = np.sign(out) * np.sqrt(np.abs(out))
    v = out.ravel()
    return v / max(np.linalg.norm(v), 1e-12)


def build_database(
    camera: CameraModel,
    T_world_kf: np.ndarray,
    keyframe_images: dict[int, KeyframeImage],
    params: HlocParams = HlocParams(),
) -> KeyframeDatabase:
    """``camera``: the ego camera (raw, with distortion); ``T_world_kf``: keyframe poses
    indexed like ``keyframe_images``."""
    indices = sorted(keyframe_images)
    feats, points = [], []
    for i in indices:
        kf = keyframe_images[i]
        f = extract(kf.rgb, params.max_features)
        feats.append(f)
        points.append(lift(camera, T_world_kf[i], f.uv, kf.depth, params.depth_edge_ratio))
    pooled = np.vstack([f.descriptors for f in feats] or [np.zeros((0, 128), np.float32)])
    if len(pooled) < params.vocabulary_size:
        raise ValueError(f"{len(pooled)} keyframe descriptors cannot train a {params.vocabulary_size}-word vocabulary")
    rng = np.random.default_rng(RANSAC_SEED)
    sample = pooled[rng.choice(len(pooled), min(len(pooled), params.vocabulary_samples), replace=False)]
    cv2.setRNGSeed(RANSAC_SEED)
    _, _, vocabulary = cv2.kmeans(
        sample,
        params.vocabulary_size,
        None,
        (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4),
        3,
        cv2.KMEANS_PP_CENTERS,
    )
    return KeyframeDatabase(
        indices=indices,
        features=feats,
        points=points,
        vocabulary=vocabulary,
        vlad=np.array([vlad(f.descriptors, vocabulary) for f in feats]),
    )


def mutual_ratio_matches(da: np.ndarray, db: np.ndarray, ratio: float, allowed: np.ndarray | None = None) -> np.ndarray:
    """(M, 2) index pairs (i in a, j in b): mutual nearest neighbours passing Lowe's ratio
    test both ways, among the pairs ``allowed`` (bool (Na, Nb); None: all)."""
    if len(da) < 2 or len(db) < 2:
        return np.zeros((0, 2), int)
    d2 = np.maximum((da * da).sum(1)[:, None] + (db * db).sum(1)[None, :] - 2.0 * da @ db.T, 0.0)
    if allowed is not None:
        d2[~allowed] = np.inf
    two_ab = np.partition(d2, 1, axis=1)[:, :2]
    two_ba = np.partition(d2, 1, axis=0)[:2, :]
    nn_ab, nn_ba = d2.argmin(axis=1), d2.argmin(axis=0)
    i = np.arange(len(da))
    r2 = ratio * ratio
    ok = (
        (nn_ba[nn_ab] == i)
        & np.isfinite(two_ab[:, 0])
        & (two_ab[:, 0] < r2 * two_ab[:, 1])
        & (two_ba[0, nn_ab] < r2 * two_ba[1, nn_ab])
    )
    return np.column_stack([i[ok], nn_ab[ok]]).astype(int)


def _prior_candidates(db: KeyframeDatabase, camera: CameraModel, T_prior: np.ndarray, params: HlocParams) -> list[int]:
    """Database entries with the most lifted keypoints visible in the prior camera: inside
    its image and not behind the nearest map point of their image cell (a coarse z-buffer
    of every keyframe's points, so keyframes of the room behind a wall do not count)."""
    cell = params.prior_cell_px
    cols, rows = -(-camera.width // cell), -(-camera.height // cell)
    seen = []
    for P in db.points:
        P_cam = transform_points(inv_se3(T_prior), np.nan_to_num(P, nan=0.0))
        uv, front = camera.project(P_cam)
        ok = front & camera.in_image(uv) & np.isfinite(P).all(axis=1)
        z = P_cam[:, 2]
        c = np.where(ok, (uv[:, 1] // cell).clip(0, rows - 1) * cols + (uv[:, 0] // cell).clip(0, cols - 1), -1)
        seen.append((ok, c.astype(int), z))
    nearest = np.full(rows * cols, np.inf)
    for ok, c, z in seen:
        np.minimum.at(nearest, c[ok], z[ok])
    scores = []
    for e, (ok, c, z) in enumerate(seen):
        visible = ok & (z <= nearest[np.maximum(c, 0)] * (1 + params.prior_depth_tolerance))
        if visible.sum() >= params.prior_min_overlap * np.isfinite(db.points[e]).all(axis=1).sum():
            scores.append((int(visible.sum()), e))
    return [e for _, e in sorted(scores, reverse=True)[: params.num_retrieved]]


def localize(
    db: KeyframeDatabase,
    name: str,
    background: np.ndarray,
    camera: CameraModel,
    prior: np.ndarray | None = None,
    params: HlocParams = HlocParams(),
) -> LocalizationResult:
    """T_world_cam of one CMC from its background image (RGB), with or without a prior pose."""
    query = extract(background, params.max_features)
    if len(query.uv) < params.min_inliers:
        return LocalizationResult(
            name=name, T_world_cam=None, reason=f"only {len(query.uv)} SIFT keypoints in its image"
        )
    if prior is None:
        sims = db.vlad @ vlad(query.descriptors, db.vocabulary)
        entries = [int(e) for e in np.argsort(-sims, kind="stable")[: params.num_retrieved]]
    else:
        entries = _prior_candidates(db, camera, prior, params)
        if not entries:
            return LocalizationResult(
                name=name,
                T_world_cam=None,
                reason="no keyframe sees the part of the map in the prior camera's view",
            )
    query_tree = cKDTree(query.uv)
    obj, img = [], []
    for e in entries:
        P = db.points[e]
        valid = np.flatnonzero(np.isfinite(P).all(axis=1))
        allowed = None
        if prior is not None:
            proj, front = camera.project_world(prior, P[valid])
            allowed = np.zeros((len(query.uv), len(valid)), bool)
            for j, near in enumerate(query_tree.query_ball_point(proj, params.prior_gate_px)):
                allowed[near, j] = front[j]
        m = mutual_ratio_matches(query.descriptors, db.features[e].descriptors[valid], params.ratio, allowed)
        obj.append(P[valid[m[:, 1]]])
        img.append(query.uv[m[:, 0]])
    retrieved = [db.indices[e] for e in entries]
    obj, img = np.vstack(obj), camera.undistort_pixels(np.vstack(img))
    if len(obj) < params.min_inliers:
        return LocalizationResult(
            name=name,
            T_world_cam=None,
            reason=f"only {len(obj)} 2D-3D matches with {len(entries)} keyframes (needs {params.min_inliers})",
            num_matches=len(obj),
            retrieved=retrieved,
        )
    rvec, tvec, idx = sqpnp_ransac(
        obj, img, camera.K, params.pnp_px, iterations=params.pnp_iterations, confidence=0.9999, seed=RANSAC_SEED
    )
    n = len(idx)
    if n < params.min_inliers:
        return LocalizationResult(
            name=name,
            T_world_cam=None,
            reason=f"PnP RANSAC found {n} inliers among {len(obj)} matches (needs {params.min_inliers})",
            num_inliers=n,
            num_matches=len(obj),
            retrieved=retrieved,
        )
    rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], camera.K, None, rvec, tvec)
    T = inv_se3(se3(cv2.Rodrigues(rvec)[0], tvec.ravel()))
    return LocalizationResult(
        name=name, T_world_cam=T, reason="", num_inliers=n, num_matches=len(obj), retrieved=retrieved
    )
