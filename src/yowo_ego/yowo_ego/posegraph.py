"""Multiway registration of the keyframes (paper: ICP with multiway
registration [Choi et al. 2015]), as an Open3D pose graph:

- odometry edges between consecutive keyframes, each checked against the two
  keyframes' SIFT matches + PnP RANSAC: dense odometry can settle in a wrong
  minimum that still fits well, PnP on SIFT is independent of it and
  millimetre-accurate on these images; an edge that disagrees is replaced
  (dense odometry restarted from PnP, or PnP itself); keyframes with too few
  common features are checked across a neighbour (PnP over two edges);
- loop-closure edges between non-consecutive keyframes that the (corrected)
  odometry places close together and looking the same way, verified by SIFT +
  PnP RANSAC and refined densely from the PnP estimate (as Choi et al. refine
  every loop: PnP is off by centimetres on wide-baseline loops);
- Open3D's global optimisation (Levenberg-Marquardt with a line process on the
  loop edges, which prunes the ones inconsistent with the rest)."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from yowo_common.geometry import inv_se3, rotation_angle_deg

from .features import FeatureParams, KeyframeFeatures, PnpResult, match, relative_pose, support
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
    # A tracking edge and the PnP estimate agree within these bounds; so must a
    # dense refinement started from PnP. PnP on SIFT is accurate to a few mm /
    # 0.1 deg here, while wrong dense minima are off by 0.3-4 deg.
    agree_m: float = 0.01
    agree_deg: float = 0.25
    # Loop edges are refined densely from PnP (which is off by 1-8 cm / up to
    # 2.5 deg on wide-baseline loops, the dense result by a few mm); a dense
    # result further than this from PnP fell into another minimum.
    loop_refine_max_m: float = 0.1
    loop_refine_max_deg: float = 3.0
    # When they disagree, the tracking edge stays if the SIFT matches support it
    # almost as well as the PnP estimate (PnP may be the ambiguous one).
    keep_support_ratio: float = 0.7
    # A pair whose matches are too few for the default check is retried with
    # looser matching (the support comparison still guards the result).
    retry_features: FeatureParams = FeatureParams(ratio=0.9, pnp_min_inliers=15)
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
    loops_verified: int            # by SIFT + PnP
    loops_refined: int             # of those, refined densely
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


def _agree(T1: np.ndarray, T2: np.ndarray, params: LoopParams, loose: bool = False) -> bool:
    max_m, max_deg = ((params.loop_refine_max_m, params.loop_refine_max_deg) if loose
                      else (params.agree_m, params.agree_deg))
    return (np.linalg.norm(T1[:3, 3] - T2[:3, 3]) <= max_m
            and rotation_angle_deg(T1[:3, :3], T2[:3, :3]) <= max_deg)


def dense_edge(pair: PairMatches, kf_a: Keyframe, kf_b: Keyframe, odometry: RgbdOdometry, params: LoopParams,
               kind: str = "odometry") -> OdometryEdge | None:
    """Edge b -> a from a PnP-verified pair: dense refinement from the PnP
    estimate when it passes the odometry checks and agrees with PnP (closely
    for a tracking edge, loosely for a loop), else None."""
    if pair.pnp is None:
        return None
    T_a_b = inv_se3(pair.pnp.T_b_a)
    src, tgt = o3d_rgbd(kf_b.color, kf_b.depth_mm), o3d_rgbd(kf_a.color, kf_a.depth_mm)
    for cascade in odometry.params.cascades:
        T, fit, rmse = odometry.register(src, tgt, T_a_b, cascade)
        if (fit >= odometry.params.min_fitness and rmse <= odometry.params.max_inlier_rmse
                and _agree(T, T_a_b, params, loose=kind == "loop")):
            return OdometryEdge(kf_b.index, kf_a.index, T, odometry.information(kf_b.depth_mm, kf_a.depth_mm, T),
                                kind)
    return None


def verify_edge(edge: OdometryEdge, pair: PairMatches, features: list[KeyframeFeatures], keyframes: list[Keyframe],
                odometry: RgbdOdometry, params: LoopParams) -> tuple[OdometryEdge, bool]:
    """Check a tracking edge against the keyframes' SIFT + PnP estimate. Dense
    odometry can settle in a wrong minimum that still fits well (along a wall,
    rotation and translation trade off), so an edge that disagrees with PnP
    and is clearly less supported by the matches is replaced: by the dense
    result restarted from PnP if that agrees with PnP, else by PnP itself.
    A PnP estimate from the looser retry matching must be confirmed by the
    dense restart, unless the edge is a tracking break's guess. Returns the
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
    if edge.kind == "odometry" and (
            _agree(edge.T_target_source, T_pnp, params)
            or support(fa, fb, matches, inv_se3(edge.T_target_source), K)
            >= params.keep_support_ratio * support(fa, fb, matches, pnp.T_b_a, K)):
        return edge, False
    kf_a, kf_b = keyframes[pair.a], keyframes[pair.b]
    fixed = dense_edge(PairMatches(pair.a, pair.b, matches, pnp), kf_a, kf_b, odometry, params)
    if fixed is None and (not loose or edge.kind == "break"):   # a break edge is only a guess anyway
        fixed = OdometryEdge(kf_b.index, kf_a.index, T_pnp,
                             odometry.information(kf_b.depth_mm, kf_a.depth_mm, T_pnp), "odometry")
    return (edge, False) if fixed is None else (fixed, True)


def _verify_across(edges: list[OdometryEdge], checked: list[bool], pairs: list[PairMatches],
                   features: list[KeyframeFeatures], keyframes: list[Keyframe], odometry: RgbdOdometry,
                   params: LoopParams) -> int:
    """Edges a -> a+1 whose keyframes share too few matches to be checked are
    checked across a neighbour instead: PnP between a-1 and a+1 (or a and a+2)
    combined with the neighbour's checked edge implies the edge. Returns how
    many edges were replaced (in place); the extra pairs join ``pairs``."""
    K = odometry.K_full
    n, replaced = len(edges), 0
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
            if not _agree(e.T_target_source, implied, params):
                edges[i] = OdometryEdge(b, a, implied, odometry.information(keyframes[b].depth_mm,
                                                                             keyframes[a].depth_mm, implied),
                                        "odometry")
                replaced += 1
            break
    return replaced


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
                          params: LoopParams = LoopParams(), workers: int = 2) -> MultiwayResult:
    """Pairs are matched and loops refined on ``workers`` threads (BLAS, OpenCV and
    Open3D release the GIL; each pair's result does not depend on the thread)."""
    K = odometry.K_full
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="ego_match") as pool:
        def match_all(ab: list[tuple[int, int]]) -> list[PairMatches]:
            return list(pool.map(lambda p: match_pair(features[p[0]], features[p[1]], p[0], p[1], K,
                                                      params.features), ab))

        pairs, edges, checked, corrected = [], [], [], 0
        for e, pair in zip(odometry_edges, match_all([(e.target, e.source) for e in odometry_edges])):
            pairs.append(pair)
            e, replaced = verify_edge(e, pair, features, keyframes, odometry, params)
            edges.append(e)
            checked.append(pair.pnp is not None)
            corrected += replaced
        corrected += _verify_across(edges, checked, pairs, features, keyframes, odometry, params)
        # Re-initialise the nodes along the verified chain (tracking built on the old edges).
        T_init = chain_poses(len(keyframes), edges)
        nodes = [Keyframe(k.index, k.frame_index, k.stamp_ns, T, k.color, k.depth_mm, k.segment)
                 for k, T in zip(keyframes, T_init)]
        candidates = loop_candidates(nodes, params)
        loop_pairs = [p for p in match_all(candidates) if p.pnp is not None]
        # Choi et al. refine every loop densely: PnP alone is too coarse for the
        # information matrix a dense edge carries. Loops that fail it give no
        # edge; their matches still serve the bundle adjustment.
        refined = list(pool.map(lambda p: dense_edge(p, keyframes[p.a], keyframes[p.b], odometry, params, "loop"),
                                loop_pairs))
    loop_edges = [e for e in refined if e is not None]
    pairs += loop_pairs
    T, kept = optimize(nodes, edges + loop_edges, params)
    return MultiwayResult(T, corrected, len(candidates), len(loop_pairs), len(loop_edges), kept, pairs)
