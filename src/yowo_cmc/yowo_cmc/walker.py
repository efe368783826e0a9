"""Which of the people a camera sees is the walker, the ego camera's wearer.

Evidence from the ego trajectory, available before any camera is registered: the walker
walks and stands when the head camera does. Each person track's speed in body heights
per second (its box's foot point over its box's height: no calibration needed) is read as
walking or standing on a time grid, as is the ego camera's speed, and the two are compared
at every clock offset the camera may have (one offset per camera, shared by its tracks).
The agreement is balanced over the ego camera's walking and standing, so a person who
walks all along agrees half of the time with a walker who stops. A track is the walker
when it agrees clearly and clearly better than anyone else seen at the same time; a
person alone in view is the walker unless its motion contradicts the head camera's."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .params import PeopleParams
from .person_tracks import PersonTrack, box_height


@dataclass(kw_only=True)
class EgoMotion:
    """The ego camera's positions (any fixed frame, metres) at its stamps (ego clock)."""

    stamps_ns: np.ndarray
    positions: np.ndarray  # (N, 3) [m]

    def speed_mps(self, t_ns: np.ndarray, window_s: float) -> np.ndarray:
        """Speed over `window_s` centred on each time; NaN outside the trajectory."""
        half = 0.5e9 * window_s
        s = np.asarray(self.stamps_ns, float)
        a, b = t_ns - half, t_ns + half
        pa = np.column_stack([np.interp(a, s, self.positions[:, k]) for k in range(3)])
        pb = np.column_stack([np.interp(b, s, self.positions[:, k]) for k in range(3)])
        v = np.linalg.norm(pb - pa, axis=1) / window_s
        v[(a < s[0]) | (b > s[-1])] = np.nan
        return v


@dataclass(kw_only=True)
class TrackEvidence:
    track_id: int
    images: int
    seconds: float
    agreement: float | None  # None: not informative (too short, or the ego camera only walked or stood)
    alone: bool  # nobody else was in view while this track was
    walker: bool
    why: str


@dataclass(kw_only=True)
class WalkerChoice:
    track_ids: list[int]  # the walker's tracks (a walker leaving the view and coming back: several)
    clock_offset_s: float | None  # camera clock - ego clock at which the motions agreed best
    evidence: list[TrackEvidence] = field(default_factory=list)
    reason: str = ""  # why no track is the walker

    def summary(self) -> str:
        def one(e: TrackEvidence) -> str:
            score = "no evidence" if e.agreement is None else f"agreement {e.agreement:.2f}"
            return f"track {e.track_id} ({e.seconds:.1f} s, {score}{'' if e.alone else ', others in view'}: {e.why})"

        head = f"walker: track {', '.join(map(str, self.track_ids))}" if self.track_ids else f"no walker: {self.reason}"
        if self.clock_offset_s is not None:
            head += f" (motions agree at clock offset {round(self.clock_offset_s, 1) + 0.0:+.1f} s)"
        return head + ("; " + "; ".join(one(e) for e in self.evidence) if self.evidence else "")


def _track_speed(track: PersonTrack, t_ns: np.ndarray, window_s: float) -> np.ndarray:
    """Speed of the box's foot point in body heights per second, NaN where the track has a gap."""
    s = np.asarray(track.stamps_ns, float)
    boxes = np.array([q.box for q in track.poses], float)
    foot = np.column_stack([(boxes[:, 0] + boxes[:, 2]) / 2, boxes[:, 3]])
    heights = np.array([box_height(b) for b in boxes])
    half = 0.5e9 * window_s
    a, b = t_ns - half, t_ns + half
    fa = np.column_stack([np.interp(a, s, foot[:, k]) for k in range(2)])
    fb = np.column_stack([np.interp(b, s, foot[:, k]) for k in range(2)])
    v = np.hypot(*(fb - fa).T) / window_s / np.interp(t_ns, s, heights)
    # A gap (the person hidden) longer than the window tells nothing about the motion inside it.
    gap = np.diff(s, prepend=s[0])
    idx = np.searchsorted(s, t_ns)
    big = gap[np.clip(idx, 0, len(s) - 1)] > 1e9 * window_s
    v[big | (a < s[0]) | (b > s[-1])] = np.nan
    return v


def _agreement(moving: np.ndarray, ego_moving: np.ndarray, p: PeopleParams) -> tuple[float | None, int]:
    """Balanced agreement of two walking/standing series (NaN: unknown), and the samples
    they share; None when the ego camera did not both walk and stand enough of that time."""
    ok = ~np.isnan(moving) & ~np.isnan(ego_moving)
    n = int(ok.sum())
    if n * p.grid_s < p.min_track_s:
        return None, n
    m, e = moving[ok] > 0.5, ego_moving[ok] > 0.5
    share = e.mean()
    if min(share, 1 - share) < p.min_state_share:
        return None, n
    return 0.5 * (float(m[e].mean()) + float((~m[~e]).mean())), n


def _overlaps(a: PersonTrack, b: PersonTrack) -> bool:
    """Whether two tracks share images (both people in view at once)."""
    return bool(set(a.stamps_ns) & set(b.stamps_ns))


def choose_walker(tracks: list[PersonTrack], ego: EgoMotion | None, params: PeopleParams) -> WalkerChoice:
    p = params
    candidates = [t for t in tracks if t.seconds() >= p.min_track_s]
    if not candidates:
        return WalkerChoice(track_ids=[], clock_offset_s=None, reason="no person seen long enough")
    alone = {t.track_id: not any(_overlaps(t, o) for o in tracks if o is not t) for t in candidates}
    if ego is None or len(ego.stamps_ns) < 2:
        return _without_ego(candidates, alone)
    # Walking/standing of each candidate on its own grid, and the ego camera's at every offset.
    lags_s = np.arange(-p.max_clock_offset_s, p.max_clock_offset_s + 1e-9, p.grid_s)
    scores = np.full((len(candidates), len(lags_s)), np.nan)
    shared = np.zeros_like(scores)
    for i, t in enumerate(candidates):
        grid = np.arange(t.stamps_ns[0], t.stamps_ns[-1] + 1, p.grid_s * 1e9)
        moving = _track_speed(t, grid, p.smooth_s)
        moving = np.where(np.isnan(moving), np.nan, moving > p.track_moving_heights_s)
        for k, lag in enumerate(lags_s):
            ego_v = ego.speed_mps(grid - lag * 1e9, p.smooth_s)
            ego_m = np.where(np.isnan(ego_v), np.nan, ego_v > p.ego_moving_mps)
            a, shared[i, k] = _agreement(moving, ego_m, p)
            scores[i, k] = np.nan if a is None else a
    # The camera's offset: where the tracks together agree most beyond chance, over the most
    # shared time (ties: nearest 0).
    gain = np.nansum(np.clip(scores - 0.5, 0, None) * shared, axis=0)
    if not np.any(gain > 0):
        k = int(np.argmin(np.abs(lags_s)))
    else:
        best = np.flatnonzero(gain >= gain.max() - 1e-12)
        k = int(best[np.argmin(np.abs(lags_s[best]))])
    at = {t.track_id: (None if np.isnan(scores[i, k]) else float(scores[i, k])) for i, t in enumerate(candidates)}
    evidence = []
    for t in candidates:
        a = at[t.track_id]
        others = [at[o.track_id] for o in candidates if o is not t and _overlaps(t, o)]
        others = [x for x in others if x is not None]
        if alone[t.track_id]:
            walker = a is None or a >= p.reject_agreement
            why = "alone in view" if walker else "alone in view, but moves unlike the head camera"
        elif a is None:
            walker, why = False, "others in view and no motion evidence to tell them apart"
        elif a < p.accept_agreement:
            walker, why = False, "moves unlike the head camera"
        elif others and a < max(others) + p.min_margin:
            walker, why = False, "another person in view moves as much like the head camera"
        else:
            walker, why = True, "moves like the head camera"
        evidence.append(
            TrackEvidence(
                track_id=t.track_id,
                images=len(t.stamps_ns),
                seconds=t.seconds(),
                agreement=a,
                alone=alone[t.track_id],
                walker=walker,
                why=why,
            )
        )
    chosen = [e.track_id for e in evidence if e.walker]
    reason = "" if chosen else "no track is clearly the walker"
    offset = float(lags_s[k]) if np.any(gain > 0) else None
    return WalkerChoice(track_ids=chosen, clock_offset_s=offset, evidence=evidence, reason=reason)


def _without_ego(candidates: list[PersonTrack], alone: dict[int, bool]) -> WalkerChoice:
    """No ego trajectory (a CMC-only calibration): the people alone in view, else the
    longest track."""
    ids = [t.track_id for t in candidates if alone[t.track_id]]
    why = "alone in view (no ego trajectory to check)"
    if not ids:
        ids = [max(candidates, key=lambda t: len(t.stamps_ns)).track_id]
        why = "the longest track among others in view (no ego trajectory to tell them apart)"
    evidence = [
        TrackEvidence(
            track_id=t.track_id,
            images=len(t.stamps_ns),
            seconds=t.seconds(),
            agreement=None,
            alone=alone[t.track_id],
            walker=t.track_id in ids,
            why=why if t.track_id in ids else "not chosen",
        )
        for t in candidates
    ]
    return WalkerChoice(track_ids=ids, clock_offset_s=None, evidence=evidence)
