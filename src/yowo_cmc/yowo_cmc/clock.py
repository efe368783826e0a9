"""Clock offsets of unsynchronised CMCs from the agent's motion alone.

Two cameras that watch the walking agent see the same 3D keypoint at the same instant
only when their stamps are shifted by the offset between their clocks: at any other
shift the correspondences (camera A's sample at t, camera B's track at t + delta) break
the epipolar constraint in proportion to the agent's image speed. Per co-observing pair
an offset and its sigma (clock_pairs). Globally, here: the pair offsets over the
co-visibility graph by weighted least squares, one reference camera per connected
component, inconsistent pair estimates dropped one by one. Per calibrated group, the
offsets are refined with its poses (clock_refine)."""

from __future__ import annotations

from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from .clock_pairs import PairOffset, SplineTracks, covisible_pairs, estimate_pair
from .keypoint_tracks import CameraTracks
from .params import ClockParams, SfmParams


@dataclass(kw_only=True)
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
    while True:
        _drop_lone_bridges(usable)
        G = nx.Graph()
        G.add_nodes_from(range(len(names)))
        G.add_edges_from((index[p.a], index[p.b]) for p in usable)
        solution, worst = {}, None
        for comp in nx.connected_components(G):
            if len(comp) < 2:
                continue
            part, bad = _solve_component(comp, [p for p in usable if index[p.a] in comp], index, params)
            solution.update(part)
            if bad is not None and (worst is None or bad[1] > worst[1]):
                worst = bad
        if worst is None:
            break
        p, nsig, miss = worst
        p.reason = f"inconsistent with the other pairs: {miss * 1e3:+.1f} ms off ({nsig:.1f} sigma)"
        usable.remove(p)
    for p in usable:
        p.used = True
    out: dict[str, CameraClock] = {}
    for k, n in enumerate(names):
        if k in solution:
            off, sig, ref = solution[k]
            out[n] = CameraClock(name=n, offset_s=off, sigma_s=sig, reference=names[ref])
        else:
            reason = _no_estimate_reason(n, pairs, params)
            out[n] = CameraClock(name=n, offset_s=None, sigma_s=None, reference=None, reason=reason)
    return out


def _solve_component(
    comp: set[int], edges: list[PairOffset], index: dict[str, int], params: ClockParams
) -> tuple[dict[int, tuple[float, float, int]], tuple[PairOffset, float, float] | None]:
    """The offsets of one connected component's cameras from its pairs `edges`: {camera:
    (offset, sigma, reference)}, and its pair farthest off the solution if one is off by
    more than max_residual_sigma and min_residual_s: (pair, sigmas off, seconds off)."""
    members = sorted(comp)
    ref, col = members[0], {c: k for k, c in enumerate(members[1:])}
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
    solution = {ref: (0.0, 0.0, ref)}
    for c, k in col.items():
        solution[c] = (float(x[k]), float(np.sqrt(cov[k, k])), ref)
    off = np.abs(res) > params.max_residual_sigma
    off &= np.abs(y - A @ x) > params.min_residual_s
    if not off.any():
        return solution, None
    k = int(np.argmax(np.where(off, np.abs(res), -1.0)))
    return solution, (edges[k], abs(res[k]), float((y - A @ x)[k]))


def _no_estimate_reason(name: str, pairs: list[PairOffset], params: ClockParams) -> str:
    """Why camera `name` has no offset: no pair, or each of its pairs' reason."""
    mine = [p for p in pairs if name in (p.a, p.b)]
    if not mine:
        return (
            f"sees the agent at no time another camera does (within +-{params.max_offset_s:g} s): "
            "no pair to compare with"
        )
    return "no usable camera pair: " + "; ".join(f"with '{p.b if p.a == name else p.a}': {p.reason}" for p in mine)


def estimate_clock_offsets(
    tracks: list[CameraTracks], params: ClockParams = ClockParams(), sfm: SfmParams = SfmParams()
) -> ClockEstimate:
    """Each camera's clock offset from the reference camera of its co-visibility
    component (raw-pixel tracks on each camera's own clock; `sfm` gives the track
    cleaning and the spatial spread of the RANSAC subsets, as the group SfM uses them)."""
    stamps = [t.stamps_ns.min() for c in tracks for t in c.tracks.values() if len(t)]
    origin = int(min(stamps)) if stamps else 0
    cams = [SplineTracks(c, origin, sfm) for c in tracks]
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
