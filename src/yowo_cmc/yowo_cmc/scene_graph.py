"""The CMC scene graph (paper "CMC Processing"): every camera's keypoints on one time
grid, correspondences by time and keypoint id, MAGSAC fundamental matrices (eq.
inliers), overlap scores (eqs. grid, overlap, match), and the grouping of the cameras
along strong edges, split at weak cuts."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import networkx as nx
import numpy as np

from yowo_common.camera import CameraModel

from .keypoint_tracks import CameraTracks, noise_scale, resample, sigma_factors
from .params import SfmParams, TrackParams

# Keypoint ids per person: another person's joint j seen beside the walker is person * PERSON_STRIDE + j
# (yowo_cmc.people_identity); the walker's ids are the joints' own.
PERSON_STRIDE = 1000
MAX_IDS = 100 * PERSON_STRIDE  # keypoint ids per grid time: key = grid index * MAX_IDS + id
RANSAC_SEED = 0  # OpenCV's RANSAC draws from a global RNG: seed it so a bag always gives the same result


@dataclass(kw_only=True)
class GridObservations:
    """Every camera's keypoints sampled on one time grid: a 3D agent point is a
    (grid time, keypoint id) pair, so views at unequal rates correspond."""

    grid_ns: np.ndarray  # (G,) stamps of the grid
    cameras: list[CameraModel]  # ideal pinhole (undistorted) intrinsics
    names: list[str]
    per_camera: list[dict[int, np.ndarray]]  # camera -> {key: uv (2,)}
    noise_scale: list[float]  # camera -> factor on its pixel thresholds (tracks.noise_scale)
    sigma_factor: list[dict[int, float]]  # camera -> {key: factor on its BA sigma} for weak detections only
    # The keypoints' declared skeleton (yowo_cmc.skeletons): the noise classes by joint; None,
    # by id ranges (SfmParams.sigma_class_bounds).
    skeleton: object = None

    def keys(self, c: int) -> np.ndarray:
        return np.fromiter(self.per_camera[c].keys(), dtype=np.int64)

    def stamp_and_id(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.grid_ns[keys // MAX_IDS], keys % MAX_IDS


@dataclass(kw_only=True)
class PairGeometry:
    a: int
    b: int
    F: np.ndarray | None  # x_b^T F x_a = 0 (ideal pixels)
    keys: np.ndarray  # co-visible keys
    inliers: np.ndarray  # bool mask over keys
    overlap: tuple[float, float] = (0.0, 0.0)  # eq. overlap of the inliers in image a, image b

    @property
    def num_inliers(self) -> int:
        return int(self.inliers.sum())

    @classmethod
    def without_geometry(cls, a: int, b: int, keys: np.ndarray) -> PairGeometry:
        """A pair with no fundamental matrix, its co-visible `keys` all outliers."""
        return cls(a=a, b=b, F=None, keys=keys, inliers=np.zeros(len(keys), bool))


def sample_on_grid(cams: list[CameraTracks], params: TrackParams) -> GridObservations:
    """Clean, undistort and sample every track on a common grid at the fastest camera's period."""
    period = min(c.frame_period_ns for c in cams)
    all_stamps = np.concatenate([t.stamps_ns for c in cams for t in c.tracks.values()] or [np.zeros(0, np.int64)])
    if len(all_stamps) == 0:
        return GridObservations(
            grid_ns=np.zeros(0, np.int64),
            cameras=[],
            names=[c.name for c in cams],
            per_camera=[{} for _ in cams],
            noise_scale=[1.0 for _ in cams],
            sigma_factor=[{} for _ in cams],
        )
    t0 = all_stamps.min() - all_stamps.min() % period
    grid = np.arange(t0, all_stamps.max() + period, period, dtype=np.int64)
    per_camera, models, factors = [], [], []
    scales = [noise_scale(c, params) for c in cams]
    for cam, scale in zip(cams, scales):
        model, samples = resample(cam, grid, params, scale)
        models.append(model)
        obs, weak = {}, {}
        for kp_id, (uv, ok) in samples.items():
            if kp_id < MAX_IDS:
                at = np.flatnonzero(ok)
                obs.update((int(k) * MAX_IDS + kp_id, uv[k]) for k in at)
                factor = sigma_factors(cam.tracks[kp_id], grid[at], params)
                weak.update((int(at[i]) * MAX_IDS + kp_id, float(factor[i])) for i in np.flatnonzero(factor > 1))
        per_camera.append(obs)
        factors.append(weak)
    return GridObservations(
        grid_ns=grid,
        cameras=models,
        names=[c.name for c in cams],
        per_camera=per_camera,
        noise_scale=scales,
        sigma_factor=factors,
    )


def spread_subset(uv: np.ndarray, camera: CameraModel, params: SfmParams) -> np.ndarray:
    """Indices keeping at most `per_cell` points per image grid cell: a long stationary
    stretch puts thousands of near-identical correspondences in one spot, which would
    dominate (and degenerate) a RANSAC estimate."""
    cols = np.clip((uv[:, 0] / camera.width * params.grid_cols).astype(int), 0, params.grid_cols - 1)
    rows = np.clip((uv[:, 1] / camera.height * params.grid_rows).astype(int), 0, params.grid_rows - 1)
    cell = rows * params.grid_cols + cols
    order = np.argsort(cell, kind="stable")
    rank = np.arange(len(order)) - np.searchsorted(cell[order], cell[order])
    return np.sort(order[rank < params.per_cell])


def signed_sampson_px(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """First-order geometric (Sampson) error of x_b^T F x_a = 0, in pixels, with its sign
    (a least-squares residual)."""
    xa = np.column_stack([pa, np.ones(len(pa))])
    xb = np.column_stack([pb, np.ones(len(pb))])
    Fa, Ftb = xa @ F.T, xb @ F
    return np.sum(xb * Fa, axis=1) / np.sqrt(Fa[:, 0] ** 2 + Fa[:, 1] ** 2 + Ftb[:, 0] ** 2 + Ftb[:, 1] ** 2 + 1e-300)


def sampson_px(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """First-order geometric (Sampson) distance of x_b^T F x_a = 0, in pixels."""
    return np.abs(signed_sampson_px(F, pa, pb))


def pair_geometry(obs: GridObservations, a: int, b: int, params: SfmParams) -> PairGeometry:
    """MAGSAC fundamental matrix on a spatially spread subset; eq. inliers counted over
    every co-visible correspondence."""
    keys = np.intersect1d(obs.keys(a), obs.keys(b))
    if len(keys) < params.min_matches:
        return PairGeometry.without_geometry(a, b, keys)
    pa = np.array([obs.per_camera[a][k] for k in keys])
    pb = np.array([obs.per_camera[b][k] for k in keys])
    sub = spread_subset(pa, obs.cameras[a], params)
    ransac_px = params.ransac_px * max(obs.noise_scale[a], obs.noise_scale[b])
    F = None
    if len(sub) >= params.min_matches:
        cv2.setRNGSeed(RANSAC_SEED)
        try:
            F, _ = cv2.findFundamentalMat(pa[sub], pb[sub], cv2.USAC_MAGSAC, ransac_px, 0.9999, 10000)
        except cv2.error:  # degenerate configurations (e.g. all points in one spot) make USAC assert
            F = None
    if F is None or F.shape != (3, 3):
        return PairGeometry.without_geometry(a, b, keys)
    inliers = sampson_px(F, pa, pb) <= ransac_px
    return PairGeometry(
        a=a,
        b=b,
        F=F,
        keys=keys,
        inliers=inliers,
        overlap=(
            overlap_score(pa[inliers], obs.cameras[a], params),
            overlap_score(pb[inliers], obs.cameras[b], params),
        ),
    )


def overlap_score(uv: np.ndarray, camera: CameraModel, params: SfmParams) -> float:
    """Eqs. grid + overlap: occupied-cell spread (rows x cols, normalised) times occupied cells."""
    if len(uv) == 0:
        return 0.0
    cols = np.clip((uv[:, 0] / camera.width * params.grid_cols).astype(int), 0, params.grid_cols - 1)
    rows = np.clip((uv[:, 1] / camera.height * params.grid_rows).astype(int), 0, params.grid_rows - 1)
    G = np.zeros((params.grid_rows, params.grid_cols), bool)
    G[rows, cols] = True
    r, c = np.nonzero(G)
    spread = (r.max() - r.min()) * (c.max() - c.min()) / (params.grid_cols * params.grid_rows)
    return float(spread * G.sum())


def match_score(pair: PairGeometry) -> float:
    """Eq. match: overlap(c_i) * overlap(c_j) over the pair's inliers."""
    return pair.overlap[0] * pair.overlap[1]


def strong_edge(pair: PairGeometry, params: SfmParams) -> bool:
    return pair.num_inliers >= params.min_matches and min(pair.overlap) >= params.min_edge_overlap


def weak_cut_parts(G: nx.Graph, max_conductance: float) -> list[set]:
    """The graph's nodes split along every cut whose conductance (inliers across the cut /
    the smaller side's inliers at its cameras) is below max_conductance, recursively.
    Each cut is the best sweep of the normalised Laplacian's second eigenvector (spectral
    partitioning: exact enumeration grows as 2^n with a floor's cameras)."""
    nodes = list(G.nodes)
    if len(nodes) < 4 or max_conductance <= 0:  # each side needs two cameras
        return [set(nodes)]
    W = nx.to_numpy_array(G, nodelist=nodes, weight="weight")
    d = W.sum(axis=1)
    if not d.all():  # cameras left without an edge on their side of an earlier cut
        return [{n} for n, x in zip(nodes, d) if not x] + weak_cut_parts(
            G.subgraph(n for n, x in zip(nodes, d) if x), max_conductance
        )
    _, V = np.linalg.eigh(np.eye(len(nodes)) - W / np.sqrt(np.outer(d, d)))
    order = np.argsort(V[:, 1] / np.sqrt(d), kind="stable")
    side = np.zeros(len(nodes), bool)
    best, best_at = max_conductance, None
    for i in order[:-1]:
        side[i] = True
        cut = W[side][:, ~side].sum()
        conductance = cut / min(d[side].sum(), d[~side].sum())
        if min(side.sum(), (~side).sum()) >= 2 and conductance < best:
            best, best_at = conductance, side.copy()
    if best_at is None:
        return [set(nodes)]
    return [
        part
        for s in (best_at, ~best_at)
        for part in weak_cut_parts(G.subgraph(n for n, k in zip(nodes, s) if k), max_conductance)
    ]


def group_cameras(
    obs: GridObservations, pairs: list[PairGeometry], params: SfmParams
) -> tuple[list[list[int]], dict[int, str]]:
    """Scene-graph clustering: edges with >= min_matches inliers covering both images;
    members of a group of three or more must be joined by two edge-disjoint paths, and a
    group is split where it hangs together by a weak cut (weak_cut_parts)."""
    G = nx.Graph()
    G.add_nodes_from(range(len(obs.names)))
    for p in pairs:
        if strong_edge(p, params):
            G.add_edge(p.a, p.b, weight=p.num_inliers)
    groups: list[list[int]] = []
    for comp in nx.connected_components(G):
        if len(comp) > 2:
            for part in weak_cut_parts(G.subgraph(comp), params.max_cut_conductance):
                groups += [sorted(c) for c in nx.k_edge_components(G.subgraph(part), k=2) if len(c) >= 2]
    # Cameras left over (a pair alone, or joined to the rest by single edges) form pairs
    # along their strongest edges: a pair needs no second path.
    grouped = {c for g in groups for c in g}
    rest = G.subgraph(set(G.nodes) - grouped)
    groups += sorted(
        sorted(pair)
        for pair in (
            nx.max_weight_matching(rest)
            if params.pair_leftovers
            else (c for c in nx.connected_components(rest) if len(c) == 2)
        )
    )
    grouped = {c for g in groups for c in g}
    reasons = {c: _ungrouped_reason(obs, pairs, c, params) for c in range(len(obs.names)) if c not in grouped}
    return groups, reasons


def _ungrouped_reason(obs: GridObservations, pairs: list[PairGeometry], c: int, params: SfmParams) -> str:
    """Why camera c is in no group, from its best edge."""
    frames = len({k // MAX_IDS for k in obs.per_camera[c]})
    best = max((p for p in pairs if c in (p.a, p.b)), key=lambda p: p.num_inliers, default=None)
    if best is None or best.num_inliers == 0:
        return (
            f"seen in {frames} frames; shares no view of the agent with another camera "
            f"(needs {params.min_matches} matches)"
        )
    other = obs.names[best.b if best.a == c else best.a]
    if best.num_inliers < params.min_matches:
        return (
            f"seen in {frames} frames; only {best.num_inliers} inlier matches with '{other}' "
            f"(needs {params.min_matches})"
        )
    if not any(strong_edge(p, params) for p in pairs if c in (p.a, p.b)):
        return (
            f"its {best.num_inliers} matches with '{other}' cover too little of the images "
            f"(overlap {min(best.overlap):.1f}, needs {params.min_edge_overlap:.1f})"
        )
    return "joined to a group by a single camera pair (needs two paths to its members)"
