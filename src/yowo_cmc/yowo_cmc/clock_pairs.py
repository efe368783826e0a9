"""One camera pair's clock offset from the agent's motion (yowo_cmc.clock): camera a's
samples against camera b's spline tracks shifted by a trial offset, a coarse search
over +-max_offset_s (essential matrix by USAC at each shift, truncated Sampson cost over
every correspondence; coarse to fine: a cheap fit every frame or so, the full one on the
half-frame grid around the best few of those), then one least-squares fit of the
relative pose and the shift together (sub-frame), its sigma from the fit's curvature."""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_coeffs
from scipy.spatial.transform import Rotation

from yowo_common.bundle import robust_sigma

from .keypoint_tracks import CameraTracks, _window, clean_track, noise_scale, track_splines, undistort_tracks
from .params import ClockParams, SfmParams
from .scene_graph import RANSAC_SEED, sampson_px, signed_sampson_px, spread_subset


@dataclass(kw_only=True)
class PairOffset:
    a: str
    b: str
    offset_s: float | None  # clock of b - clock of a (b's stamp of an instant = a's + this)
    sigma_s: float | None
    correspondences: int  # samples in the refinement (0: not refined)
    rms_px: float | None  # Sampson error at the solution, robust (MAD) sigma
    used: bool = False  # in the global solution
    reason: str = ""  # why not usable / dropped ('' when used)


class SplineTracks:
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

    def __init__(self, a: SplineTracks, b: SplineTracks):
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


def _essential_model(E0: np.ndarray):
    """x -> E: the relative pose of E0 with x[:3] a rotation vector applied to its rotation
    and x[3:5] its unit translation moved in the tangent plane (5 degrees of freedom)."""
    R0, _, t0 = cv2.decomposeEssentialMat(E0)  # any of the four: all give the same E up to sign
    t0 = t0.ravel() / np.linalg.norm(t0)
    e1 = np.cross(t0, [1.0, 0, 0] if abs(t0[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(t0, e1)

    def essential(x: np.ndarray) -> np.ndarray:
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        t = t0 + x[3] * e1 + x[4] * e2
        t /= np.linalg.norm(t)
        tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        return tx @ R

    return essential


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

    essential = _essential_model(E0)

    def residuals(x: np.ndarray) -> np.ndarray:
        return signed_sampson_px(_fundamental(essential(x), Ka, Kb), pa, b_points(x[5]))

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


def estimate_pair(a: SplineTracks, b: SplineTracks, params: ClockParams, sfm: SfmParams) -> PairOffset:
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
        return _no_offset(a, b, f"fewer than {params.min_correspondences} co-visible samples at every shift")
    dip = prominence(cheap)  # the cheap curve: evenly spaced, whatever the search evaluates in full
    if not dip >= params.min_prominence:
        return _no_offset(
            a,
            b,
            f"no clear minimum over the shifts (the best, {grid[best]:+.3f} s, is {dip:.1f} noise "
            f"levels below the median cost; needs {params.min_prominence:g})",
        )
    if best in (0, len(grid) - 1):
        return _no_offset(
            a,
            b,
            f"the best shift is at the edge of the search range (+-{params.max_offset_s:g} s): "
            "the offset may lie beyond it",
        )
    refined = _refine(pair, float(grid[best]), costs[best][1], step, params, thr, params.huber_px * scale)
    if isinstance(refined, str):
        return _no_offset(a, b, refined)
    delta, sigma, n, rms = refined
    out = PairOffset(a=a.name, b=b.name, offset_s=delta, sigma_s=sigma, correspondences=n, rms_px=rms)
    if sigma > params.max_pair_sigma_s:
        out.reason = f"sigma {sigma * 1e3:.1f} ms > {params.max_pair_sigma_s * 1e3:.0f} ms (too little motion)"
    return out


def _no_offset(a: SplineTracks, b: SplineTracks, reason: str) -> PairOffset:
    return PairOffset(a=a.name, b=b.name, offset_s=None, sigma_s=None, correspondences=0, rms_px=None, reason=reason)


def covisible_pairs(cams: list[SplineTracks], params: ClockParams) -> list[tuple[int, int]]:
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
