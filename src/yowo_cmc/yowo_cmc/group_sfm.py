"""CMC groups and their relative calibration from agent keypoints alone
(paper "CMC Processing"): correspondences by time and keypoint id, MAGSAC
fundamental matrices (eq. inliers), scene graph and grouping, overlap scores
(eqs. grid, overlap), initial pair by match score (eq. match), E = K^T F K with
the cheirality check, triangulation, next camera by overlap + PnP RANSAC, and
group bundle adjustment (eq. cmc_bd) with per-keypoint-id noise re-estimation."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import networkx as nx
import numpy as np

from yowo_common.bundle import BundleProblem, Observations, robust_sigma, solve
from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, se3
from yowo_common.pnp import sqpnp_ransac

from .intrinsics import EstimatedCamera, centred, focal_from_fundamental, pnp_unknown_focal, solve_with_intrinsics
from .keypoint_tracks import CameraTracks, noise_scale, resample, sigma_factors
from .params import SfmParams, TrackParams

MAX_IDS = 1000  # keypoint ids per grid time: key = grid index * MAX_IDS + id
RANSAC_SEED = 0  # OpenCV's RANSAC draws from a global RNG: seed it so a bag always gives the same result


@dataclass
class GridObservations:
    """Every camera's keypoints sampled on one time grid: a 3D agent point is a
    (grid time, keypoint id) pair, so views at unequal rates correspond."""

    grid_ns: np.ndarray  # (G,) stamps of the grid
    cameras: list[CameraModel]  # ideal pinhole (undistorted) intrinsics
    names: list[str]
    per_camera: list[dict[int, np.ndarray]]  # camera -> {key: uv (2,)}
    noise_scale: list[float]  # camera -> factor on its pixel thresholds (tracks.noise_scale)
    sigma_factor: list[dict[int, float]]  # camera -> {key: factor on its BA sigma} for weak detections only

    def keys(self, c: int) -> np.ndarray:
        return np.fromiter(self.per_camera[c].keys(), dtype=np.int64)

    def stamp_and_id(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.grid_ns[keys // MAX_IDS], keys % MAX_IDS


@dataclass
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


@dataclass
class CameraGroupResult:
    group_id: str
    reference: str
    names: list[str]
    T_local_cam: dict[str, np.ndarray]
    point_stamps_ns: np.ndarray  # (P,)
    point_ids: np.ndarray  # (P,)
    points: np.ndarray  # (P, 3) local, pseudo-scale
    rmse_px: dict[str, float]
    num_observations: dict[str, int]
    sigma_px_by_id: dict[int, float]
    initial_pair: tuple[str, str]
    # each member's intrinsics with distortion (intrinsics.EstimatedCamera: estimated by the group)
    cameras: dict[str, CameraModel] = field(default_factory=dict)
    # Estimated clock offsets (yowo_cmc.clock): member's clock - the reference camera's [s].
    clock_offsets_s: dict[str, float] = field(default_factory=dict)
    clock_sigmas_s: dict[str, float] = field(default_factory=dict)
    # True: calibrated on stamps corrected by them, the points on the reference's clock.
    clocks_applied: bool = False
    # keypoint id -> factor on the triangulation gates of the kept reconstruction ({}: the nominal gates)
    gate_scales: dict[int, float] = field(default_factory=dict)


@dataclass
class GroupingResult:
    groups: list[CameraGroupResult]
    ungrouped: dict[str, str]  # camera -> reason
    pairs: list[PairGeometry]


def sample_on_grid(cams: list[CameraTracks], params: TrackParams) -> GridObservations:
    """Clean, undistort and sample every track on a common grid at the fastest camera's period."""
    period = min(c.frame_period_ns for c in cams)
    all_stamps = np.concatenate([t.stamps_ns for c in cams for t in c.tracks.values()] or [np.zeros(0, np.int64)])
    if len(all_stamps) == 0:
        return GridObservations(
            np.zeros(0, np.int64),
            [],
            [c.name for c in cams],
            [{} for _ in cams],
            [1.0 for _ in cams],
            [{} for _ in cams],
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
    return GridObservations(grid, models, [c.name for c in cams], per_camera, scales, factors)


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


def sampson_px(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """First-order geometric (Sampson) distance of x_b^T F x_a = 0, in pixels."""
    xa = np.column_stack([pa, np.ones(len(pa))])
    xb = np.column_stack([pb, np.ones(len(pb))])
    Fa, Ftb = xa @ F.T, xb @ F
    num = np.sum(xb * Fa, axis=1)
    return np.abs(num) / np.sqrt(Fa[:, 0] ** 2 + Fa[:, 1] ** 2 + Ftb[:, 0] ** 2 + Ftb[:, 1] ** 2 + 1e-300)


def pair_geometry(obs: GridObservations, a: int, b: int, params: SfmParams) -> PairGeometry:
    """MAGSAC fundamental matrix on a spatially spread subset; eq. inliers counted over
    every co-visible correspondence."""
    keys = np.intersect1d(obs.keys(a), obs.keys(b))
    if len(keys) < params.min_matches:
        return PairGeometry(a, b, None, keys, np.zeros(len(keys), bool))
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
        return PairGeometry(a, b, None, keys, np.zeros(len(keys), bool))
    inliers = sampson_px(F, pa, pb) <= ransac_px
    return PairGeometry(
        a,
        b,
        F,
        keys,
        inliers,
        (overlap_score(pa[inliers], obs.cameras[a], params), overlap_score(pb[inliers], obs.cameras[b], params)),
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
    reasons = {}
    for c in range(len(obs.names)):
        if c in grouped:
            continue
        frames = len({k // MAX_IDS for k in obs.per_camera[c]})
        best = max((p for p in pairs if c in (p.a, p.b)), key=lambda p: p.num_inliers, default=None)
        if best is None or best.num_inliers == 0:
            reasons[c] = (
                f"seen in {frames} frames; shares no view of the agent with another camera "
                f"(needs {params.min_matches} matches)"
            )
        elif best.num_inliers < params.min_matches:
            other = obs.names[best.b if best.a == c else best.a]
            reasons[c] = (
                f"seen in {frames} frames; only {best.num_inliers} inlier matches with '{other}' "
                f"(needs {params.min_matches})"
            )
        elif not any(strong_edge(p, params) for p in pairs if c in (p.a, p.b)):
            other = obs.names[best.b if best.a == c else best.a]
            reasons[c] = (
                f"its {best.num_inliers} matches with '{other}' cover too little of the images "
                f"(overlap {min(best.overlap):.1f}, needs {params.min_edge_overlap:.1f})"
            )
        else:
            reasons[c] = "joined to a group by a single camera pair (needs two paths to its members)"
    return groups, reasons


def triangulate(cameras: list[CameraModel], poses: list[np.ndarray], uvs: list[np.ndarray]) -> np.ndarray:
    """Linear multi-view triangulation (DLT) of one point."""
    A = []
    for cam, T, uv in zip(cameras, poses, uvs):
        P = cam.K @ inv_se3(T)[:3]
        A += [uv[0] * P[2] - P[0], uv[1] * P[2] - P[1]]
    _, _, Vt = np.linalg.svd(np.array(A))
    X = Vt[-1]
    return X[:3] / X[3] if abs(X[3]) > 1e-12 else np.full(3, np.nan)


def view_residuals_px(
    X: np.ndarray, cameras: list[CameraModel], poses: list[np.ndarray], uvs: list[np.ndarray]
) -> list[float]:
    """The reprojection residual (px) of the point X in each of its views."""
    return [float(np.linalg.norm(cam.project_world(T, X[None])[0][0] - uv)) for cam, T, uv in zip(cameras, poses, uvs)]


def ideal_view(model: CameraModel, raw: dict[int, np.ndarray]) -> tuple[CameraModel, dict[int, np.ndarray]]:
    """A camera's pinhole model and its observations {key: uv} undistorted by `model`."""
    if not model.has_distortion:
        return CameraModel(model.width, model.height, model.K), raw
    keys = list(raw)
    ideal = model.undistort_pixels(np.array([raw[k] for k in keys]).reshape(-1, 2))
    return CameraModel(model.width, model.height, model.K), dict(zip(keys, ideal))


def with_estimates(obs: GridObservations, result: CameraGroupResult) -> GridObservations:
    """The observations as the group's intrinsics estimates see them (obs itself if it has none)."""
    estimated = {obs.names.index(n): c for n, c in result.cameras.items() if isinstance(c, EstimatedCamera)}
    if not estimated:
        return obs
    cameras, per_camera = list(obs.cameras), list(obs.per_camera)
    for c, model in estimated.items():
        cameras[c], per_camera[c] = ideal_view(model, obs.per_camera[c])
    return replace(obs, cameras=cameras, per_camera=per_camera)


def _translation_given_rotation(R_cam_world: np.ndarray, X: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """Least-squares t of x ~ R X + t from normalised image points: linear once R is known."""
    RX = X @ R_cam_world.T
    A = np.zeros((2 * len(X), 3))
    A[0::2, 0] = A[1::2, 1] = 1.0
    A[0::2, 2], A[1::2, 2] = -xn[:, 0], -xn[:, 1]
    rhs = np.column_stack([xn[:, 0] * RX[:, 2] - RX[:, 0], xn[:, 1] * RX[:, 2] - RX[:, 1]]).ravel()
    return np.linalg.lstsq(A, rhs, rcond=None)[0].reshape(3, 1)


class IncrementalSfm:
    """Incremental reconstruction of one group in its local frame (reference camera = identity)."""

    def __init__(
        self,
        obs: GridObservations,
        members: list[int],
        params: SfmParams,
        id_gate_scale: dict[int, float] | None = None,
        unknown: frozenset[int] = frozenset(),
    ):
        # Its own lists of intrinsics and observations: those of a camera of unknown intrinsics
        # (`unknown`) change with each estimate (pinhole K, pixels undistorted by its k1).
        self.obs = replace(obs, cameras=list(obs.cameras), per_camera=list(obs.per_camera))
        self.raw = obs.per_camera
        self.members, self.params = members, params
        self.unknown = unknown & set(members)
        self.estimated: dict[int, CameraModel] = {}  # unknown camera -> its current estimate (with k1)
        # keypoint id -> factor on the triangulation gates (at least the camera's noise scale)
        self.id_gate_scale = id_gate_scale or {}
        self.poses: dict[int, np.ndarray] = {}
        self.points: dict[int, np.ndarray] = {}
        self.failed: dict[int, str] = {}

    def initialise(self, pair: PairGeometry) -> None:
        if {pair.a, pair.b} & self.unknown:
            self._pair_focals(pair)
        self.poses[pair.a] = np.eye(4)
        candidates = self._relative_candidates(pair.a, pair.b, pair.keys[pair.inliers], pair.F)
        self.poses[pair.b] = max(candidates, key=lambda T: self._verify(pair.b, T))
        self.triangulate_new()

    def _pair_focals(self, pair: PairGeometry) -> None:
        """Initial focal lengths of the pair's unknown cameras from its fundamental matrix."""
        a, b, F = pair.a, pair.b, pair.F
        if a in self.unknown and b not in self.unknown:
            a, b, F = b, a, F.T
        size = {c: (self.obs.cameras[c].width, self.obs.cameras[c].height) for c in (a, b)}
        fa, fb = focal_from_fundamental(
            F, None if a in self.unknown else self.obs.cameras[a].K, size[a], size[b], self.params.hfov_range_deg
        )
        for c, f in ((a, fa), (b, fb)):
            if c in self.unknown:
                self._set_intrinsics(c, centred(*size[c], f))

    def _set_intrinsics(self, c: int, model: CameraModel) -> None:
        """A new estimate of unknown camera c's intrinsics: its pinhole model and pixels follow."""
        self.estimated[c] = model
        self.obs.cameras[c], self.obs.per_camera[c] = ideal_view(model, self.raw[c])

    def _relative_candidates(self, a: int, b: int, keys: np.ndarray, F: np.ndarray | None = None) -> list[np.ndarray]:
        """Candidate poses T_a_b (unit baseline) from the 2D-2D matches `keys`."""
        pa = np.array([self.obs.per_camera[a][k] for k in keys])
        pb = np.array([self.obs.per_camera[b][k] for k in keys])
        Ka, Kb = self.obs.cameras[a].K, self.obs.cameras[b].K
        na = cv2.undistortPoints(pa[:, None], Ka, None).reshape(-1, 2)
        nb = cv2.undistortPoints(pb[:, None], Kb, None).reshape(-1, 2)
        # Deviation from the paper (E = K^T F K, eq. F2E): the agent's points lie close to two
        # horizontal planes (head and floor), where the 7-DoF F is nearly degenerate and its E
        # can be far off; the calibrated 5-point solver on the F inliers is well conditioned.
        cv2.setRNGSeed(RANSAC_SEED)
        thresh = (
            self.params.ransac_px * max(self.obs.noise_scale[a], self.obs.noise_scale[b]) / np.sqrt(Ka[0, 0] * Kb[0, 0])
        )
        sub = spread_subset(pa, self.obs.cameras[a], self.params)
        E = None
        if len(sub) >= 5:
            E, _ = cv2.findEssentialMat(na[sub], nb[sub], np.eye(3), cv2.USAC_MAGSAC, 0.9999, thresh)
        if (E is None or E.shape != (3, 3)) and F is not None:
            E = Kb.T @ F @ Ka
        candidates = []
        if E is not None and E.shape == (3, 3):
            _, R, t, _ = cv2.recoverPose(E, na, nb, np.eye(3))  # SVD + cheirality check
            candidates.append(inv_se3(se3(R, t.ravel())))  # T_a_b: R_ab = R^T, X_b = -R^T t
        # Our addition to the paper's geometric verification: each keypoint id of a walking
        # agent stays near one horizontal plane (head top, floor point), so its matches also
        # fit a homography. At high noise the 5-point E of the two nearly planar layers can
        # fall into a wrong solution (5 px: 34 deg off) where a per-id homography's
        # decomposition is close (4.5 deg); _verify picks among them.
        ids = keys % MAX_IDS
        for i in np.unique(ids):
            if np.sum(ids == i) < self.params.min_matches:
                continue
            cv2.setRNGSeed(RANSAC_SEED)
            H, _ = cv2.findHomography(na[ids == i], nb[ids == i], cv2.USAC_MAGSAC, thresh)
            if H is not None:
                _, Rs, ts, _ = cv2.decomposeHomographyMat(H, np.eye(3))
                candidates += [
                    inv_se3(se3(R, t.ravel() / np.linalg.norm(t))) for R, t in zip(Rs, ts) if np.linalg.norm(t) > 1e-9
                ]
        return candidates

    def _verify(self, c: int, T: np.ndarray) -> tuple[int, float]:
        """Geometric verification of a candidate pose T of camera c: how many of c's points
        seen by a posed camera triangulate acceptably with it, then minus their mean
        reprojection error (px). Scored on a spread subset (a long stop is one spot)."""
        poses = {**self.poses, c: T}
        keys = list(self.obs.per_camera[c])
        uv = np.array([self.obs.per_camera[c][k] for k in keys]).reshape(-1, 2)
        count, errs = 0, []
        for i in spread_subset(uv, self.obs.cameras[c], self.params):
            views = [v for v in poses if keys[i] in self.obs.per_camera[v]]
            if len(views) < 2:
                continue
            cams = [self.obs.cameras[v] for v in views]
            uvs = [self.obs.per_camera[v][keys[i]] for v in views]
            X = triangulate(cams, [poses[v] for v in views], uvs)
            if np.isfinite(X).all() and self._acceptable(
                X, cams, [poses[v] for v in views], uvs, self._gate_scales(keys[i], views)
            ):
                count += 1
                errs += view_residuals_px(X, cams, [poses[v] for v in views], uvs)
        return count, -float(np.mean(errs)) if errs else 0.0

    def _views(self, key: int) -> list[int]:
        return [c for c in self.poses if key in self.obs.per_camera[c]]

    def triangulate_new(self, gate_px: float | None = None) -> None:
        """Triangulate the keys seen by >= 2 posed cameras that have no point yet, each kept if
        it reprojects within gate_px (default max_reproj_px) times the cameras' noise scale."""
        candidates = set().union(*(self.obs.per_camera[c].keys() for c in self.poses)) - set(self.points)
        for key in candidates:
            views = self._views(key)
            if len(views) < 2:
                continue
            cams = [self.obs.cameras[c] for c in views]
            poses = [self.poses[c] for c in views]
            uvs = [self.obs.per_camera[c][key] for c in views]
            X = triangulate(cams, poses, uvs)
            scales = self._gate_scales(key, views) if gate_px is None else [self.obs.noise_scale[c] for c in views]
            if np.isfinite(X).all() and self._acceptable(X, cams, poses, uvs, scales, gate_px):
                self.points[key] = X

    def _gate_scales(self, key: int, views: list[int]) -> list[float]:
        id_scale = self.id_gate_scale.get(int(key) % MAX_IDS, 1.0)
        return [max(self.obs.noise_scale[c], id_scale) for c in views]

    def _acceptable(self, X, cams, poses, uvs, scales, gate_px: float | None = None) -> bool:
        gate_px = self.params.max_reproj_px if gate_px is None else gate_px
        rays = []
        for cam, T, uv, scale in zip(cams, poses, uvs, scales):
            proj, front = cam.project_world(T, X[None])
            if not front[0] or np.linalg.norm(proj[0] - uv) > gate_px * scale:
                return False
            rays.append((X - T[:3, 3]) / np.linalg.norm(X - T[:3, 3]))
        cos = max(abs(float(r1 @ r2)) for i, r1 in enumerate(rays) for r2 in rays[i + 1 :])
        return np.degrees(np.arccos(min(cos, 1.0))) >= self.params.min_angle_deg

    def next_camera(self) -> int | None:
        """The unregistered member whose 2D points on existing 3D points cover its image best."""
        best, best_score = None, 0.0
        for c in self.members:
            if c in self.poses or c in self.failed:
                continue
            keys = [k for k in self.obs.per_camera[c] if k in self.points]
            if len(keys) < self.params.min_pnp:
                continue
            uv = np.array([self.obs.per_camera[c][k] for k in keys])
            score = overlap_score(uv, self.obs.cameras[c], self.params) if self.params.overlap_ordering else len(uv)
            if score > best_score:
                best, best_score = c, score
        return best

    def register(self, c: int) -> bool:
        keys = [k for k in self.obs.per_camera[c] if k in self.points]
        obj = np.array([self.points[k] for k in keys])
        gate = self.params.pnp_px * self.obs.noise_scale[c]
        if c in self.unknown:
            cam = self.obs.cameras[c]
            found = pnp_unknown_focal(
                obj,
                np.array([self.raw[c][k] for k in keys]),
                (cam.width, cam.height),
                self.params.hfov_range_deg,
                self.params.focal_steps,
                gate,
                self.params.min_pnp,
                self.params.estimate_k1,
                RANSAC_SEED,
            )
            if found is None:
                self.failed[c] = (
                    f"PnP with unknown focal length found no focal with {self.params.min_pnp} consistent agent points"
                )
                return False
            model, rvec, tvec, idx = found
            self._set_intrinsics(c, model)
        else:
            rvec, tvec, idx = sqpnp_ransac(
                obj, np.array([self.obs.per_camera[c][k] for k in keys]), self.obs.cameras[c].K, gate, seed=RANSAC_SEED
            )
        img = np.array([self.obs.per_camera[c][k] for k in keys])
        if len(idx) < self.params.min_pnp:
            self.failed[c] = f"PnP found {len(idx)} consistent agent points (needs {self.params.min_pnp})"
            return False
        K = self.obs.cameras[c].K
        rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, None, rvec, tvec)
        candidates = [inv_se3(se3(cv2.Rodrigues(rvec)[0], tvec.ravel()))]
        # Our addition: the group's points this camera sees may all be one id (one plane),
        # where PnP at high noise flips (5 px: 106 deg off). Rotations from the 2D-2D
        # geometry with each posed camera (as for the initial pair), with the translation
        # fitted to the 2D-3D matches, compete with it in the same verification.
        norm = cv2.undistortPoints(img[:, None], K, None).reshape(-1, 2)
        for r in list(self.poses):
            shared = np.array([k for k in self.obs.per_camera[c] if k in self.obs.per_camera[r]], dtype=np.int64)
            if len(shared) < self.params.min_matches:
                continue
            for T_rc in self._relative_candidates(r, c, shared):
                R_cl = (self.poses[r][:3, :3] @ T_rc[:3, :3]).T
                t = _translation_given_rotation(R_cl, obj, norm)
                err = np.linalg.norm(cv2.projectPoints(obj, cv2.Rodrigues(R_cl)[0], t, K, None)[0][:, 0] - img, axis=1)
                inl = err <= self.params.pnp_px * self.obs.noise_scale[c]
                if inl.sum() >= self.params.min_pnp:
                    rv, tv = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, cv2.Rodrigues(R_cl)[0], t)
                    candidates.append(inv_se3(se3(cv2.Rodrigues(rv)[0], tv.ravel())))
        self.poses[c] = max(candidates, key=lambda T: self._verify(c, T))
        self.triangulate_new()
        return True

    def bundle_adjust(self, reference: int, second: int, sigma_by_id: dict[int, float]) -> dict:
        cams = sorted(self.poses)
        index = {c: i for i, c in enumerate(cams)}
        keys = np.array(sorted(self.points), dtype=np.int64)
        kidx = {int(k): i for i, k in enumerate(keys)}
        cam_i, pt_i, uv, raw, sig = [], [], [], [], []
        for c in cams:
            for k, p in self.obs.per_camera[c].items():
                if k in kidx:
                    cam_i.append(index[c])
                    pt_i.append(kidx[k])
                    uv.append(p)
                    raw.append(self.raw[c][k])
                    sig.append(
                        sigma_by_id.get(k % MAX_IDS, self.params.initial_sigma_px * self.obs.noise_scale[c])
                        * self.obs.sigma_factor[c].get(k, 1.0)
                    )
        obs = Observations(
            np.array(cam_i, dtype=int),
            np.array(pt_i, dtype=int),
            np.array(uv).reshape(-1, 2),
            np.array(sig, dtype=float),
        )
        baseline = np.linalg.norm(self.poses[second][:3, 3])
        problem = BundleProblem(
            [self.obs.cameras[c] for c in cams],
            [self.poses[c] for c in cams],
            np.array([self.points[int(k)] for k in keys]),
            obs,
            fixed_cameras={index[reference]},
            # The scale gauge only (a prior on a centre would also pin the
            # baseline's direction to its noisy initial estimate).
            baseline_prior=(index[reference], index[second], baseline, 1e-4 * baseline),
        )
        unknown = {index[c]: self.estimated.get(c, self.obs.cameras[c]) for c in cams if c in self.unknown}
        if unknown:
            res, estimated = solve_with_intrinsics(
                problem, unknown, np.array(raw).reshape(-1, 2), self.params.estimate_k1
            )
            for c in cams:
                if index[c] in estimated:
                    self._set_intrinsics(c, estimated[index[c]])
        else:
            res = solve(problem)
        for c in cams:
            self.poses[c] = res.T_world_cam[index[c]]
        for k, i in kidx.items():
            self.points[k] = res.points[i]
        return {"obs": obs, "residuals": res.residuals_px, "cams": cams, "keys": keys}


def residual_sigmas(ba: dict, class_bounds: tuple[int, ...]) -> dict[int, float]:
    """{keypoint id: robust sigma px} from a bundle adjustment's residuals, pooled over each
    keypoint class (ids split at class_bounds; classes with 10 or more residuals)."""
    kp_ids = ba["keys"][ba["obs"].point] % MAX_IDS
    classes = np.searchsorted(np.asarray(class_bounds, dtype=np.int64), kp_ids, side="right")
    sigma = {
        int(k): max(robust_sigma(ba["residuals"][classes == k]), 0.05)
        for k in np.unique(classes)
        if np.sum(classes == k) >= 10
    }
    return {int(i): sigma[int(k)] for i, k in zip(*np.unique(np.stack([kp_ids, classes]), axis=1)) if int(k) in sigma}


def geometric_gate_scales(sigma_by_id: dict[int, float], params: SfmParams) -> dict[int, float]:
    """{keypoint id: factor on the triangulation gates} for the ids whose estimated sigma (their
    residual between views) is at least min_gate_scale times the nominal noise the gates were
    tuned for; {} if none is."""
    nominal = params.tracks.nominal_noise_px
    return {i: s / nominal for i, s in sigma_by_id.items() if s >= params.min_gate_scale * nominal}


def reconstruct_group(
    obs: GridObservations,
    members: list[int],
    pairs: list[PairGeometry],
    group_id: str,
    params: SfmParams,
    unknown: frozenset[int] = frozenset(),
) -> tuple[CameraGroupResult | None, dict[int, str]]:
    """One group's reconstruction; `unknown`: the cameras whose intrinsics it estimates."""
    inside = [p for p in pairs if p.a in members and p.b in members and p.F is not None and strong_edge(p, params)]
    if not inside:
        return None, {c: "no camera pair of its group has enough matches" for c in members}
    result, failed, keys = _reconstruct(obs, members, inside, group_id, params, {}, unknown)
    # Our addition: the gates are tuned for keypoints whose views agree to ~1 px. Real pose
    # keypoints disagree between views by 3-5 px per class (view-dependent errors that the
    # temporal noise scale does not see), and the 6 px gate then keeps only the views that
    # agree with the first poses. Once the robust rounds have measured each class, the group
    # is reconstructed again with the incremental registration's gate of the noisier classes
    # widened in proportion (the rounds' wider gate stays: widened too, caliscope got worse).
    # The wider gate also lets outliers in: the new poses are kept only if they register as
    # many cameras and explain the first reconstruction's own points nearly as well.
    scales = geometric_gate_scales(result.sigma_px_by_id, params) if result is not None else {}
    if params.geometric_gates and scales:
        again, failed_again, _ = _reconstruct(obs, members, inside, group_id, params, scales, unknown)
        if again is not None and len(again.names) >= len(result.names):
            before, after = agreement_px(obs, keys, result), agreement_px(obs, keys, again)
            if after <= params.max_agreement_ratio * before:
                result, failed = again, failed_again
                result.gate_scales = scales
    return result, failed


def agreement_px(obs: GridObservations, keys: np.ndarray, result: CameraGroupResult) -> float:
    """Median reprojection residual (px) of the agent points `keys`, each triangulated from
    its views among the group's cameras with the group's poses: how well the poses explain
    those points, in any gauge (raw pixels of estimated cameras through the group's estimates)."""
    obs = with_estimates(obs, result)
    poses = {obs.names.index(n): T for n, T in result.T_local_cam.items()}
    residuals = []
    for key in keys:
        views = [c for c in poses if key in obs.per_camera[c]]
        if len(views) < 2:
            continue
        cams, Ts = [obs.cameras[c] for c in views], [poses[c] for c in views]
        uvs = [obs.per_camera[c][key] for c in views]
        X = triangulate(cams, Ts, uvs)
        if np.isfinite(X).all():
            residuals += view_residuals_px(X, cams, Ts, uvs)
    return float(np.median(residuals)) if residuals else float("inf")


def _reconstruct(
    obs: GridObservations,
    members: list[int],
    inside: list[PairGeometry],
    group_id: str,
    params: SfmParams,
    id_gate_scale: dict[int, float],
    unknown: frozenset[int] = frozenset(),
) -> tuple[CameraGroupResult | None, dict[int, str], np.ndarray]:
    """One incremental reconstruction and its robust rounds: the group, the reasons of the
    cameras left out, and the keys of the agent points in its final bundle adjustment."""
    # A pair of known intrinsics first: its relative pose needs no focal estimate.
    ranked = sorted(
        inside,
        key=lambda p: (-len({p.a, p.b} & unknown), match_score(p) if params.overlap_ordering else p.num_inliers),
        reverse=True,
    )
    for init in ranked:
        sfm = IncrementalSfm(obs, members, params, id_gate_scale, unknown)
        sfm.initialise(init)
        # A wrong decomposition triangulates few of the pair's inliers in front of both
        # cameras: then try the next pair (paper: geometric verification of the solution).
        if len(sfm.points) >= params.min_init_fraction * init.num_inliers:
            break
    while (c := sfm.next_camera()) is not None:
        sfm.register(c)
    for c in members:
        if c not in sfm.poses and c not in sfm.failed:
            sfm.failed[c] = f"sees fewer than {params.min_pnp} of the group's triangulated agent points"
    if len(sfm.points) < params.min_pnp:
        return (
            None,
            {c: f"the initial pair triangulated only {len(sfm.points)} agent points" for c in members},
            np.zeros(0, np.int64),
        )
    # Robust BA rounds; after each, every keypoint class's sigma from its residuals (variance
    # component estimation).
    sigma_by_id: dict[int, float] = {}
    for round_ in range(max(params.sigma_rounds, 2) if params.class_sigma else 1):
        if round_:
            # Points rejected under the pre-BA poses get a second chance, at the wider gate.
            sfm.triangulate_new(params.rounds_reproj_px)
        ba = sfm.bundle_adjust(init.a, init.b, sigma_by_id)
        previous, sigma_by_id = sigma_by_id, residual_sigmas(ba, params.sigma_class_bounds)
        if previous and all(abs(sigma_by_id.get(i, v) / v - 1) <= params.sigma_tolerance for i, v in previous.items()):
            break
    res, o = ba["residuals"], ba["obs"]
    names = [obs.names[c] for c in ba["cams"]]
    rmse, counts = {}, {}
    for i, c in enumerate(ba["cams"]):
        r = res[o.camera == i]
        r = r[np.isfinite(r).all(axis=1)]
        rmse[obs.names[c]] = float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")
        counts[obs.names[c]] = int(len(r))
    stamps, ids = obs.stamp_and_id(ba["keys"])
    result = CameraGroupResult(
        group_id,
        obs.names[init.a],
        names,
        {obs.names[c]: sfm.poses[c] for c in ba["cams"]},
        stamps,
        ids,
        np.array([sfm.points[int(k)] for k in ba["keys"]]),
        rmse,
        counts,
        sigma_by_id,
        (obs.names[init.a], obs.names[init.b]),
        {obs.names[c]: m for c, m in sfm.estimated.items() if c in sfm.poses},
    )
    return result, sfm.failed, ba["keys"]


def calibrate_groups(
    cams: list[CameraTracks],
    params: SfmParams = SfmParams(),
    clock_components: dict[str, str] | None = None,
    estimate: frozenset[str] = frozenset(),
) -> GroupingResult:
    """All CMCs -> groups with relative poses + local agent tracks, and the rest with reasons.
    `clock_components`: camera -> the reference of its clock (yowo_cmc.clock); two cameras
    on different clocks whose offset is unknown are not matched (their stamps do not
    relate: a room walked after another would pair the end of one with the start of the
    other). `estimate`: the cameras whose intrinsics are unknown (their CameraTracks carry a
    nominal model of the right image size): the group SfM estimates them."""
    if not cams:
        return GroupingResult([], {}, [])
    obs = sample_on_grid(cams, params.tracks)
    clocks = clock_components or {}

    def related(a: int, b: int) -> bool:
        ca, cb = clocks.get(obs.names[a]), clocks.get(obs.names[b])
        return ca is None or cb is None or ca == cb

    pairs = [
        pair_geometry(obs, a, b, params)
        if related(a, b)
        else PairGeometry(a, b, None, np.zeros(0, np.int64), np.zeros(0, bool))
        for a in range(len(cams))
        for b in range(a + 1, len(cams))
    ]
    groups, reasons = group_cameras(obs, pairs, params)
    results = []
    for members in groups:
        unknown = frozenset(c for c in members if obs.names[c] in estimate)
        if unknown == frozenset(members):
            # No member's focal length is known: nothing fixes the group's (measured: 40-60 % off with
            # sigmas of a third of the focal length on a camera pair), so none is calibrated.
            reasons.update(
                {
                    c: "no camera of its group has known intrinsics (CameraInfo or --intrinsics), so "
                    "their focal lengths are not determined; give one of them an intrinsics file"
                    for c in members
                }
            )
            continue
        result, failed = reconstruct_group(obs, members, pairs, f"g{len(results)}", params, unknown)
        reasons.update(failed)
        if result is not None and len(result.names) >= 2:
            result.cameras = {c.name: result.cameras.get(c.name, c.camera) for c in cams if c.name in result.names}
            results.append(result)
        elif result is not None:
            reasons.update(
                {obs.names.index(n): "its group fell apart (too few registered cameras)" for n in result.names}
            )
    return GroupingResult(results, {obs.names[c]: r for c, r in sorted(reasons.items())}, pairs)
