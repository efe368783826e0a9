"""The ego map's weak places, for the walker to walk again (walk guidance): stretches the ego
stage tracked weakly or not at all, areas walked once with no return (nothing checks their
drift), and stretches where a group's agent track misses the ego trajectory (typically a
doorway between rooms the groups see apart). Each is placed on the floor and said in words."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np
from scipy import ndimage

from .alignment import head_tops, interpolate_positions
from .records import AgentTrack

WEAK_TRACKING, WALKED_ONCE, TRACK_MISSES = "weak tracking", "walked once", "track misses the walk"


@dataclass(frozen=True)
class WeakPlaceParams:
    merge_gap_s: float = 1.0  # weak frames closer in time than this form one stretch [s]
    min_weak_s: float = 0.5  # a weak stretch shorter than this is left out (a gap is always kept) [s]
    cell_m: float = 1.0  # floor grid of the walked-once areas [m]
    revisit_away_m: float = 2.0  # back in a cell after going this far from it counts as a return [m]
    min_walked_once_m: float = 3.0  # an area walked once with less path than this is left out [m]
    track_miss_m: float = 0.15  # a group's head top further than this from the walk's misses it [m]
    min_miss_s: float = 1.0  # a miss shorter than this is left out [s]
    max_time_gap_s: float = 0.2  # ego poses further apart than this are not interpolated [s]


@dataclass(frozen=True, kw_only=True)
class WeakPlace:
    kind: str  # WEAK_TRACKING, WALKED_ONCE or TRACK_MISSES
    start_s: float  # from the walk's first frame [s]
    end_s: float
    x_m: float  # where on the floor (map frame): the stretch's or area's centre [m]
    y_m: float
    extent_m: float  # the stretch's path length or the area's diagonal [m]
    why: str
    group: str = ""  # the group whose track misses the walk

    def as_dict(self) -> dict:
        return {k: round(v, 3) if isinstance(v, float) else v for k, v in asdict(self).items()}


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))


def _merged(runs: list[tuple[int, int]], stamps_ns: np.ndarray, gap_s: float) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for a, b in runs:
        if out and stamps_ns[a] - stamps_ns[out[-1][1]] < gap_s * 1e9:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


def _path_m(xy: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def _place(kind, stamps_ns, t0, xy, a, b, why, group="") -> WeakPlace:
    centre = xy[a : b + 1].mean(axis=0)
    return WeakPlace(
        kind=kind,
        start_s=float(stamps_ns[a] - t0) / 1e9,
        end_s=float(stamps_ns[b] - t0) / 1e9,
        x_m=float(centre[0]),
        y_m=float(centre[1]),
        extent_m=_path_m(xy[a : b + 1]),
        why=why,
        group=group,
    )


def weak_tracking(
    stamps_ns: np.ndarray, xy: np.ndarray, weak: np.ndarray, gap: np.ndarray, params: WeakPlaceParams
) -> list[WeakPlace]:
    """Stretches of frames whose motion the ego map does not vouch for (few landmarks and a
    low overlap, not tracked by vision, or after a gap: yowo_fusion.verdict.weak_ego_frames)."""
    out = []
    for a, b in _merged(_runs(weak), stamps_ns, params.merge_gap_s):
        seconds = (stamps_ns[b] - stamps_ns[max(a - 1, 0)]) / 1e9
        gaps = int(gap[a : b + 1].sum())
        if not gaps and seconds < params.min_weak_s:
            continue
        why = (
            f"the ego camera tracked weakly for {seconds:.1f} s (few landmarks and little overlap, or no image motion)"
        )
        if gaps:
            why = f"the ego camera lost track {gaps} time(s) here ({seconds:.1f} s): the map's two sides are joined by a guess"
        out.append(_place(WEAK_TRACKING, stamps_ns, stamps_ns[0], xy, max(a - 1, 0), b, why))
    return out


def _returned(xy: np.ndarray, inside: np.ndarray, away_m: float) -> bool:
    """Whether the walk left a cell (its frames `inside`) by away_m and came back."""
    centre = xy[inside].mean(axis=0)
    for i, j in zip(inside[:-1], inside[1:]):
        if j > i + 1 and np.linalg.norm(xy[i:j] - centre, axis=1).max() >= away_m:
            return True
    return False


def walked_once(stamps_ns: np.ndarray, xy: np.ndarray, params: WeakPlaceParams) -> list[WeakPlace]:
    """Areas of the floor the walk passed through once and never came back to: no revisit
    (nor loop closure) checks their drift."""
    if len(xy) < 2:
        return []
    lo = xy.min(axis=0)
    cells = np.floor((xy - lo) / params.cell_m).astype(int)
    shape = tuple(cells.max(axis=0) + 1)
    flat = np.ravel_multi_index(cells.T, shape)
    once = np.zeros(shape, bool)
    for cell in np.unique(flat):
        once.flat[cell] = not _returned(xy, np.flatnonzero(flat == cell), params.revisit_away_m)
    labels, n = ndimage.label(once)
    out = []
    for label in range(1, n + 1):
        members = labels.flat[flat] == label
        idx = np.flatnonzero(members)
        inside = members[:-1] & members[1:]  # steps within the area
        length = float(np.linalg.norm(np.diff(xy, axis=0)[inside], axis=1).sum())
        if length < params.min_walked_once_m:
            continue
        a, b = int(idx[0]), int(idx[-1])
        box = np.ptp(xy[idx], axis=0)
        why = f"walked once ({length:.1f} m of path), never returned to: nothing checks this part's drift"
        place = _place(WALKED_ONCE, stamps_ns, stamps_ns[0], xy, a, b, why)
        out.append(replace(place, extent_m=float(np.hypot(*box))))
    return out


def track_misses(
    agent: AgentTrack,
    chain: np.ndarray,
    chains: dict[str, int],
    stamps_ns: np.ndarray,
    T_world_ego: np.ndarray,
    head_offset: np.ndarray,
    params: WeakPlaceParams,
) -> list[WeakPlace]:
    """Stretches where a group's head tops are further than track_miss_m from the head top
    the ego trajectory predicts: the group and the ego map disagree there (a doorway the
    groups see apart, a drifting stretch of the map)."""
    out = []
    for group, c in sorted(chains.items()):
        sel = np.flatnonzero((chain == c) & (agent.ids == 0))
        if not len(sel):
            continue
        order = sel[np.argsort(agent.stamps_ns[sel])]
        t = agent.stamps_ns[order]
        predicted, ok = interpolate_positions(
            stamps_ns, head_tops(T_world_ego, head_offset), t, int(params.max_time_gap_s * 1e9)
        )
        d = np.where(ok, np.linalg.norm(agent.points[order] - predicted, axis=1), 0.0)
        for a, b in _merged(_runs(d > params.track_miss_m), t, params.merge_gap_s):
            if (t[b] - t[a]) / 1e9 < params.min_miss_s:
                continue
            xy = predicted[:, :2]
            why = (
                f"group {group}'s agent track is {np.median(d[a : b + 1]):.2f} m (median) from the walk for "
                f"{(t[b] - t[a]) / 1e9:.1f} s: the group and the ego map disagree here"
            )
            out.append(_place(TRACK_MISSES, t, stamps_ns[0], xy, a, b, why, group))
    return out


def weak_places(
    stamps_ns: np.ndarray,
    T_world_ego: np.ndarray,
    weak: tuple[np.ndarray, np.ndarray],
    agent: AgentTrack,
    chain: np.ndarray,
    chains: dict[str, int],
    head_offset: np.ndarray,
    params: WeakPlaceParams,
) -> list[WeakPlace]:
    """Every weak place of the walk (weak tracking, walked once, track misses), in time order."""
    T = np.asarray(T_world_ego)
    if not len(T):
        return []
    xy = T[:, :2, 3]
    found = (
        weak_tracking(stamps_ns, xy, *weak, params)
        + walked_once(stamps_ns, xy, params)
        + track_misses(agent, chain, chains, stamps_ns, T, head_offset, params)
    )
    return sorted(found, key=lambda w: (w.start_s, w.kind))
