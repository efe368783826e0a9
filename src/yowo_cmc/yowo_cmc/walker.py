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
from .person_tracks import PersonTrack, appearance_distance, box_height, identities


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
class PersonEvidence:
    track_ids: list[int]  # one person's tracks in this camera (person_tracks.identities)
    images: int
    seconds: float
    agreement: float | None  # None: not informative (too short, or the ego camera only walked or stood)
    # The agreement's lower confidence bound: its samples a smoothing window apart count as independent.
    confidence: float | None
    alone: bool  # nobody else was in view while this person was
    walker: bool
    why: str


@dataclass(kw_only=True)
class WalkerChoice:
    track_ids: list[int]  # the walker's tracks (a walker leaving the view and coming back: several)
    clock_offset_s: float | None  # camera clock - ego clock at which the motions agreed best
    evidence: list[PersonEvidence] = field(default_factory=list)
    reason: str = ""  # why no track is the walker
    doubt: str = ""  # why the walker taken may be someone else ('' where the evidence decided)

    def as_dict(self) -> dict:
        """For cameras.yaml: the walker's tracks, the clock offset and each person's evidence."""
        return {
            "tracks": list(self.track_ids),
            "clock_offset_s": None if self.clock_offset_s is None else round(self.clock_offset_s, 2) + 0.0,
            "reason": self.reason,
            "doubt": self.doubt,
            "people": [
                {
                    "tracks": e.track_ids,
                    "seconds": round(e.seconds, 2),
                    "agreement": None if e.agreement is None else round(e.agreement, 3),
                    "confidence": None if e.confidence is None else round(e.confidence, 3),
                    "alone": e.alone,
                    "walker": e.walker,
                    "why": e.why,
                }
                for e in self.evidence
            ],
        }

    def summary(self) -> str:
        def one(e: PersonEvidence) -> str:
            score = "no evidence" if e.agreement is None else f"agreement {e.agreement:.2f} (>= {e.confidence:.2f})"
            return (
                f"person of track {'+'.join(map(str, e.track_ids))} ({e.seconds:.1f} s, {score}"
                f"{'' if e.alone else ', others in view'}: {e.why})"
            )

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


def _overlaps(a: list[PersonTrack], b: list[PersonTrack]) -> bool:
    """Whether two people's tracks share images (both in view at once)."""
    seen = set().union(*(t.stamps_ns for t in a))
    return any(not seen.isdisjoint(t.stamps_ns) for t in b)


def choose_walker(tracks: list[PersonTrack], ego: EgoMotion | None, params: PeopleParams) -> WalkerChoice:
    """The walker's tracks among one camera's person tracks, with each person's evidence; `ego`:
    the ego camera's trajectory (None: a CMC-only calibration, no motion to compare)."""
    p = params
    everyone = identities(tracks, p)
    no_ego = ego is None or len(ego.stamps_ns) < 2
    # Without an ego trajectory no motion is compared: a short recording's one person is the walker.
    people = everyone if no_ego else [g for g in everyone if sum(t.seconds() for t in g) >= p.min_track_s]
    if not people:
        if everyone and not any(_overlaps(g, o) for i, g in enumerate(everyone) for o in everyone[i + 1 :]):
            return _too_short_alone(everyone)
        return WalkerChoice(track_ids=[], clock_offset_s=None, reason="no person seen long enough")
    alone = [not any(_overlaps(g, o) for o in everyone if o is not g) for g in people]
    if no_ego:
        choice = _without_ego(people, alone)
        choice.track_ids = _with_glimpses(choice.track_ids, everyone, people) if choice.track_ids else []
        return choice
    lags_s, scores, shared = _agreements(people, ego, p)
    bounds = np.where(np.isnan(scores), np.nan, _lower_bound(np.nan_to_num(scores), shared * p.grid_s / p.smooth_s))
    # The camera's offset: where one person agrees most surely (ties: nearest 0). Not the sum over
    # people: a bystander who walks the walker's way a little later agrees at another offset, and
    # summed with the walker's partial agreement there it could outweigh the walker's own.
    gain = np.nanmax(np.where(np.isnan(bounds), -np.inf, bounds), axis=0)
    informative = bool(np.any(np.isfinite(gain)))
    if not informative:
        k = int(np.argmin(np.abs(lags_s)))
    else:
        best = np.flatnonzero(gain >= gain.max() - 1e-12)
        k = int(best[np.argmin(np.abs(lags_s[best]))])
    at = [None if np.isnan(scores[i, k]) else float(scores[i, k]) for i in range(len(people))]
    sure = [None if np.isnan(bounds[i, k]) else float(bounds[i, k]) for i in range(len(people))]
    evidence = [_judge(i, people, alone, at, sure, p) for i in range(len(people))]
    _one_walker(people, evidence, p)
    chosen = sorted(t.track_id for g, e in zip(people, evidence) if e.walker for t in g)
    if chosen and all(e.walker for e in evidence):
        chosen = _with_glimpses(chosen, everyone, people)
    reason = "" if chosen else "no track is clearly the walker"
    offset = float(lags_s[k]) if informative else None
    return WalkerChoice(track_ids=chosen, clock_offset_s=offset, evidence=evidence, reason=reason)


def _agreements(people: list[list[PersonTrack]], ego: EgoMotion, p: PeopleParams):
    """(clock offsets searched, agreement per person and offset (NaN: not informative), samples
    shared): each person's walking/standing on its tracks' grids against the ego camera's."""
    lags_s = np.arange(-p.max_clock_offset_s, p.max_clock_offset_s + 1e-9, p.grid_s)
    scores = np.full((len(people), len(lags_s)), np.nan)
    shared = np.zeros_like(scores)
    for i, g in enumerate(people):
        grids = [np.arange(t.stamps_ns[0], t.stamps_ns[-1] + 1, p.grid_s * 1e9) for t in g]
        v = np.concatenate([_track_speed(t, grid, p.smooth_s) for t, grid in zip(g, grids)])
        moving = np.where(np.isnan(v), np.nan, v > p.track_moving_heights_s)
        grid = np.concatenate(grids)
        for k, lag in enumerate(lags_s):
            ego_v = ego.speed_mps(grid - lag * 1e9, p.smooth_s)
            ego_m = np.where(np.isnan(ego_v), np.nan, ego_v > p.ego_moving_mps)
            a, shared[i, k] = _agreement(moving, ego_m, p)
            scores[i, k] = np.nan if a is None else a
    return lags_s, scores, shared


def _judge(i: int, people, alone: list[bool], at: list, sure: list, p: PeopleParams) -> PersonEvidence:
    """Person i's verdict at the camera's offset: alone in view, it is the walker unless it moves
    unlike the head camera; among others, it must agree clearly and more surely than them."""
    g, a = people[i], at[i]
    others = [sure[j] for j, o in enumerate(people) if j != i and sure[j] is not None and _overlaps(g, o)]
    if alone[i]:
        walker = a is None or a >= p.reject_agreement
        why = "alone in view" if walker else "alone in view, but moves unlike the head camera"
    elif a is None:
        walker, why = False, "others in view and no motion evidence to tell them apart"
    elif a < p.accept_agreement:
        walker, why = False, "moves unlike the head camera"
    elif others and sure[i] < max(others) + p.min_margin:
        walker, why = False, "another person in view moves as much like the head camera"
    else:
        walker, why = True, "moves like the head camera"
    return _evidence(g, a, alone[i], walker, why, sure[i])


def _one_walker(people: list[list[PersonTrack]], evidence: list[PersonEvidence], p: PeopleParams) -> None:
    """One person in a camera is the walker: of several accepted, the one agreeing most surely
    (no evidence counts as chance), then the longest; the others are kept only when
    their clothes look like it (one person split where its look changed across the view)."""
    accepted = [i for i, e in enumerate(evidence) if e.walker]
    if len(accepted) < 2:
        return
    best = max(accepted, key=lambda i: (evidence[i].confidence or 0.5, evidence[i].seconds))
    for i in accepted:
        if i != best and _look_distance(people[i], people[best]) > p.max_appearance_distance:
            evidence[i].walker = False
            evidence[i].why += "; but another person here moves more like the head camera"


def _look_distance(a: list[PersonTrack], b: list[PersonTrack]) -> float:
    looks = [[t.look for t in g if t.look is not None] for g in (a, b)]
    if not looks[0] or not looks[1]:
        return 0.5
    return appearance_distance(*(np.mean(x, axis=0) for x in looks))


def _lower_bound(agreement, n, z: float = 1.645):
    """Wilson's lower bound (one-sided 95 %) of an agreement over n independent samples (arrays
    alike): a short track that agrees by chance is less sure than a long one that agrees as well."""
    n = np.maximum(np.asarray(n, float), 1e-9)
    centre = agreement + z * z / (2 * n)
    spread = z * np.sqrt(agreement * (1 - agreement) / n + z * z / (4 * n * n))
    return (centre - spread) / (1 + z * z / n)


def _with_glimpses(chosen: list[int], everyone: list[list[PersonTrack]], people: list[list[PersonTrack]]) -> list[int]:
    """Where nobody else was ever in a camera's view (no two tracks in one image), its tracks
    too short to judge are the walker's glimpses too."""
    if any(_overlaps(g, o) for i, g in enumerate(everyone) for o in everyone[i + 1 :]):
        return chosen
    return sorted(chosen + [t.track_id for g in everyone if not any(g is h for h in people) for t in g])


def _evidence(g: list[PersonTrack], agreement, alone: bool, walker: bool, why: str, sure=None) -> PersonEvidence:
    return PersonEvidence(
        track_ids=[t.track_id for t in g],
        images=sum(len(t.stamps_ns) for t in g),
        seconds=sum(t.seconds() for t in g),
        agreement=agreement,
        confidence=sure,
        alone=alone,
        walker=walker,
        why=why,
    )


def _too_short_alone(everyone: list[list[PersonTrack]]) -> WalkerChoice:
    """Nobody seen long enough to compare with the ego camera's motion, and never two people in
    view at once: what was seen is taken for the walker, as a person alone in view is."""
    why = "alone in view, seen too briefly to compare with the ego camera's motion"
    evidence = [_evidence(g, None, True, True, why) for g in everyone]
    return WalkerChoice(
        track_ids=sorted(t.track_id for g in everyone for t in g), clock_offset_s=None, evidence=evidence
    )


def _without_ego(people: list[list[PersonTrack]], alone: list[bool]) -> WalkerChoice:
    """No ego trajectory (a CMC-only calibration): the people alone in view, else the person
    seen longest."""
    chosen = [i for i in range(len(people)) if alone[i]]
    why, doubt = "alone in view (no ego trajectory to check)", ""
    if not chosen:
        chosen = [max(range(len(people)), key=lambda i: sum(len(t.stamps_ns) for t in people[i]))]
        why = "seen longest among others in view (no ego trajectory to tell them apart)"
        doubt = (
            f"the walker was taken for the person seen longest of {len(people)} in view together: without an "
            "ego camera nothing tells them apart, and another camera may have taken another person"
        )
    evidence = [
        _evidence(g, None, alone[i], i in chosen, why if i in chosen else "not chosen") for i, g in enumerate(people)
    ]
    ids = sorted(t.track_id for i in chosen for t in people[i])
    return WalkerChoice(track_ids=ids, clock_offset_s=None, evidence=evidence, doubt=doubt)
