"""The checks of multiway registration's edges (``posegraph``) against the keyframes' SIFT
matches + PnP RANSAC: a tracking edge that disagrees with PnP is replaced (dense odometry
restarted from PnP, or PnP itself), across a neighbour where its keyframes share too few
matches; a loop is refined densely from PnP."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from yowo_common.geometry import inv_se3, rotation_angle_deg

from .features import FeatureParams, KeyframeFeatures, PnpResult, match, relative_pose, support
from .odometry import Keyframe, OdometryEdge
from .rgbd_odometry import RgbdOdometry, o3d_rgbd

if TYPE_CHECKING:  # posegraph imports this module
    from .posegraph import LoopParams


@dataclass
class PairMatches:
    """SIFT matches between keyframes a < b and, when verified, T_b_a from PnP."""

    a: int
    b: int
    matches: np.ndarray  # (M, 2) feature indices (in a, in b)
    pnp: PnpResult | None


def match_pair(
    fa: KeyframeFeatures, fb: KeyframeFeatures, a: int, b: int, K: np.ndarray, params: FeatureParams
) -> PairMatches:
    m = match(fa, fb, params.ratio)
    return PairMatches(a, b, m, relative_pose(fa, fb, m, K, params))


def _agree(T1: np.ndarray, T2: np.ndarray, params: LoopParams, loose: bool = False) -> bool:
    max_m, max_deg = (
        (params.loop_refine_max_m, params.loop_refine_max_deg) if loose else (params.agree_m, params.agree_deg)
    )
    return np.linalg.norm(T1[:3, 3] - T2[:3, 3]) <= max_m and rotation_angle_deg(T1[:3, :3], T2[:3, :3]) <= max_deg


def dense_edge(
    pair: PairMatches,
    kf_a: Keyframe,
    kf_b: Keyframe,
    odometry: RgbdOdometry,
    params: LoopParams,
    kind: str = "odometry",
) -> OdometryEdge | None:
    """Edge b -> a from a PnP-verified pair: dense refinement from the PnP
    estimate when it passes the odometry checks and agrees with PnP (closely
    for a tracking edge, loosely for a loop), else None."""
    if pair.pnp is None:
        return None
    T_a_b = inv_se3(pair.pnp.T_b_a)
    src, tgt = o3d_rgbd(kf_b.color, kf_b.depth_mm), o3d_rgbd(kf_a.color, kf_a.depth_mm)
    for cascade in odometry.params.cascades:
        T, fit, rmse = odometry.register(src, tgt, T_a_b, cascade)
        if (
            fit >= odometry.params.min_fitness
            and rmse <= odometry.params.max_inlier_rmse
            and _agree(T, T_a_b, params, loose=kind == "loop")
        ):
            return OdometryEdge(
                source=kf_b.index,
                target=kf_a.index,
                T_target_source=T,
                information=odometry.information(kf_b.depth_mm, kf_a.depth_mm, T),
                kind=kind,
            )
    return None


def gyro_agrees(edge: OdometryEdge, T_target_source: np.ndarray, params: LoopParams) -> bool:
    return edge.R_gyro is None or (
        rotation_angle_deg(edge.R_gyro, T_target_source[:3, :3]) <= params.max_gyro_disagreement_deg
    )


def verify_edge(
    edge: OdometryEdge,
    pair: PairMatches,
    features: list[KeyframeFeatures],
    keyframes: list[Keyframe],
    odometry: RgbdOdometry,
    params: LoopParams,
) -> tuple[OdometryEdge, bool]:
    """Check a tracking edge against the keyframes' SIFT + PnP estimate. Dense
    odometry can settle in a wrong minimum that still fits well (along a wall,
    rotation and translation trade off), so an edge that disagrees with PnP
    and is clearly less supported by the matches is replaced: by the dense
    result restarted from PnP if that agrees with PnP, else by PnP itself.
    A PnP estimate from the looser retry matching must be confirmed by the
    dense restart, unless the edge is a tracking break's guess or the matches
    contradict it (``contradicted_support_ratio``). Returns the
    edge to use and whether it was replaced."""
    fa, fb = features[pair.a], features[pair.b]
    K = odometry.K_full
    matches, pnp, loose = pair.matches, pair.pnp, False
    if pnp is None:
        matches, loose = match(fa, fb, params.retry_features.ratio), True
        pnp = relative_pose(fa, fb, matches, K, params.retry_features)
    if pnp is None:
        return edge, False
    T_pnp = inv_se3(pnp.T_b_a)
    edge_support = support(fa, fb, matches, inv_se3(edge.T_target_source), K)
    pnp_support = support(fa, fb, matches, pnp.T_b_a, K)
    if edge.kind == "odometry" and (
        _agree(edge.T_target_source, T_pnp, params) or edge_support >= params.keep_support_ratio * pnp_support
    ):
        return edge, False
    kf_a, kf_b = keyframes[pair.a], keyframes[pair.b]
    fixed = dense_edge(PairMatches(pair.a, pair.b, matches, pnp), kf_a, kf_b, odometry, params)
    # A break edge is only a guess anyway; a contradicted one is worse than PnP.
    if fixed is None and (
        not loose or edge.kind == "break" or edge_support < params.contradicted_support_ratio * pnp_support
    ):
        fixed = OdometryEdge(
            source=kf_b.index,
            target=kf_a.index,
            T_target_source=T_pnp,
            information=odometry.information(kf_b.depth_mm, kf_a.depth_mm, T_pnp),
            kind="odometry",
        )
    if fixed is None or not gyro_agrees(edge, fixed.T_target_source, params):
        return edge, False
    fixed.R_gyro = edge.R_gyro
    return fixed, True


def verify_across(
    edges: list[OdometryEdge],
    checked: list[bool],
    pairs: list[PairMatches],
    features: list[KeyframeFeatures],
    keyframes: list[Keyframe],
    odometry: RgbdOdometry,
    params: LoopParams,
) -> int:
    """Edges a -> a+1 whose keyframes share too few matches to be checked are
    checked across a neighbour instead: PnP between a-1 and a+1 (or a and a+2)
    combined with the neighbour's checked edge implies the edge. Returns how
    many edges were replaced (in place); the extra pairs join ``pairs``."""
    K = odometry.K_full
    replaced = 0
    step = {e.target: i for i, e in enumerate(edges) if e.source == e.target + 1}
    for i, e in enumerate(edges):
        a, b = e.target, e.source
        if checked[i] or b != a + 1:
            continue
        for lo, hi, via in ((a - 1, b, step.get(a - 1)), (a, b + 1, step.get(b))):
            if lo < 0 or hi >= len(keyframes) or via is None or not checked[via]:
                continue
            pair = match_pair(features[lo], features[hi], lo, hi, K, params.features)
            if pair.pnp is None:
                continue
            pairs.append(pair)
            T_lo_hi = inv_se3(pair.pnp.T_b_a)
            T_via = edges[via].T_target_source
            implied = inv_se3(T_via) @ T_lo_hi if lo == a - 1 else T_lo_hi @ inv_se3(T_via)
            # As verify_edge: the edge stays where the matches support it nearly as well. In a
            # room of look-alike walls PnP across two keyframes can fit a shifted copy (small
            # symmetric s2 without IMU: a correctly tracked edge moved 0.50 m).
            T_lo_hi_edge = T_via @ e.T_target_source if lo == a - 1 else e.T_target_source @ T_via
            if support(
                features[lo], features[hi], pair.matches, inv_se3(T_lo_hi_edge), K
            ) >= params.keep_support_ratio * support(features[lo], features[hi], pair.matches, pair.pnp.T_b_a, K):
                break
            if (
                not _agree(e.T_target_source, implied, params)
                and gyro_agrees(e, implied, params)
                and rotation_angle_deg(e.T_target_source[:3, :3], implied[:3, :3]) <= params.max_across_correction_deg
            ):
                edges[i] = OdometryEdge(
                    source=b,
                    target=a,
                    T_target_source=implied,
                    information=odometry.information(keyframes[b].depth_mm, keyframes[a].depth_mm, implied),
                    kind="odometry",
                    R_gyro=e.R_gyro,
                )
                replaced += 1
            break
    return replaced
