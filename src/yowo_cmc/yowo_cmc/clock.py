"""Clock offsets of unsynchronised CMCs from the agent's motion alone.

Two cameras that watch the walking agent see the same 3D keypoint at the same instant
only when their stamps are shifted by the offset between their clocks: at any other
shift the correspondences (camera A's sample at t, camera B's track at t + delta) break
the epipolar constraint in proportion to the agent's image speed. Per co-observing pair:
a coarse search over +-max_offset_s (essential matrix by USAC at each shift, truncated
Sampson cost over every correspondence; coarse to fine: a cheap fit every frame or so,
the full one on the half-frame grid around the best few of those), then one least-squares fit of the relative pose
and the shift together (sub-frame), its sigma from the fit's curvature. Globally: the
pair offsets over the co-visibility graph by weighted least squares, one reference
camera per connected component, inconsistent pair estimates dropped one by one."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import networkx as nx
import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_coeffs
from scipy.spatial.transform import Rotation

from yowo_common.bundle import robust_sigma

from .group_sfm import RANSAC_SEED, CameraGroupResult, SfmParams, sampson_px, spread_subset
from .keypoint_tracks import CameraTracks, _window, clean_track, noise_scale, track_splines, undistort_tracks
from .params import ClockParams


@dataclass
class PairOffset:
    a: str
    b: str
    offset_s: float | None  # clock of b - clock of a (b's stamp of an instant = a's + this)
    sigma_s: float | None
    correspondences: int  # samples in the refinement (0: not refined)
    rms_px: float | None  # Sampson error at the solution, robust (MAD) sigma
    used: bool = False  # in the global solution
    reason: str = ""  # why not usable / dropped ('' when used)


@dataclass
class CameraClock:
    name: str
    offset_s: float | None  # this camera's clock - the reference camera's
    sigma_s: float | None
    reference: str | None  # the camera of its component whose offset is fixed at 0
    reason: str = ""  # why there is no estimate


@dataclass
class ClockEstimate:
    cameras: dict[str, CameraClock]
    pairs: list[PairOffset] = field(default_factory=list)


class _Tracks:
    """One camera's cleaned, undistorted keypoint tracks as cubic splines per segment,
    on a float time axis [s] from a common origin."""

    def __init__(self, cam: CameraTracks, origin_ns: int, sfm: SfmParams):
        self.name, self.period_s = cam.name, cam.frame_period_ns / 1e9
        self.scale = noise_scale(cam, sfm.tracks)
        cleaned = CameraTracks(
            cam.name,
            cam.camera,
            {i: clean_track(t, cam.frame_period_ns, sfm.tracks, self.scale) for i, t in cam.tracks.items()},
            cam.frame_period_ns,
        )
        ideal = undistort_tracks(cleaned)
        self.camera = ideal.camera
        max_gap = int(sfm.tracks.gap_factor * cam.frame_period_ns)
        self.samples: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.splines: dict[int, list] = {}
        for i, t in ideal.tracks.items():
            if len(t) == 0:
                continue
            self.samples[i] = ((t.stamps_ns - origin_ns) / 1e9, t.uv)
            self.splines[i] = track_splines(t, max_gap, origin_ns)
        window = _window(cam.frame_period_ns, sfm.tracks)
        self.correlation = 1.0 / savgol_coeffs(window, sfm.tracks.polyorder)[window // 2]

    def times(self) -> np.ndarray:
        return np.concatenate([ts for ts, _ in self.samples.values()]) if self.samples else np.zeros(0)

    def at(self, kp_id: int, t: np.ndarray, within: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(uv, valid, segment index) at times t; valid where [t - within, t + within]
        lies inside one segment (no extrapolation, no bridging of gaps)."""
        uv, seg = np.full((len(t), 2), np.nan), np.full(len(t), -1)
        for k, (t0, t1, spline) in enumerate(self.splines.get(kp_id, [])):
            inside = (t - within >= t0) & (t + within <= t1)
            if inside.any():
                uv[inside] = spline(t[inside])
                seg[inside] = k
        return uv, seg >= 0, seg


def _fundamental(E: np.ndarray, Ka: np.ndarray, Kb: np.ndarray) -> np.ndarray:
    return np.linalg.inv(Kb).T @ E @ np.linalg.inv(Ka)


def _normalised(uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    return (uv - K[:2, 2]) / np.diag(K)[:2]


class _Pair:
    """Correspondences of camera a's samples with camera b's tracks at a shift delta."""

    def __init__(self, a: _Tracks, b: _Tracks):
        self.a, self.b = a, b
        self.ids = sorted(set(a.samples) & set(b.splines))
        self.ta = np.concatenate([a.samples[i][0] for i in self.ids]) if self.ids else np.zeros(0)
        self.uva = np.concatenate([a.samples[i][1] for i in self.ids]) if self.ids else np.zeros((0, 2))
        self.id_of = (
            np.concatenate([np.full(len(a.samples[i][0]), i) for i in self.ids]) if self.ids else np.zeros(0, int)
        )

    def b_at(self, delta: float, within: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        uv, ok, seg = np.full((len(self.ta), 2), np.nan), np.zeros(len(self.ta), bool), np.full(len(self.ta), -1)
        for i in self.ids:
            m = self.id_of == i
            uv[m], ok[m], seg[m] = self.b.at(i, self.ta[m] + delta, within)
        return uv, ok, seg


def _coarse_cost(
    pair: _Pair, delta: float, params: ClockParams, sfm: SfmParams, thr_px: float
) -> tuple[float, np.ndarray | None]:
    """(truncated squared Sampson error / threshold^2, essential matrix) at one shift,
    averaged over all of camera a's samples: one without a counterpart in b at this shift
    costs as much as an outlier. (A mean over the co-visible samples alone favours shifts
    where few remain: 40 samples of a short stretch fit some essential matrix well.)"""
    uvb, ok, _ = pair.b_at(delta)
    if ok.sum() < params.min_correspondences:
        return np.inf, None
    pa, pb = pair.uva[ok], uvb[ok]
    Ka, Kb = pair.a.camera.K, pair.b.camera.K
    sub = spread_subset(pa, pair.a.camera, sfm)
    sub = sub[np.linspace(0, len(sub) - 1, min(len(sub), params.coarse_points)).astype(int)]
    if len(sub) < 8:
        return np.inf, None
    focal = 0.25 * (Ka[0, 0] + Ka[1, 1] + Kb[0, 0] + Kb[1, 1])
    cv2.setRNGSeed(RANSAC_SEED)
    try:
        E, _ = cv2.findEssentialMat(
            _normalised(pa[sub], Ka),
            _normalised(pb[sub], Kb),
            np.eye(3),
            cv2.USAC_DEFAULT,
            0.999,
            thr_px / focal,
            params.coarse_iterations,
        )
    except cv2.error:  # degenerate configurations make USAC assert
        return np.inf, None
    if E is None or E.shape[0] < 3:
        return np.inf, None
    best = (np.inf, None)
    for k in range(E.shape[0] // 3):  # the 5-point solver may return several
        e = sampson_px(_fundamental(E[3 * k : 3 * k + 3], Ka, Kb), pa, pb)
        cost = (float(np.sum(np.minimum(e, thr_px) ** 2)) + (len(ok) - len(e)) * thr_px**2) / (len(ok) * thr_px**2)
        best = min(best, (cost, E[3 * k : 3 * k + 3]), key=lambda c: c[0])
    return best


def _search_every(params: ClockParams) -> int:
    """The search step in steps of the coarse grid."""
    return max(1, round(params.search_step_frames / params.coarse_step_frames))


def _cheap_curve(
    pair: _Pair, grid: np.ndarray, params: ClockParams, sfm: SfmParams, thr_px: float
) -> tuple[np.ndarray, np.ndarray]:
    """(indices into the grid, cost there): the cheap fit every search step."""
    every = _search_every(params)
    cheap = replace(params, coarse_iterations=params.search_iterations, coarse_points=params.search_points)
    coarse = np.arange(0, len(grid), every)
    return coarse, np.array([_coarse_cost(pair, grid[k], cheap, sfm, thr_px)[0] for k in coarse])


def _fine_shifts(coarse: np.ndarray, cost: np.ndarray, grid_size: int, params: ClockParams) -> list[int]:
    """Indices into the coarse grid where the full cost is worth evaluating: within one
    search step of the search_candidates best shifts of the cheap curve."""
    every = _search_every(params)
    picked: list[int] = []
    for r in np.argsort(cost, kind="stable"):
        if not np.isfinite(cost[r]) or len(picked) == params.search_candidates:
            break
        if all(abs(coarse[r] - j) > every for j in picked):
            picked.append(int(coarse[r]))
    return sorted({j for k in picked for j in range(max(0, k - every), min(grid_size, k + every + 1))})


def prominence(cost: np.ndarray) -> float:
    """How far the cost curve's minimum lies below its median, in units of the curve's
    own shift-to-shift noise (robust sigma of its successive differences / sqrt 2). A
    curve with no true minimum (an agent that barely moves, keypoints noisier than the
    motion between shifts) still has a lowest point; pure noise over ~150 shifts dips
    about 3 noise levels below its median."""
    c = cost[np.isfinite(cost)]
    if len(c) < 5:
        return float("nan")
    noise = robust_sigma(np.diff(c)[:, None]) / np.sqrt(2.0)
    return float((np.median(c) - c.min()) / max(noise, 1e-12))


def _signed_sampson(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    xa = np.column_stack([pa, np.ones(len(pa))])
    xb = np.column_stack([pb, np.ones(len(pb))])
    Fa, Ftb = xa @ F.T, xb @ F
    return np.sum(xb * Fa, axis=1) / np.sqrt(Fa[:, 0] ** 2 + Fa[:, 1] ** 2 + Ftb[:, 0] ** 2 + Ftb[:, 1] ** 2 + 1e-300)


def _refine(
    pair: _Pair, delta0: float, E0: np.ndarray, step: float, params: ClockParams, thr_px: float, huber_px: float
) -> tuple[float, float, int, float] | str:
    """Relative pose and shift by one robust least-squares fit from the coarse minimum:
    (offset, sigma, correspondences, rms px), or why it failed."""
    # Correspondences that stay inside one segment of b over the whole search interval,
    # and are inliers of the coarse fit: a fixed residual vector for the optimiser.
    uvb, ok, seg = pair.b_at(delta0, within=step)
    Ka, Kb = pair.a.camera.K, pair.b.camera.K
    ok[ok] = sampson_px(_fundamental(E0, Ka, Kb), pair.uva[ok], uvb[ok]) <= thr_px
    if ok.sum() < params.min_correspondences:
        return f"{int(ok.sum())} inlier correspondences around the best shift (needs {params.min_correspondences})"
    ta, pa, ids = pair.ta[ok], pair.uva[ok], pair.id_of[ok]
    seg = seg[ok]
    groups = [
        (np.flatnonzero((ids == i) & (seg == k)), pair.b.splines[i][k][2])
        for i in pair.ids
        for k in np.unique(seg[ids == i])
    ]

    def b_points(delta: float) -> np.ndarray:
        pb = np.empty((len(ta), 2))
        for idx, spline in groups:
            pb[idx] = spline(ta[idx] + delta)
        return pb

    R0, _, t0 = cv2.decomposeEssentialMat(E0)  # any of the four: all give the same E up to sign
    t0 = t0.ravel() / np.linalg.norm(t0)
    e1 = np.cross(t0, [1.0, 0, 0] if abs(t0[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t0, e1)

    def residuals(x: np.ndarray) -> np.ndarray:
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        t = t0 + x[3] * e1 + x[4] * e2
        t /= np.linalg.norm(t)
        tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        return _signed_sampson(_fundamental(tx @ R, Ka, Kb), pa, b_points(x[5]))

    lo = np.r_[np.full(5, -np.inf), delta0 - step]
    hi = np.r_[np.full(5, np.inf), delta0 + step]
    fit = least_squares(
        residuals,
        np.r_[np.zeros(5), delta0],
        bounds=(lo, hi),
        loss="huber",
        f_scale=huber_px,
        x_scale="jac",
        method="trf",
    )
    delta = float(fit.x[5])
    if min(delta - lo[5], hi[5] - delta) < 1e-3 * step:
        return f"the refined shift {delta:+.3f} s ran to the edge of its interval (no clear minimum)"
    rms = robust_sigma(fit.fun[:, None])
    inlier = np.abs(fit.fun) <= 3 * max(rms, 1e-12)
    J = fit.jac[inlier]
    try:
        cov = np.linalg.inv(J.T @ J) * max(rms, 1e-12) ** 2
    except np.linalg.LinAlgError:
        return "the shift is not observable (singular fit)"
    corr = max(pair.a.correlation, pair.b.correlation) if params.correlated_sigma else 1.0
    sigma = float(np.sqrt(max(cov[5, 5], 0.0) * corr))
    return delta, max(sigma, params.min_sigma_s), int(ok.sum()), float(rms)


def estimate_pair(a: _Tracks, b: _Tracks, params: ClockParams, sfm: SfmParams) -> PairOffset:
    """Offset of b's clock from a's: coarse search, then the sub-frame refinement."""
    pair = _Pair(a, b)
    scale = max(a.scale, b.scale)
    thr = params.truncate_px * scale
    step = params.coarse_step_frames * min(a.period_s, b.period_s)
    grid = np.arange(-params.max_offset_s, params.max_offset_s + 0.5 * step, step)
    costs = [(np.inf, None)] * len(grid)
    coarse, cheap = _cheap_curve(pair, grid, params, sfm, thr)
    for k in _fine_shifts(coarse, cheap, len(grid), params) if params.search_candidates > 0 else range(len(grid)):
        costs[k] = _coarse_cost(pair, grid[k], params, sfm, thr)
    best = int(np.argmin([c for c, _ in costs]))
    if not np.isfinite(costs[best][0]):
        return PairOffset(
            a.name,
            b.name,
            None,
            None,
            0,
            None,
            reason=f"fewer than {params.min_correspondences} co-visible samples at every shift",
        )
    dip = prominence(cheap)  # the cheap curve: evenly spaced, whatever the search evaluates in full
    if not dip >= params.min_prominence:
        return PairOffset(
            a.name,
            b.name,
            None,
            None,
            0,
            None,
            reason=f"no clear minimum over the shifts (the best, {grid[best]:+.3f} s, is {dip:.1f} noise "
            f"levels below the median cost; needs {params.min_prominence:g})",
        )
    if best in (0, len(grid) - 1):
        return PairOffset(
            a.name,
            b.name,
            None,
            None,
            0,
            None,
            reason=f"the best shift is at the edge of the search range (+-{params.max_offset_s:g} s): "
            "the offset may lie beyond it",
        )
    refined = _refine(pair, float(grid[best]), costs[best][1], step, params, thr, params.huber_px * scale)
    if isinstance(refined, str):
        return PairOffset(a.name, b.name, None, None, 0, None, reason=refined)
    delta, sigma, n, rms = refined
    out = PairOffset(a.name, b.name, delta, sigma, n, rms)
    if sigma > params.max_pair_sigma_s:
        out.reason = f"sigma {sigma * 1e3:.1f} ms > {params.max_pair_sigma_s * 1e3:.0f} ms (too little motion)"
    return out


def covisible_pairs(cams: list[_Tracks], params: ClockParams) -> list[tuple[int, int]]:
    """Camera pairs where one sees the agent at least min_correspondences times within
    +-max_offset_s of when the other sees it: the only ones worth a search."""
    bin_s = 0.5
    pad = int(np.ceil(params.max_offset_s / bin_s))
    bins = [np.unique(np.floor(c.times() / bin_s).astype(int)) for c in cams]
    dilated = [np.unique((b[:, None] + np.arange(-pad, pad + 1)).ravel()) for b in bins]
    out = []
    for i in range(len(cams)):
        ti = np.floor(cams[i].times() / bin_s).astype(int)
        for j in range(i + 1, len(cams)):
            if np.isin(ti, dilated[j]).sum() >= params.min_correspondences:
                out.append((i, j))
    return out


def _drop_lone_bridges(usable: list[PairOffset]) -> None:
    """Remove (with the reason) each pair that alone joins two sets of two or more cameras."""
    G = nx.Graph((p.a, p.b) for p in usable)
    for a, b in list(nx.bridges(G)):
        H = G.copy()
        H.remove_edge(a, b)
        sizes = len(nx.node_connected_component(H, a)), len(nx.node_connected_component(H, b))
        if min(sizes) >= 2:
            p = next(p for p in usable if {p.a, p.b} == {a, b})
            p.reason = (
                f"the only pair joining {sizes[0]} cameras to {sizes[1]} others (needs two paths, as in the group SfM)"
            )
            usable.remove(p)


def combine(names: list[str], pairs: list[PairOffset], params: ClockParams) -> dict[str, CameraClock]:
    """One offset per camera from the usable pair offsets: weighted least squares per
    connected component (its first camera fixed at 0); while a pair is more than
    max_residual_sigma (and min_residual_s) off the solution, the worst is dropped.
    A single pair that is all that joins two sets of cameras is not used (as the group
    SfM will not join them through one camera pair): a stretch of walk seen by cameras of
    two rooms one after the other fits some shift well enough, at a few dozen samples."""
    index = {n: k for k, n in enumerate(names)}
    usable = [p for p in pairs if p.offset_s is not None and not p.reason]
    out: dict[str, CameraClock] = {}
    while True:
        _drop_lone_bridges(usable)
        G = nx.Graph()
        G.add_nodes_from(range(len(names)))
        G.add_edges_from((index[p.a], index[p.b]) for p in usable)
        solution, worst = {}, None
        for comp in nx.connected_components(G):
            members = sorted(comp)
            if len(members) < 2:
                continue
            ref, col = members[0], {c: k for k, c in enumerate(members[1:])}
            edges = [p for p in usable if index[p.a] in comp]
            A = np.zeros((len(edges), len(col)))
            for r, p in enumerate(edges):
                if index[p.b] in col:
                    A[r, col[index[p.b]]] += 1.0
                if index[p.a] in col:
                    A[r, col[index[p.a]]] -= 1.0
            w = 1.0 / np.array([p.sigma_s for p in edges])
            y = np.array([p.offset_s for p in edges])
            x = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
            res = (y - A @ x) * w
            dof = len(edges) - len(col)
            # Pair sigmas are approximate: scale them by the observed scatter when it is larger.
            inflate = max(1.0, float(np.sqrt(res @ res / dof))) if dof > 0 else 1.0
            cov = np.linalg.inv((A * w[:, None]).T @ (A * w[:, None])) * inflate**2
            solution[ref] = (0.0, 0.0, ref)
            for c, k in col.items():
                solution[c] = (float(x[k]), float(np.sqrt(cov[k, k])), ref)
            off = np.abs(res) > params.max_residual_sigma
            off &= np.abs(y - A @ x) > params.min_residual_s
            if off.any():
                k = int(np.argmax(np.where(off, np.abs(res), -1.0)))
                if worst is None or abs(res[k]) > worst[1]:
                    worst = (edges[k], abs(res[k]), float((y - A @ x)[k]))
        if worst is None:
            break
        p, nsig, miss = worst
        p.reason = f"inconsistent with the other pairs: {miss * 1e3:+.1f} ms off ({nsig:.1f} sigma)"
        usable.remove(p)
    for p in usable:
        p.used = True
    for k, n in enumerate(names):
        if k in solution:
            off, sig, ref = solution[k]
            out[n] = CameraClock(n, off, sig, names[ref])
            continue
        mine = [p for p in pairs if n in (p.a, p.b)]
        if not mine:
            reason = (
                f"sees the agent at no time another camera does (within +-{params.max_offset_s:g} s): "
                "no pair to compare with"
            )
        else:
            reason = "no usable camera pair: " + "; ".join(
                f"with '{p.b if p.a == n else p.a}': {p.reason}" for p in mine
            )
        out[n] = CameraClock(n, None, None, None, reason)
    return out


def estimate_clock_offsets(
    tracks: list[CameraTracks], params: ClockParams = ClockParams(), sfm: SfmParams = SfmParams()
) -> ClockEstimate:
    """Each camera's clock offset from the reference camera of its co-visibility
    component (raw-pixel tracks on each camera's own clock; `sfm` gives the track
    cleaning and the spatial spread of the RANSAC subsets, as the group SfM uses them)."""
    stamps = [t.stamps_ns.min() for c in tracks for t in c.tracks.values() if len(t)]
    origin = int(min(stamps)) if stamps else 0
    cams = [_Tracks(c, origin, sfm) for c in tracks]
    pairs = [estimate_pair(cams[i], cams[j], params, sfm) for i, j in covisible_pairs(cams, params)]
    return ClockEstimate(combine([c.name for c in tracks], pairs, params), pairs)


def attach_to_groups(groups, estimate: ClockEstimate) -> None:
    """Each group's members' clock offsets relative to the group's reference camera
    (`clock_offsets_s`, `clock_sigmas_s`), where both are estimated on one reference."""
    for g in groups:
        ref = estimate.cameras.get(g.reference)
        if ref is None or ref.offset_s is None:
            continue
        for n in g.names:
            c = estimate.cameras.get(n)
            if c is not None and c.offset_s is not None and c.reference == ref.reference:
                g.clock_offsets_s[n] = c.offset_s - ref.offset_s
                g.clock_sigmas_s[n] = float(np.hypot(c.sigma_s or 0.0, ref.sigma_s or 0.0)) if n != g.reference else 0.0


def triangulate_weighted(
    P: np.ndarray,
    cam_i: np.ndarray,
    pt_i: np.ndarray,
    uv: np.ndarray,
    weight: np.ndarray,
    n_points: int,
    iterations: int = 2,
) -> np.ndarray:
    """Every point from its observations at once: linear (DLT) then Gauss-Newton steps on
    the weighted reprojection error. P: (C, 3, 4) projection matrices."""
    Pc = P[cam_i]
    rows = (
        np.concatenate([uv[:, :1] * Pc[:, 2] - Pc[:, 0], uv[:, 1:] * Pc[:, 2] - Pc[:, 1]])
        * np.r_[weight, weight][:, None]
    )
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    M = np.zeros((n_points, 4, 4))
    np.add.at(M, np.r_[pt_i, pt_i], rows[:, :, None] * rows[:, None, :])
    X = np.linalg.eigh(M)[1][:, :, 0]
    X = X[:, :3] / np.where(np.abs(X[:, 3:]) > 1e-12, X[:, 3:], 1e-12)
    for _ in range(iterations):
        h = np.einsum("nij,nj->ni", Pc[:, :, :3], X[pt_i]) + Pc[:, :, 3]
        r = (h[:, :2] / h[:, 2:] - uv) * weight[:, None]
        J = (Pc[:, :2, :3] - (h[:, :2] / h[:, 2:])[:, :, None] * Pc[:, 2:, :3]) / h[:, 2:, None] * weight[:, None, None]
        H, g = np.zeros((n_points, 3, 3)), np.zeros((n_points, 3))
        np.add.at(H, pt_i, np.einsum("nki,nkj->nij", J, J))
        np.add.at(g, pt_i, np.einsum("nki,nk->ni", J, r))
        X = X - np.linalg.solve(H + 1e-9 * np.eye(3), g[:, :, None])[:, :, 0]
    return X


def refine_group_offsets(
    group: CameraGroupResult, tracks: dict[str, CameraTracks], params: ClockParams, sfm: SfmParams
) -> dict[str, tuple[float, float]]:
    """Corrections to the members' clocks, each against the group's reference camera: one
    robust least-squares fit of every member's pose and correction, the agent points
    triangulated anew at every step (variable projection), each member's observation of
    a point taken from its track at the point's time plus its correction (second-order
    Taylor expansion of the track's spline). `tracks`: the members' tracks on the clock of
    the group's points. Returns name -> (correction [s], sigma [s]) for the members it
    could refine (the reference's correction is 0 by definition); the sigma is the
    correction's marginal, scaled like the pairs' for the smoothed tracks."""
    members = [n for n in group.names if n in tracks]
    if group.reference not in members or len(group.point_stamps_ns) == 0:
        return {}
    origin = int(group.point_stamps_ns.min())
    t_pts = (group.point_stamps_ns - origin) / 1e9
    cams = [_Tracks(tracks[n], origin, sfm) for n in members]
    w = params.refine_range_s
    cam_i, pt_i, uv0, uv1, uv2 = [], [], [], [], []
    for ci, c in enumerate(cams):
        for i in np.unique(group.point_ids):
            sel = np.flatnonzero(group.point_ids == i)
            for t0, t1, spline in c.splines.get(int(i), []):
                inside = sel[(t_pts[sel] - w >= t0) & (t_pts[sel] + w <= t1)]
                if len(inside):
                    cam_i.append(np.full(len(inside), ci))
                    pt_i.append(inside)
                    uv0 += [spline(t_pts[inside])]
                    uv1 += [spline(t_pts[inside], 1)]
                    uv2 += [spline(t_pts[inside], 2)]
    if not cam_i:
        return {}
    cam_i, pt_i = np.concatenate(cam_i), np.concatenate(pt_i)
    uv0, uv1, uv2 = np.vstack(uv0), np.vstack(uv1), np.vstack(uv2)
    # Points seen by two members at least, evenly thinned over time (deterministic).
    pts = np.flatnonzero(np.bincount(pt_i, minlength=len(t_pts)) >= 2)
    pts = pts[np.argsort(t_pts[pts], kind="stable")]
    pts = pts[np.linspace(0, len(pts) - 1, min(len(pts), params.refine_max_points)).astype(int)] if len(pts) else pts
    keep = np.isin(pt_i, pts)
    cam_i, uv0, uv1, uv2 = cam_i[keep], uv0[keep], uv1[keep], uv2[keep]
    pt_i = np.searchsorted(pts, pt_i[keep])
    ref = members.index(group.reference)
    free = [k for k in range(len(members)) if k != ref]
    if len(pts) < sfm.min_pnp or any(np.sum(cam_i == k) < params.refine_min_observations for k in free):
        return {}
    weight = (
        1.0 / np.array([group.sigma_px_by_id.get(int(i), sfm.initial_sigma_px) for i in group.point_ids[pts]])[pt_i]
    )
    K = np.array([c.camera.K for c in cams])
    T0 = [np.linalg.inv(group.T_local_cam[n]) for n in members]  # T_cam_local
    second = members.index(group.initial_pair[1]) if group.initial_pair[1] in members else free[0]
    baseline = float(np.linalg.norm(group.T_local_cam[members[second]][:3, 3] - group.T_local_cam[members[ref]][:3, 3]))

    def unpack(x):
        T, d = [t.copy() for t in T0], np.zeros(len(members))
        for j, k in enumerate(free):
            T[k][:3, :3] = Rotation.from_rotvec(x[7 * j : 7 * j + 3]).as_matrix() @ T0[k][:3, :3]
            T[k][:3, 3] = T0[k][:3, 3] + x[7 * j + 3 : 7 * j + 6]
            d[k] = x[7 * j + 6]
        return T, d

    def residuals(x):
        T, d = unpack(x)
        P = np.einsum("cij,cjk->cik", K, np.array(T)[:, :3, :])
        dc = d[cam_i][:, None]
        target = uv0 + dc * uv1 + 0.5 * dc**2 * uv2
        X = triangulate_weighted(P, cam_i, pt_i, target, weight, len(pts))
        h = np.einsum("nij,nj->ni", P[cam_i][:, :, :3], X[pt_i]) + P[cam_i][:, :, 3]
        r = (h[:, :2] / h[:, 2:] - target) * weight[:, None]
        centres = [-T[k][:3, :3].T @ T[k][:3, 3] for k in (second, ref)]
        # The scale gauge: the initial pair's baseline stays as the group SfM fixed it.
        gauge = (np.linalg.norm(centres[0] - centres[1]) - baseline) / (1e-4 * baseline)
        return np.concatenate([r.ravel(), [gauge]])

    x0 = np.zeros(7 * len(free))
    lo, hi = np.full(len(x0), -np.inf), np.full(len(x0), np.inf)
    lo[6::7], hi[6::7] = -w, w
    fit = least_squares(residuals, x0, bounds=(lo, hi), loss="huber", f_scale=1.345, x_scale="jac", method="trf")
    # The residuals' spread understates the noise by the unknowns fitted to them: each point's
    # 3 coordinates (a point seen twice keeps 1 of its 4 residual dof) and the members' 7.
    # Uncorrected, the sigmas were ~2.8x optimistic on the simulator's recordings.
    n_res = 2 * len(cam_i)
    dof = max(n_res - 3 * len(pts) - len(x0), 1)
    scale = robust_sigma(fit.fun[:-1].reshape(-1, 2)) ** 2 * n_res / dof
    corr = max(c.correlation for c in cams) if params.correlated_sigma else 1.0
    try:
        cov = np.linalg.inv(fit.jac.T @ fit.jac) * scale * corr
    except np.linalg.LinAlgError:
        return {}
    out = {}
    for j, k in enumerate(free):
        delta = float(fit.x[7 * j + 6])
        if min(delta + w, w - delta) < 1e-3 * w:
            continue  # ran to the edge of its range: no clear minimum, keep the pairs' estimate
        out[members[k]] = (delta, max(float(np.sqrt(max(cov[7 * j + 6, 7 * j + 6], 0.0))), params.min_sigma_s))
    return out
