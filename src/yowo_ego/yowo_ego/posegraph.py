"""Multiway registration of the keyframes (paper: ICP with multiway
registration [Choi et al. 2015]), as an Open3D pose graph:

- odometry edges between consecutive keyframes, each checked against the two
  keyframes' SIFT matches + PnP RANSAC: dense odometry can settle in a wrong
  minimum that still fits well, PnP on SIFT is independent of it and
  millimetre-accurate on these images; an edge that disagrees is replaced
  (dense odometry restarted from PnP, or PnP itself); keyframes with too few
  common features are checked across a neighbour (PnP over two edges)
  (``edge_checks``);
- loop-closure edges between non-consecutive keyframes that the (corrected)
  odometry places close together and looking the same way, verified by SIFT +
  PnP RANSAC and refined densely from the PnP estimate (as Choi et al. refine
  every loop: PnP is off by centimetres on wide-baseline loops);
- relocalisation: a segment that starts after a tracking break is joined to the
  walk by the earlier keyframes that look most like its keyframes (place
  recognition, ``retrieval``), verified and refined as a loop; its break edge then
  takes the pose that loop implies. Once joined, each keyframe's best look-alike
  further away than the pose-based search reaches is tried as a loop too;
- global optimisation: Open3D's (Levenberg-Marquardt with a line process on the
  loop edges, which prunes the ones inconsistent with the rest), solved sparsely
  with GTSAM (``optimize``).

Edge checks and loop closures run per keyframe as the recording goes on
(``MultiwayRegistration.add``); only the optimisation waits for its end."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from yowo_common.bundle import optimize as levenberg_marquardt
from yowo_common.bundle import pose3
from yowo_common.geometry import inv_se3

from .edge_checks import PairMatches, dense_edge, gyro_agrees, match_pair, verify_across, verify_edge
from .features import FeatureParams, KeyframeFeatures
from .odometry import TRACKING_KINDS, Keyframe, OdometryEdge
from .retrieval import PlaceIndex, RetrievalParams
from .rgbd_odometry import RgbdOdometry, orthonormalize


@dataclass(frozen=True)
class LoopParams:
    min_separation: int = 3  # keyframes between a loop's two at least; closer ones are linked by odometry [count]
    max_distance_m: float = 2.5  # loop candidates: camera centres at most this far apart
    max_angle_deg: float = 45.0  # loop candidates: viewing directions at most this far apart
    max_per_keyframe: int = 2  # nearest loop candidates verified per keyframe [count]
    break_window: int = 4  # keyframes either side of a tracking break whose pairs are all tried [count]
    features: FeatureParams = FeatureParams()  # matching and PnP of the edge checks and loops
    # Translation within which a tracking edge and the PnP estimate agree, as must a dense
    # refinement started from it. PnP on SIFT is accurate to millimetres on these images, while
    # wrong dense minima are off by more.
    agree_m: float = 0.01
    agree_deg: float = 0.25  # rotation within which a tracking edge and the PnP estimate agree
    # A loop's dense refinement further than this from PnP fell into another minimum. PnP is
    # off by centimetres on wide-baseline loops, the dense result by millimetres.
    loop_refine_max_m: float = 0.1
    loop_refine_max_deg: float = 3.0  # the same in rotation
    # Support by the SIFT matches, the edge's over the PnP estimate's, at which a disagreeing
    # tracking edge stays [ratio]. PnP may be the ambiguous one.
    keep_support_ratio: float = 0.7
    # Support ratio (the edge's over PnP's) below which a PnP estimate from the looser retry
    # matching replaces the edge unconfirmed [ratio]. A wrong dense minimum on a fast turn
    # explains none; an ambiguous PnP leaves the edge most of its support.
    contradicted_support_ratio: float = 0.2
    # A pair whose matches are too few for the default check is retried with
    # looser matching (the support comparison still guards the result).
    retry_features: FeatureParams = FeatureParams(ratio=0.9, pnp_min_inliers=15)
    # A tracking edge with the gyro's rotation is not replaced by an estimate turning further
    # than this from the gyro's. In a symmetric room PnP can match a look-alike view far off,
    # while the gyro over a keyframe interval is accurate.
    max_gyro_disagreement_deg: float = 5.0
    # Without a dense confirmation, a tracking edge checked only across a neighbour is not turned
    # further than this. The check corrects wrong dense minima, a few degrees off, while a larger
    # change means PnP matched a look-alike view.
    max_across_correction_deg: float = 20.0
    retrieval: RetrievalParams = RetrievalParams()  # place recognition
    # Correspondence distance behind the loop edges' line-process weight (Open3D's GlobalOptimizationOption).
    max_correspondence_distance_m: float = 0.05
    edge_prune_threshold: float = 0.25  # loops whose line process ends below this are pruned [share]
    preference_loop_closure: float = 1.0  # weight of the loop edges' line process (Open3D's) [x]
    max_iterations: int = 100  # Levenberg-Marquardt iterations at most [count]
    relative_error_tol: float = 1e-6  # LM stops once an iteration lowers the error by less than this [share]


@dataclass(kw_only=True)
class MultiwayResult:
    T_odom_kf: list[np.ndarray]  # optimised keyframe poses
    edges_corrected: int  # tracking edges replaced after the PnP check
    loops_tried: int
    loops_verified: int  # by SIFT + PnP
    loops_refined: int  # of those, refined densely
    loops_kept: int  # after the line process pruned the inconsistent ones
    relocalised: int  # segments joined to the walk by place recognition
    loops_retrieved: int  # loop edges between keyframes found by place recognition
    pairs: list[PairMatches]  # every matched keyframe pair (consecutive and loops)
    edges: list[OdometryEdge]  # the graph's edges the optimisation kept (tracking, IMU, break, loop)


def tied_segment_starts(segments: list[int], edges: list[OdometryEdge]) -> list[int]:
    """The first keyframe of every segment after the first that measured edges (a verified loop,
    a corrected tracking edge: anything but a break's guess) tie to the walk's first segment,
    directly or through other segments. `segments`: each keyframe's segment."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    seg = np.asarray(segments)
    pairs = np.array([(seg[e.source], seg[e.target]) for e in edges if e.kind != "break"], dtype=int).reshape(-1, 2)
    n = int(seg.max()) + 1 if len(seg) else 0
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    starts = [k for k in range(1, len(seg)) if seg[k] != seg[k - 1]]
    return [k for k in starts if label[seg[k]] == label[0]]


def loop_candidates_of(b: int, T_odom_kf: list[np.ndarray], params: LoopParams = LoopParams()) -> list[int]:
    """Earlier keyframes a (at least ``min_separation`` before b) likely to see
    the same surfaces as b: close and looking the same way by the given poses;
    the ``max_per_keyframe`` nearest."""
    if b < params.min_separation:
        return []
    C = np.array([T[:3, 3] for T in T_odom_kf[: b - params.min_separation + 1]])
    Z = np.array([T[:3, 2] for T in T_odom_kf[: b - params.min_separation + 1]])
    dist = np.linalg.norm(C - T_odom_kf[b][:3, 3], axis=1)
    ok = np.flatnonzero(
        (dist <= params.max_distance_m) & (Z @ T_odom_kf[b][:3, 2] >= np.cos(np.radians(params.max_angle_deg)))
    )
    return [int(a) for a in ok[np.argsort(dist[ok], kind="stable")][: params.max_per_keyframe]]


def break_pairs(segments: list[int], params: LoopParams = LoopParams()) -> list[tuple[int, int]]:
    """Every keyframe pair (a < c) within ``break_window`` either side of a
    tracking break (where odometry poses cannot be trusted)."""
    n, pairs = len(segments), set()
    for b in np.flatnonzero(np.diff(segments) > 0) + 1:
        lo, hi = max(0, b - params.break_window), min(n, b + params.break_window)
        pairs.update((a, c) for a in range(lo, b) for c in range(b, hi))
    return sorted(pairs)


def chain_poses(n: int, edges: list[OdometryEdge]) -> list[np.ndarray]:
    """Keyframe poses composed along the consecutive edges (b = a + 1)."""
    step = {e.target: e.T_target_source for e in edges if e.source == e.target + 1}
    T = [np.eye(4)]
    for a in range(n - 1):
        T.append(orthonormalize(T[-1] @ step[a]))
    return T


def optimize(
    keyframes: list[Keyframe], edges: list[OdometryEdge], params: LoopParams = LoopParams()
) -> tuple[list[np.ndarray], list[OdometryEdge]]:
    """Global pose-graph optimisation of Choi et al. 2015 as Open3D's
    ``global_optimization`` does it (Levenberg-Marquardt with a line process on
    the loop edges; the loops whose line process ends below
    ``edge_prune_threshold`` are pruned and the rest optimised again), solved with
    GTSAM's sparse LM instead: Open3D builds the normal equations as a dense
    6N x 6N matrix (a 2000-keyframe chain took 4.5 GB, a 25-minute floor 22 GB).
    The residual of an edge is the same (GTSAM's BetweenFactor error is
    Log(T_meas^-1 T_target^-1 T_source), rotation first as Open3D's information);
    the line process at its optimum is the Geman-McClure kernel with c^2 = Open3D's
    line-process weight. Keyframe 0 stays fixed (Open3D's reference node).
    Returns T_odom_kf and the edges kept."""
    T = [kf.T_odom_cam for kf in keyframes]
    active = list(range(len(edges)))
    for _ in range(2):
        T, confidence = _optimize_once(T, [edges[i] for i in active], params)
        active = [i for i, c in zip(active, confidence) if c > params.edge_prune_threshold]
    return [orthonormalize(t) for t in T], [edges[i] for i in active]


def _optimize_once(
    T_init: list[np.ndarray], edges: list[OdometryEdge], params: LoopParams
) -> tuple[list[np.ndarray], list[float]]:
    """One of Open3D's optimisation passes: poses and each edge's line process
    (1 for tracking edges)."""
    # Open3D's line-process weight (ComputeLineProcessWeight), over the edges of this pass.
    mu = (
        params.preference_loop_closure
        * params.max_correspondence_distance_m**2
        * float(np.mean([e.information[5, 5] for e in edges]))
        if edges
        else 0.0
    )
    kernel = gtsam.noiseModel.mEstimator.GemanMcClure.Create(np.sqrt(mu)) if mu > 0 else None
    uncertain = [e.kind not in TRACKING_KINDS for e in edges]
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, T in enumerate(T_init):
        values.insert(i, pose3(T))
    factors = []
    for e, loose in zip(edges, uncertain):
        model = gtsam.noiseModel.Gaussian.Information(e.information)
        if loose and kernel is not None:
            model = gtsam.noiseModel.Robust.Create(kernel, model)
        factors.append(gtsam.BetweenFactorPose3(e.target, e.source, pose3(e.T_target_source), model))
        graph.add(factors[-1])
    # Fix one node per connected part: keyframe 0, and where pruned loops left a part
    # unattached (Open3D's damped solve leaves such a part where it is), its first keyframe.
    n = len(T_init)
    adjacency = coo_matrix((np.ones(len(edges)), ([e.source for e in edges], [e.target for e in edges])), shape=(n, n))
    _, part = connected_components(adjacency, directed=False)
    for first in np.unique(part, return_index=True)[1]:
        graph.add(gtsam.NonlinearEqualityPose3(int(first), pose3(T_init[first])))
    result, *_ = levenberg_marquardt(graph, values, params.max_iterations, params.relative_error_tol)
    confidence = []
    for f, e, loose in zip(factors, edges, uncertain):
        if not loose:
            confidence.append(1.0)
            continue
        r = f.unwhitenedError(result)
        confidence.append((mu / (mu + float(r @ e.information @ r))) ** 2 if mu > 0 else 1.0)
    return [result.atPose3(i).matrix() for i in range(n)], confidence


class MultiwayRegistration:
    """Streaming multiway registration. ``add`` takes each keyframe with its
    features and the tracking edge from the previous keyframe as soon as they
    exist (the ego stage calls it on its feature thread while the recording
    goes on): the edge is checked against PnP, and the keyframe's loop
    candidates among the earlier ones (by the poses chained along the checked
    edges) are verified and refined. ``finish`` checks the edges that need a
    neighbour, tries the pairs around tracking breaks and optimises the graph."""

    def __init__(self, odometry: RgbdOdometry, params: LoopParams = LoopParams()):
        self.odometry, self.params = odometry, params
        self.keyframes: list[Keyframe] = []
        self.features: list[KeyframeFeatures] = []
        self.edges: list[OdometryEdge] = []  # checked tracking edges, b -> b - 1
        self._checked: list[bool] = []
        self._chain: list[np.ndarray] = []  # keyframe poses along the checked edges
        self._pairs: list[PairMatches] = []
        self._loops: list[OdometryEdge] = []
        self._tried: set[tuple[int, int]] = set()
        self._corrected = self._verified = 0
        self.places = PlaceIndex(params.retrieval)
        self._joined = {0}  # segments tied to the walk's first keyframe
        self._segment_start: dict[int, int] = {}  # segment -> its first keyframe
        self._relocalised = self._retrieved = 0

    def add(self, keyframe: Keyframe, features: KeyframeFeatures, edge: OdometryEdge | None) -> None:
        """``edge``: the tracking edge to the previous keyframe (None for the first)."""
        b = keyframe.index
        if b != len(self.keyframes) or (edge is None) != (b == 0):
            raise ValueError(f"keyframe {b} added out of order (have {len(self.keyframes)})")
        self.keyframes.append(keyframe)
        self.features.append(features)
        self.places.add(features.descriptors)
        self._segment_start.setdefault(keyframe.segment, b)
        if edge is None:
            self._chain.append(np.eye(4))
            return
        a = edge.target
        pair = match_pair(self.features[a], features, a, b, self.odometry.K_full, self.params.features)
        self._pairs.append(pair)
        edge, replaced = verify_edge(edge, pair, self.features, self.keyframes, self.odometry, self.params)
        self.edges.append(edge)
        self._checked.append(pair.pnp is not None)
        self._corrected += replaced
        self._chain.append(orthonormalize(self._chain[a] @ edge.T_target_source))
        if edge.kind != "break" and self.keyframes[a].segment in self._joined:
            self._joined.add(keyframe.segment)  # the break's edge was verified after all
        for a in loop_candidates_of(b, self._chain, self.params):
            self._try_loop(a, b)
        if self.params.retrieval.enabled:
            self._retrieve(b)

    def _retrieve(self, b: int) -> None:
        """Loops found by appearance: for a keyframe of a segment not yet joined, among
        the joined segments' keyframes (the first verified one relocalises the segment);
        else among the joined keyframes the pose-based search leaves out."""
        r, segment = self.params.retrieval, self.keyframes[b].segment
        joined = segment in self._joined
        last = b - self.params.min_separation if joined else b - 1
        allowed = [
            a for a in range(last + 1) if self.keyframes[a].segment in self._joined and (a, b) not in self._tried
        ]
        for a, _ in self.places.query(b, allowed)[: r.loop_candidates if joined else r.relocalisation_candidates]:
            edge = self._try_loop(a, b)
            if edge is None:
                continue
            if segment not in self._joined:
                s0 = self._segment_start[segment]
                T_s0 = self._relocalised_start(edge, s0)
                if T_s0 is None:  # a look-alike place (a symmetric room)
                    self._loops.remove(edge)
                    continue
                self._relocalise(s0, T_s0)
            self._retrieved += 1

    def _relocalised_start(self, loop: OdometryEdge, s0: int) -> np.ndarray | None:
        """The pose of keyframe s0, the first of the loop's newer keyframe's segment, that the
        loop implies; None when the walk could not have got there from its last joined
        keyframe in the time between them (faster than the odometry's `max_speed_mps`),
        or the turn across the break it implies contradicts the gyro's."""
        b, a = loop.source, loop.target
        T_s0 = self._chain[a] @ loop.T_target_source @ inv_se3(self._chain[b]) @ self._chain[s0]
        last = max(k.index for k in self.keyframes[:s0] if k.segment in self._joined)
        dt_s = (self.keyframes[s0].stamp_ns - self.keyframes[last].stamp_ns) * 1e-9
        reachable = np.linalg.norm(T_s0[:3, 3] - self._chain[last][:3, 3]) <= self.odometry.params.max_speed_mps * dt_s
        turn = gyro_agrees(self.edges[s0 - 1], inv_se3(self._chain[s0 - 1]) @ T_s0, self.params)
        return T_s0 if reachable and turn else None

    def _relocalise(self, s0: int, T_s0: np.ndarray) -> None:
        """Join a segment to the walk at the pose T_s0 of its first keyframe s0: when that
        one's edge is a break (not one verified to a segment not joined either), the break
        edge takes that pose; the chained poses follow."""
        self._joined.add(self.keyframes[s0].segment)
        self._relocalised += 1
        brk = self.edges[s0 - 1]
        if brk.kind != "break":
            return
        self.edges[s0 - 1] = OdometryEdge(
            source=brk.source,
            target=brk.target,
            T_target_source=orthonormalize(inv_se3(self._chain[s0 - 1]) @ T_s0),
            information=brk.information,
            kind=brk.kind,
            R_gyro=brk.R_gyro,
        )
        for k in range(s0, len(self.keyframes)):
            self._chain[k] = orthonormalize(self._chain[k - 1] @ self.edges[k - 1].T_target_source)

    def _try_loop(self, a: int, b: int) -> OdometryEdge | None:
        """Verify a loop candidate by SIFT + PnP and refine it densely (Choi et
        al. refine every loop: PnP is off by centimetres on wide-baseline loops
        and too coarse for the information matrix a dense edge carries). A loop
        that fails the refinement gives no edge; its matches still serve the
        bundle adjustment."""
        self._tried.add((a, b))
        pair = match_pair(self.features[a], self.features[b], a, b, self.odometry.K_full, self.params.features)
        if pair.pnp is None:
            return None
        self._verified += 1
        self._pairs.append(pair)
        edge = dense_edge(pair, self.keyframes[a], self.keyframes[b], self.odometry, self.params, "loop")
        if edge is not None:
            self._loops.append(edge)
        return edge

    def finish(self) -> MultiwayResult:
        p = self.params
        self._corrected += verify_across(
            self.edges, self._checked, self._pairs, self.features, self.keyframes, self.odometry, p
        )
        for a, c in break_pairs([k.segment for k in self.keyframes], p):
            if (a, c) not in self._tried:
                self._try_loop(a, c)
        # Re-initialise the nodes along the checked chain (tracking built on the old edges).
        T_init = chain_poses(len(self.keyframes), self.edges)
        nodes = [k.moved(T) for k, T in zip(self.keyframes, T_init)]
        T, kept = optimize(nodes, self.edges + self._loops, p)
        return MultiwayResult(
            T_odom_kf=T,
            edges_corrected=self._corrected,
            loops_tried=len(self._tried),
            loops_verified=self._verified,
            loops_refined=len(self._loops),
            loops_kept=sum(e.kind not in TRACKING_KINDS for e in kept),
            relocalised=self._relocalised,
            loops_retrieved=self._retrieved,
            pairs=self._pairs,
            edges=kept,
        )
