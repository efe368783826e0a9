"""Register a CMC group to the ego world frame (paper "Register CMCs to the scene"):
spatiotemporal clustering of the co-visible ego positions (eq. clustering), the
rebalanced weights alpha_f = 1 / (N_clus * N_phi_k), and the weighted
Kabsch-Umeyama (eq. reblanced_matching) from the group's head-top track to the
ego trajectory, matched by timestamp. Against the ego map: the rig's head offset (the head
top in the ego camera's frame), each group aligned to the head top the ego poses predict,
a group on the best window of a broken map, and each group's track on the ego clock."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation, Slerp

from yowo_cmc.group_sfm import CameraGroupResult
from yowo_common.geometry import Sim3, umeyama

from .records import AgentTrack, EgoMapData


@dataclass(frozen=True)
class AlignParams:
    # Two ego positions link in a spatiotemporal cluster when closer than this (eq. clustering's
    # spatialThreshold). Single linkage chains consecutive frames, so it sits below the
    # per-frame displacement of walking (~7 cm at 1 m/s, 15 Hz) and above the jitter of a
    # standing head: a stop becomes one cluster, a walk many.
    spatial_threshold_m: float = 0.025
    # Two ego positions link only when also closer in time than this (temporalThreshold; in
    # seconds, as the frame rates differ).
    temporal_threshold_s: float = 1.0
    max_time_gap_s: float = 0.15  # ego poses further than this from a track stamp are not matched
    rebalance: bool = True  # rebalanced weights (eq. reblanced_matching); False: the original KU, for ablation
    use_ground_points: bool = True  # ground points matched to the floor as well (see align_group)
    # A group whose track misses the ego trajectory by more than this (weighted RMS) has a
    # broken reconstruction, not a bad fit. Measured before the head offset is known, so a
    # group that fits misses by about that offset.
    max_rms_m: float = 0.5
    # Each group's clock offset to the ego camera estimated from the agent's track against the
    # ego trajectory (real CCTV clocks are not synchronised).
    estimate_clock_offset: bool = True
    max_clock_offset_s: float = 2.5  # the clock offset is searched within +- this
    clock_step_s: float = 0.02  # step of that search's grid of offsets
    # An offset with a larger sigma is not used: the clocks are taken as equal (a straight walk
    # at constant speed leaves the offset unobservable).
    max_clock_sigma_s: float = 0.05
    # An offset within this many sigmas of 0 is not applied [sigmas]. As cmc.clock.min_significance.
    min_clock_significance: float = 3.0


@dataclass(kw_only=True)
class Alignment:
    sim3_world_local: Sim3
    num_pairs: int
    num_clusters: int
    weights: np.ndarray  # alpha_f per matched pair (sums to one)
    residuals_m: np.ndarray  # ||X_world - S(X_local)|| per pair

    @property
    def rms_m(self) -> float:
        """Weighted RMS of the residuals (the weights sum to one)."""
        return float(np.sqrt(np.sum(self.weights * self.residuals_m**2)))


def spatiotemporal_clusters(positions: np.ndarray, stamps_ns: np.ndarray, params: AlignParams) -> np.ndarray:
    """Single-linkage clusters (label per position) where two frames link when they are
    close both in space and in time."""
    n = len(positions)
    order = np.argsort(stamps_ns, kind="stable")
    t = stamps_ns[order] / 1e9
    p = positions[order]
    rows, cols = [], []
    # Frames are sorted by time, so each frame only looks ahead within the temporal window.
    end = np.searchsorted(t, t + params.temporal_threshold_s, side="right")
    for i in range(n):
        js = np.arange(i + 1, end[i])
        close = js[np.linalg.norm(p[js] - p[i], axis=1) <= params.spatial_threshold_m]
        rows += [i] * len(close)
        cols += close.tolist()
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, labels_sorted = connected_components(graph, directed=False)
    labels = np.empty(n, dtype=int)
    labels[order] = labels_sorted
    return labels


def rebalanced_weights(labels: np.ndarray) -> np.ndarray:
    """alpha_f = 1 / (N_clus * N_phi_k) for f in cluster phi_k (sums to one)."""
    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    return 1.0 / (len(counts) * counts[inverse])


def interpolation_pairs(stamps_ns: np.ndarray, query_ns: np.ndarray, max_gap_ns: int):
    """(left index, right index, weight of right, valid) for each query stamp: valid only
    inside the stream, between two samples at most max_gap_ns apart."""
    right = np.clip(np.searchsorted(stamps_ns, query_ns), 1, len(stamps_ns) - 1)
    left = right - 1
    gap = stamps_ns[right] - stamps_ns[left]
    ok = (query_ns >= stamps_ns[0]) & (query_ns <= stamps_ns[-1]) & (gap <= max_gap_ns)
    a = np.clip((query_ns - stamps_ns[left]) / np.maximum(gap, 1), 0.0, 1.0)
    return left, right, a, ok


def interpolate_positions(
    stamps_ns: np.ndarray, positions: np.ndarray, query_ns: np.ndarray, max_gap_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of a trajectory at query stamps, and where it is valid (interpolation_pairs)."""
    left, right, a, ok = interpolation_pairs(stamps_ns, query_ns, max_gap_ns)
    a = a[:, None]
    return (1 - a) * positions[left] + a * positions[right], ok


def align_group(
    track_stamps_ns: np.ndarray,
    track_local: np.ndarray,
    ego_stamps_ns: np.ndarray,
    ego_positions: np.ndarray,
    params: AlignParams = AlignParams(),
    ground_stamps_ns: np.ndarray | None = None,
    ground_local: np.ndarray | None = None,
) -> Alignment:
    """Sim(3) taking the group's local frame to the world, from the head-top track
    (local, pseudo-scale) and the ego camera positions (world, metric).

    Optionally also the agent's ground points, matched to the floor (z = 0) under the
    ego position: head tops alone are nearly coplanar, and along a straight walk they
    leave the roll about the walking line free (the paper's KU uses the head track only;
    this is our addition)."""
    gap = int(params.max_time_gap_s * 1e9)
    world, ok = interpolate_positions(ego_stamps_ns, ego_positions, track_stamps_ns, gap)
    if ok.sum() < 3:
        raise ValueError(
            f"only {int(ok.sum())} head-top points of the group fall within the ego recording; "
            "needs at least 3 to align"
        )
    world, local, stamps = world[ok], track_local[ok], track_stamps_ns[ok]
    labels = spatiotemporal_clusters(world, stamps, params)
    if ground_local is not None and len(ground_local):
        floor, ok = interpolate_positions(ego_stamps_ns, ego_positions, ground_stamps_ns, gap)
        floor[:, 2] = 0.0
        if ok.any():
            # The floor points cluster on their own, so heads and feet weigh about the same.
            floor_labels = spatiotemporal_clusters(floor[ok], ground_stamps_ns[ok], params) + labels.max() + 1
            world, local = np.vstack([world, floor[ok]]), np.vstack([local, ground_local[ok]])
            labels = np.concatenate([labels, floor_labels])
    weights = rebalanced_weights(labels) if params.rebalance else np.full(len(world), 1.0 / len(world))
    S = umeyama(local, world, weights=weights)
    return Alignment(
        sim3_world_local=S,
        num_pairs=len(world),
        num_clusters=int(labels.max()) + 1,
        weights=weights,
        residuals_m=np.linalg.norm(S.apply(local) - world, axis=1),
    )


MIN_CLOCK_POINTS = 10  # head-top and ground points a group's clock offset needs (beside the 10 unknowns)


@dataclass
class ClockFit:
    offset_s: float | None  # the group's clock - the ego clock (None: not estimated)
    sigma_s: float | None
    reason: str = ""  # why not estimated


def estimate_clock_offset(
    track_stamps_ns: np.ndarray,
    track_local: np.ndarray,
    ego_stamps_ns: np.ndarray,
    T_world_ego: np.ndarray,
    params: AlignParams = AlignParams(),
    ground_stamps_ns: np.ndarray | None = None,
    ground_local: np.ndarray | None = None,
) -> ClockFit:
    """The shift of the agent track's clock against the ego clock at which the track
    fits the ego trajectory best under one similarity and one head offset (the head top
    sits behind the ego camera: at walking speed a constant offset along the path looks
    like a time shift, and only stops and turns tell them apart): the residual over a
    grid of shifts, then a least-squares parabola through nine costs around the best;
    the sigma from its curvature (the residual per coordinate as the noise). Ground
    points, when given, count as in align_group: on the floor (z = 0) under the head top
    (a group whose cameras rarely see the head top together still sees the feet). Our
    addition: the paper assumes synchronised clocks."""
    gap = int(params.max_time_gap_s * 1e9)
    step = params.clock_step_s
    shifts = np.arange(-params.max_clock_offset_s, params.max_clock_offset_s + 0.5 * step, step)
    if ground_stamps_ns is None:
        ground_stamps_ns, ground_local = np.zeros(0, np.int64), np.zeros((0, 3))
    stamps = np.concatenate([track_stamps_ns, ground_stamps_ns])
    local_all = np.vstack([track_local.reshape(-1, 3), ground_local.reshape(-1, 3)])
    on_floor = np.r_[np.zeros(len(track_stamps_ns), bool), np.ones(len(ground_stamps_ns), bool)]
    if len(stamps) < MIN_CLOCK_POINTS:
        return ClockFit(
            None,
            None,
            f"only {len(track_stamps_ns)} head-top and {len(ground_stamps_ns)} ground "
            f"points (needs {MIN_CLOCK_POINTS})",
        )
    ego_t = (ego_stamps_ns - ego_stamps_ns[0]) / 1e9
    orientations = Slerp(ego_t, Rotation.from_matrix(T_world_ego[:, :3, :3]))

    def covered(shift_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The track's stamps on the ego clock, the ego positions there, which are valid."""
        query = stamps - round(shift_s * 1e9)
        return (query, *interpolate_positions(ego_stamps_ns, T_world_ego[:, :3, 3], query, gap))

    def cost(shift_s: float, use: np.ndarray | None = None) -> tuple[float, int]:
        query, centres, ok = covered(shift_s)
        if use is not None:
            ok = use
        if ok.sum() < max(MIN_CLOCK_POINTS, len(stamps) // 2):
            return np.inf, int(ok.sum())
        t = np.clip((query[ok] - ego_stamps_ns[0]) / 1e9, ego_t[0], ego_t[-1])
        R, P, local, floor = orientations(t).as_matrix(), centres[ok], local_all[ok], on_floor[ok]
        # Rows of the residual that the head offset moves: all three of a head top, the
        # horizontal two of a ground point (its height is the floor's).
        rows = np.ones((len(P), 3), bool)
        rows[floor, 2] = False

        def targets(offset: np.ndarray) -> np.ndarray:  # head tops, and ground points on the floor
            return np.where(rows, P + R @ offset, 0.0)

        offset = np.zeros(3)
        try:
            for _ in range(4):  # the similarity and the head offset in turn
                S = umeyama(local, targets(offset))
                offset = np.linalg.lstsq(R[rows], (S.apply(local) - P)[rows], rcond=None)[0]
        except ValueError:
            return np.inf, int(ok.sum())
        return float(np.sum((S.apply(local) - targets(offset)) ** 2)), int(ok.sum())

    costs = np.array([cost(s)[0] for s in shifts])
    if not np.isfinite(costs).any():
        return ClockFit(None, None, "the agent track overlaps the ego recording at no shift")
    k = int(np.argmin(costs))
    if k in (0, len(shifts) - 1) or not np.isfinite(costs[k - 1 : k + 2]).all():
        return ClockFit(None, None, f"the best shift is at the edge of +-{params.max_clock_offset_s:g} s")
    # The fine fit on one point set (the points the ego trajectory covers over the whole
    # bracket) and slerped orientations, so the cost moves smoothly with the shift; nine
    # costs and not three, because where the CMC and ego frames share one rate the linear
    # interpolation kinks all residuals at the same shifts.
    use = covered(shifts[k] - step)[2] & covered(shifts[k])[2] & covered(shifts[k] + step)[2]
    near = shifts[k] + np.linspace(-step, step, 9)
    c = np.array([cost(s, use)[0] for s in near])
    if not np.isfinite(c).all():
        return ClockFit(None, None, "the fit has no clear minimum over the shift")
    a, b, _ = np.polyfit(near - shifts[k], c, 2)
    if a <= 0 or abs(b / (2 * a)) > step:
        return ClockFit(None, None, "the fit has no clear minimum over the shift")
    best = float(shifts[k] - b / (2 * a))
    curvature = 2 * a
    c_best, n = cost(best, use)
    sigma = float(np.sqrt(2.0 * (c_best / max(3 * n - 10, 1)) / curvature))
    if sigma > params.max_clock_sigma_s:
        return ClockFit(
            None,
            sigma,
            f"not observable from this walk (sigma {sigma:.2f} s > "
            f"{params.max_clock_sigma_s:g} s): clocks assumed equal",
        )
    return ClockFit(float(best), sigma)


def _head_offset(alignment: Sim3, top_stamps, top_local, ego: EgoMapData, max_gap_ns: int) -> np.ndarray:
    """Initial rigid head-top offset in the ego camera frame: median of R_f^T (A - t_f)."""
    A = alignment.apply(top_local)
    f = np.clip(np.searchsorted(ego.stamps_ns, top_stamps), 0, len(ego.stamps_ns) - 1)
    close = np.abs(ego.stamps_ns[f] - top_stamps) <= max_gap_ns
    T = ego.T_world_ego[f[close]]
    local = np.einsum("nji,nj->ni", T[:, :3, :3], A[close] - T[:, :3, 3])
    return np.median(local, axis=0) if len(local) else np.zeros(3)


def put_on_floor(S: Sim3, group: CameraGroupResult) -> Sim3:
    """Shift vertically so the agent's ground points lie on the ego map's floor (z = 0):
    the head-top/camera offset is mostly vertical and the Umeyama fit absorbs it."""
    bottom = group.point_ids == 1
    if bottom.sum() < 3:
        return S
    dz = float(np.median(S.apply(group.points[bottom])[:, 2]))
    return Sim3(S.s, S.R, S.t - [0.0, 0.0, dz])


def _group_tracks(group: CameraGroupResult, params: AlignParams):
    top, bottom = group.point_ids == 0, group.point_ids == 1
    ground = (group.point_stamps_ns[bottom], group.points[bottom]) if params.use_ground_points else (None, None)
    return group.point_stamps_ns[top], group.points[top], ground


def head_offset_estimate(group: CameraGroupResult, ego: EgoMapData, params: AlignParams) -> tuple[np.ndarray, int]:
    """First pass: rebalanced Umeyama of the head-top track against the ego camera
    positions, put on the floor; the head offset it implies and its weight (the number
    of spatiotemporal clusters: how much of the walk the group saw). ValueError when the
    group does not fit the ego trajectory (its cameras are then registered one by one)."""
    stamps, local, ground = _group_tracks(group, params)
    al = align_group(stamps, local, ego.stamps_ns, ego.T_world_ego[:, :3, 3], params, *ground)
    if al.rms_m > params.max_rms_m:
        raise ValueError(
            f"its agent track does not fit the ego trajectory (RMS {al.rms_m:.2f} m > {params.max_rms_m:g} m)"
        )
    return _head_offset(
        put_on_floor(al.sim3_world_local, group), stamps, local, ego, int(params.max_time_gap_s * 1e9)
    ), al.num_clusters


def head_tops(T_world_ego: np.ndarray, head_offset: np.ndarray) -> np.ndarray:
    """(F, 3) the head top each ego pose predicts: the ego camera's pose applied to the offset."""
    return np.einsum("nij,j->ni", T_world_ego[:, :3, :3], head_offset) + T_world_ego[:, :3, 3]


def align_to_world(group: CameraGroupResult, ego: EgoMapData, params: AlignParams, head_offset: np.ndarray) -> Sim3:
    """Rebalanced Umeyama against the head top predicted from the ego poses with the
    rig's head offset (one for all groups: a group that saw a short stretch of the walk
    estimates it badly on its own)."""
    stamps, local, ground = _group_tracks(group, params)
    return align_group(
        stamps, local, ego.stamps_ns, head_tops(ego.T_world_ego, head_offset), params, *ground
    ).sim3_world_local


def weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per column: the value where the cumulative weight reaches half (robust to a group's outlier)."""
    out = []
    for column in np.atleast_2d(values).T:
        order = np.argsort(column)
        cum = np.cumsum(weights[order])
        out.append(column[order][np.searchsorted(cum, 0.5 * cum[-1])])
    return np.array(out)


def window_alignment(group: CameraGroupResult, ego: EgoMapData, params: AlignParams, window_s: float):
    """The group's alignment on the window_s of its walk that fits the ego trajectory best
    (where the ego map broke: one of its pieces), or None."""
    stamps, local, (g_ns, g_local) = _group_tracks(group, params)
    best, span = None, int(window_s * 1e9)
    if not len(stamps):
        return None
    for t0 in range(int(stamps.min()), max(int(stamps.max()) - span, int(stamps.min())) + 1, 10**9):
        sel = (stamps >= t0) & (stamps < t0 + span)
        ground = (
            (None, None)
            if g_ns is None
            else (g_ns[(g_ns >= t0) & (g_ns < t0 + span)], g_local[(g_ns >= t0) & (g_ns < t0 + span)])
        )
        try:
            al = align_group(stamps[sel], local[sel], ego.stamps_ns, ego.T_world_ego[:, :3, 3], params, *ground)
        except ValueError:
            continue
        if best is None or al.rms_m < best.rms_m:
            best = al
    return best


def head_top_rms(
    agent: AgentTrack,
    chain: np.ndarray,
    c: int,
    ego_stamps_ns: np.ndarray,
    T_world_ego: np.ndarray,
    head_offset: np.ndarray,
    max_gap_s: float,
) -> float:
    """RMS distance between a group's head-top points and the head top the ego trajectory
    predicts at their stamps."""
    sel = (chain == c) & (agent.ids == 0)
    predicted, ok = interpolate_positions(
        ego_stamps_ns, head_tops(T_world_ego, head_offset), agent.stamps_ns[sel], int(max_gap_s * 1e9)
    )
    d = np.linalg.norm(agent.points[sel][ok] - predicted[ok], axis=1)
    return float(np.sqrt(np.mean(d**2))) if len(d) else float("nan")


def on_ego_clock(
    groups: list[CameraGroupResult], ego: EgoMapData, params: AlignParams
) -> tuple[list[CameraGroupResult], dict[str, float], dict[str, tuple[float | None, float | None, str]]]:
    """Each group with its track on the ego clock (its reference camera's offset to the
    ego camera estimated from the agent's track against the ego trajectory; 0 where it is
    not observable), that offset per group, and each member's clock against the ego's:
    its offset to the reference plus the reference's."""
    out, shifts, clocks = [], {}, {}
    for g in groups:
        fit = ClockFit(None, None, "not estimated (fusion.align.estimate_clock_offset is off)")
        if params.estimate_clock_offset:
            stamps, local, ground = _group_tracks(g, params)
            fit = estimate_clock_offset(stamps, local, ego.stamps_ns, ego.T_world_ego, params, *ground)
        applied = fit.offset_s is not None and abs(fit.offset_s) > params.min_clock_significance * fit.sigma_s
        delta = shifts[g.group_id] = fit.offset_s if applied else 0.0
        out.append(replace(g, point_stamps_ns=g.point_stamps_ns - round(delta * 1e9)))
        note = f"group {g.group_id}'s track against the ego trajectory (reference {g.reference})"
        if fit.offset_s is not None and not applied:
            note += (
                f": {1e3 * fit.offset_s:+.1f} +- {1e3 * fit.sigma_s:.1f} ms is within "
                f"{params.min_clock_significance:g} sigma of 0, so the clocks are taken as equal"
            )
        for n in g.names:
            if fit.offset_s is None:
                clocks[n] = (None, None, f"group {g.group_id}'s clock against the ego camera: {fit.reason}")
            else:
                clocks[n] = (
                    g.clock_offsets_s.get(n, 0.0) + delta,
                    float(np.hypot(g.clock_sigmas_s.get(n, 0.0), fit.sigma_s)),
                    note,
                )
    return out, shifts, clocks
