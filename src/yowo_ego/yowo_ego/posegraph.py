"""Multiway registration of the keyframes (paper: ICP with multiway
registration [Choi et al. 2015]): loop-closure candidates between
non-consecutive keyframes, verified by SIFT matches + PnP RANSAC and refined by
dense RGB-D odometry, then Open3D's global pose-graph optimisation (line
process: wrong loop closures are pruned)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import open3d as o3d

from yowo_common.geometry import inv_se3, rotation_angle_deg

from .features import FeatureParams, KeyframeFeatures, PnpResult, match, relative_pose
from .odometry import Keyframe, OdometryEdge, RgbdOdometry, o3d_rgbd, orthonormalize

reg = o3d.pipelines.registration


@dataclass(frozen=True)
class LoopParams:
    min_separation: int = 3              # keyframes; closer ones are linked by odometry already
    max_distance_m: float = 2.5          # candidate camera centres this close ...
    max_angle_deg: float = 45.0          # ... looking within this angle of each other
    max_per_keyframe: int = 2            # nearest candidates verified per keyframe
    break_window: int = 4                # keyframes either side of a tracking break, all pairs tried
    features: FeatureParams = FeatureParams()
    # A tracking edge and the PnP estimate agree within these bounds (else the
    # edge is replaced); so must a dense refinement started from PnP.
    agree_m: float = 0.05
    agree_deg: float = 2.0
    # Open3D global optimisation.
    max_correspondence_distance_m: float = 0.05
    edge_prune_threshold: float = 0.25
    preference_loop_closure: float = 1.0


@dataclass
class PairMatches:
    """SIFT matches between keyframes a < b and, when verified, T_b_a from PnP."""

    a: int
    b: int
    matches: np.ndarray            # (M, 2) feature indices (in a, in b)
    pnp: PnpResult | None


@dataclass
class MultiwayResult:
    T_odom_kf: list[np.ndarray]    # optimised keyframe poses
    edges_corrected: int           # tracking edges replaced after the PnP check
    loops_tried: int
    loops_verified: int
    loops_kept: int                # after the line process pruned the inconsistent ones
    pairs: list[PairMatches]       # every matched keyframe pair (consecutive and loops)


def loop_candidates(keyframes: list[Keyframe], params: LoopParams = LoopParams()) -> list[tuple[int, int]]:
    """Non-consecutive keyframe pairs (a < b) likely to see the same surfaces:
    close and looking the same way by odometry, plus every pair around a
    tracking break (where odometry poses cannot be trusted)."""
    n = len(keyframes)
    if n < 2:
        return []
    C = np.array([k.T_odom_cam[:3, 3] for k in keyframes])
    Z = np.array([k.T_odom_cam[:3, 2] for k in keyframes])
    dist = np.linalg.norm(C[:, None] - C[None], axis=2)
    cos = np.clip(Z @ Z.T, -1.0, 1.0)
    idx = np.arange(n)
    ok = ((idx[None] - idx[:, None]) >= params.min_separation) & (dist <= params.max_distance_m) \
        & (cos >= np.cos(np.radians(params.max_angle_deg)))
    pairs = set()
    for b in range(n):
        a_ok = np.flatnonzero(ok[:, b])
        for a in a_ok[np.argsort(dist[a_ok, b])][:params.max_per_keyframe]:
            pairs.add((int(a), b))
    segments = np.array([k.segment for k in keyframes])
    for b in np.flatnonzero(np.diff(segments) > 0) + 1:
        lo, hi = max(0, b - params.break_window), min(n, b + params.break_window)
        pairs.update((a, c) for a in range(lo, b) for c in range(b, hi) if c - a >= 1)
    return sorted(pairs)


def match_pair(fa: KeyframeFeatures, fb: KeyframeFeatures, a: int, b: int, K: np.ndarray,
               params: FeatureParams) -> PairMatches:
    m = match(fa, fb, params.ratio)
    return PairMatches(a, b, m, relative_pose(fa, fb, m, K, params))


def _agree(T1: np.ndarray, T2: np.ndarray, params: LoopParams) -> bool:
    return (np.linalg.norm(T1[:3, 3] - T2[:3, 3]) <= params.agree_m
            and rotation_angle_deg(T1[:3, :3], T2[:3, :3]) <= params.agree_deg)


def dense_edge(pair: PairMatches, kf_a: Keyframe, kf_b: Keyframe, odometry: RgbdOdometry, params: LoopParams
               ) -> OdometryEdge | None:
    """Edge b -> a from a PnP-verified pair: dense refinement from the PnP
    estimate when both agree (the dense result is the more accurate), else None."""
    if pair.pnp is None:
        return None
    T_a_b = inv_se3(pair.pnp.T_b_a)
    src, tgt = o3d_rgbd(kf_b.color, kf_b.depth_mm), o3d_rgbd(kf_a.color, kf_a.depth_mm)
    for cascade in odometry.params.cascades:
        T, fit, rmse = odometry.register(src, tgt, T_a_b, cascade)
        if (fit >= odometry.params.min_fitness and rmse <= odometry.params.max_inlier_rmse
                and _agree(T, T_a_b, params)):
            return OdometryEdge(kf_b.index, kf_a.index, T, odometry.information(kf_b.depth_mm, kf_a.depth_mm, T),
                                "odometry")
    return None


def verify_edge(edge: OdometryEdge, pair: PairMatches, keyframes: list[Keyframe], odometry: RgbdOdometry,
                params: LoopParams) -> tuple[OdometryEdge, bool]:
    """Check a tracking edge against the keyframes' SIFT + PnP estimate. Dense
    odometry can settle in a wrong minimum that still fits well (a single wall:
    rotation and translation trade off), so an edge that disagrees is replaced
    by the dense result started from PnP, or by the PnP estimate itself.
    Returns the edge to use and whether it was replaced."""
    if pair.pnp is None:
        return edge, False
    T_pnp = inv_se3(pair.pnp.T_b_a)
    if edge.kind == "odometry" and _agree(edge.T_target_source, T_pnp, params):
        return edge, False
    kf_a, kf_b = keyframes[pair.a], keyframes[pair.b]
    fixed = dense_edge(pair, kf_a, kf_b, odometry, params)
    if fixed is None:
        fixed = OdometryEdge(kf_b.index, kf_a.index, T_pnp,
                             odometry.information(kf_b.depth_mm, kf_a.depth_mm, T_pnp), "odometry")
    return fixed, True


def chain_poses(n: int, edges: list[OdometryEdge]) -> list[np.ndarray]:
    """Keyframe poses composed along the consecutive edges (b = a + 1)."""
    step = {e.target: e.T_target_source for e in edges if e.source == e.target + 1}
    T = [np.eye(4)]
    for a in range(n - 1):
        T.append(orthonormalize(T[-1] @ step[a]))
    return T


def optimize(keyframes: list[Keyframe], edges: list[OdometryEdge],
             params: LoopParams = LoopParams()) -> tuple[list[np.ndarray], int]:
    """Global pose-graph optimisation (Open3D, Levenberg-Marquardt with line
    process on loop edges). Returns T_odom_kf and the number of loop edges kept."""
    graph = reg.PoseGraph()
    for kf in keyframes:
        graph.nodes.append(reg.PoseGraphNode(kf.T_odom_cam))
    for e in edges:
        graph.edges.append(reg.PoseGraphEdge(e.source, e.target, e.T_target_source, e.information,
                                             uncertain=e.kind != "odometry"))
    option = reg.GlobalOptimizationOption(
        max_correspondence_distance=params.max_correspondence_distance_m,
        edge_prune_threshold=params.edge_prune_threshold,
        preference_loop_closure=params.preference_loop_closure, reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    kept = sum(1 for e in graph.edges if e.uncertain)
    return [orthonormalize(np.asarray(n.pose)) for n in graph.nodes], kept


def multiway_registration(keyframes: list[Keyframe], features: list[KeyframeFeatures],
                          odometry_edges: list[OdometryEdge], odometry: RgbdOdometry,
                          params: LoopParams = LoopParams()) -> MultiwayResult:
    K = odometry.K_full
    pairs, edges, corrected = [], [], 0
    for e in odometry_edges:
        a, b = e.target, e.source
        pair = match_pair(features[a], features[b], a, b, K, params.features)
        pairs.append(pair)
        e, replaced = verify_edge(e, pair, keyframes, odometry, params)
        edges.append(e)
        corrected += replaced
    # Re-initialise the nodes along the verified chain (tracking built on the old edges).
    T_init = chain_poses(len(keyframes), edges)
    nodes = [Keyframe(k.index, k.frame_index, k.stamp_ns, T, k.color, k.depth_mm, k.segment)
             for k, T in zip(keyframes, T_init)]
    candidates = loop_candidates(nodes, params)
    loop_edges = []
    for a, b in candidates:
        pair = match_pair(features[a], features[b], a, b, K, params.features)
        if pair.pnp is None:
            continue
        # Loop edges keep the PnP estimate (mm-accurate with SIFT; a dense
        # refinement per loop costs more than it adds); the line process of the
        # global optimisation prunes the ones that disagree with the rest.
        T_a_b = inv_se3(pair.pnp.T_b_a)
        info = odometry.information(keyframes[b].depth_mm, keyframes[a].depth_mm, T_a_b)
        loop_edges.append(OdometryEdge(b, a, T_a_b, info, "loop"))
        pairs.append(pair)
    T, kept = optimize(nodes, edges + loop_edges, params)
    return MultiwayResult(T, corrected, len(candidates), len(loop_edges), kept, pairs)
