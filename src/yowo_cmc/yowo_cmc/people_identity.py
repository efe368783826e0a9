"""Everyone in view as evidence: the people a camera sees besides the walker, matched
across cameras so that each adds constraints to the cameras' relative poses as the walker
does (OMECC uses every person). Two cameras' views of one person fit one epipolar geometry
at every instant; two different people's do not once either of them moves. Per camera
pair, the pair of people whose keypoints give the best-spread fundamental matrix seeds
the pair's geometry, and every pair of people is judged under it; the pairwise matches are
joined into people seen by several cameras, never two people of one camera in one. The
person seen by the most cameras keeps the walker's keypoint ids, every other one is
numbered apart (scene_graph.PERSON_STRIDE)."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .keypoint_tracks import CameraTracks, KeypointTrack
from .params import PeopleParams, SfmParams
from .scene_graph import (
    PERSON_STRIDE,
    RANSAC_SEED,
    pair_geometry,
    sample_on_grid,
    sampson_px,
    strong_edge,
)

WALKER = 0  # a camera's own person 0: the one its tracker handed on as the walker


@dataclass(kw_only=True)
class PersonMatch:
    """One person seen by two cameras: their local person numbers and the evidence."""

    camera_a: str
    person_a: int
    camera_b: str
    person_b: int
    keypoints: int  # keypoints seen by both at the same instants
    inliers: int  # of them, those the camera pair's geometry of every matched person holds
    seed: bool  # this pair of people started the camera pair's matching


@dataclass(kw_only=True)
class PeopleIdentity:
    tracks: list[CameraTracks]  # per camera, every matched person's keypoints, numbered apart
    people: dict[str, dict[int, int]] = field(default_factory=dict)  # camera -> its person -> shared person
    matches: list[PersonMatch] = field(default_factory=list)

    def summary(self) -> str:
        if not self.people:
            return "nobody beside the walker matched across cameras"
        shared = sorted({g for m in self.people.values() for g in m.values()})
        seen = {g: sorted(c for c, m in self.people.items() if g in m.values()) for g in shared}
        return f"{len(shared)} people matched across cameras: " + "; ".join(
            f"person {g} in {', '.join(f'{c} (its {_local(c, g, self.people)})' for c in seen[g])}" for g in shared
        )

    def as_dict(self) -> dict:
        """For the run log and cameras.yaml: each camera's people and the matches' evidence."""
        return {
            "people": {c: {int(k): int(g) for k, g in m.items()} for c, m in self.people.items()},
            "matches": [
                {
                    "cameras": [m.camera_a, m.camera_b],
                    "people": [m.person_a, m.person_b],
                    "keypoints": m.keypoints,
                    "inliers": m.inliers,
                    "seed": m.seed,
                }
                for m in self.matches
            ],
        }


def _local(camera: str, shared: int, people: dict[str, dict[int, int]]) -> str:
    local = next(k for k, g in people[camera].items() if g == shared)
    return "walker" if local == WALKER else f"person {local}"


def match_people(
    views: dict[str, dict[int, CameraTracks]], sfm: SfmParams, people: PeopleParams = PeopleParams()
) -> PeopleIdentity:
    """`views`: per camera, its people's tracks (WALKER: the walker its tracker chose, others
    numbered from 1). A camera with nobody matched keeps its walker's tracks as they are."""
    cameras = list(views)
    flat = [(c, k) for c in cameras for k in sorted(views[c])]
    if len(flat) == len(cameras):  # one person per camera: nothing to match
        return PeopleIdentity(tracks=[views[c][k] for c, k in flat])
    obs = sample_on_grid([views[c][k] for c, k in flat], sfm.tracks)
    index = {v: i for i, v in enumerate(flat)}
    matches = []
    for ia, a in enumerate(cameras):
        for b in cameras[ia + 1 :]:
            matches += _camera_pair(obs, index, a, sorted(views[a]), b, sorted(views[b]), sfm, people)
    people = _join(matches, cameras)
    return PeopleIdentity(tracks=_numbered(views, people), people=people, matches=matches)


def _camera_pair(obs, index, a, people_a, b, people_b, sfm: SfmParams, people: PeopleParams) -> list[PersonMatch]:
    """The people of camera a matched with camera b's. From each pair of people whose own
    geometry is a strong edge (keypoints spread over both images), people are added greedily
    (the pair whose joint geometry with those matched so far holds the most keypoints); of
    these assignments, the one whose single geometry holds the most keypoints is taken. A
    wrong pair can be a strong edge on its own, two people's keypoints rarely fit one
    geometry with the right pairs."""
    geometry = {(p, q): pair_geometry(obs, index[(a, p)], index[(b, q)], sfm) for p in people_a for q in people_b}
    corr = {}  # (p, q) -> their keypoints at the same instants in a and in b
    for (p, q), g in geometry.items():
        if len(g.keys) >= sfm.min_matches:
            va, vb = index[(a, p)], index[(b, q)]
            corr[(p, q)] = (
                np.array([obs.per_camera[va][k] for k in g.keys]),
                np.array([obs.per_camera[vb][k] for k in g.keys]),
            )
    strong = [pq for pq, g in geometry.items() if strong_edge(g, sfm)]
    if not strong:
        return []
    # The inlier threshold: three sigma of the epipolar distances of the strong pair that fits
    # its own geometry best, the likeliest to be one person (pose keypoints of a real person
    # differ between views by more than their jitter over time, the noise scale), at least
    # the MAGSAC threshold.
    sigma = min(1.4826 * float(np.median(sampson_px(geometry[pq].F, *corr[pq]))) for pq in strong)
    px = max(sfm.ransac_px, 3 * sigma)

    def held(pairs: list) -> list[int] | None:
        """Each pair's keypoints within px of one geometry fitted to all of them."""
        uv_a, uv_b = (np.vstack([corr[pq][i] for pq in pairs]) for i in (0, 1))
        cv2.setRNGSeed(RANSAC_SEED)
        try:
            F, _ = cv2.findFundamentalMat(uv_a, uv_b, cv2.USAC_MAGSAC, px, 0.9999, 10000)
        except cv2.error:  # degenerate (every keypoint in one spot)
            return None
        if F is None or F.shape != (3, 3):
            return None
        return [int((sampson_px(F, *corr[pq]) <= px).sum()) for pq in pairs]

    def grown(seed) -> tuple[list, list[int]]:
        chosen, inliers = [seed], held([seed]) or [0]
        while True:
            trials = []
            for pq in corr:
                if pq[0] in {c[0] for c in chosen} or pq[1] in {c[1] for c in chosen}:
                    continue
                n = held([*chosen, pq])
                # The newcomer mostly fits, and the geometry still holds those matched before:
                # two different people's keypoints pull one geometry apart.
                fits = n is not None and n[-1] >= people.match_min_share * len(corr[pq][0])
                if fits and all(x >= people.match_min_kept * y for x, y in zip(n, inliers)):
                    trials.append((sum(n), pq, n))
            if not trials:
                return chosen, inliers
            _, pq, inliers = max(trials)
            chosen.append(pq)

    chosen, inliers = max((grown(seed) for seed in strong), key=lambda r: sum(r[1]))
    return [
        PersonMatch(
            camera_a=a,
            person_a=p,
            camera_b=b,
            person_b=q,
            keypoints=len(corr[(p, q)][0]),
            inliers=n,
            seed=i == 0,
        )
        for i, ((p, q), n) in enumerate(zip(chosen, inliers))
        if n > 0
    ]


def _join(matches: list[PersonMatch], cameras: list[str]) -> dict[str, dict[int, int]]:
    """Shared people from pairwise matches (union-find, best-supported first; a join that
    would put two of one camera's people in one is refused); those seen by one camera only
    are dropped. The person seen by the most cameras is 0."""
    parent: dict[tuple[str, int], tuple[str, int]] = {}

    def root(v):
        while parent.setdefault(v, v) != v:
            v = parent[v]
        return v

    members: dict[tuple[str, int], set] = {}  # root -> the people joined under it
    for m in sorted(matches, key=lambda m: (not m.seed, -m.keypoints)):
        ra, rb = root((m.camera_a, m.person_a)), root((m.camera_b, m.person_b))
        sa, sb = members.get(ra, {ra}), members.get(rb, {rb})
        if ra == rb or {c for c, _ in sa} & {c for c, _ in sb}:
            continue
        parent[rb] = ra
        members[ra] = sa | sb
        members.pop(rb, None)
    groups = [g for g in members.values() if len({c for c, _ in g}) >= 2]
    # Most cameras first, then the walker's: the person most cameras saw keeps the walker's ids.
    groups.sort(key=lambda g: (-len(g), -sum(k == WALKER for _, k in g)))
    people: dict[str, dict[int, int]] = {}
    for shared, g in enumerate(groups):
        for c, k in g:
            people.setdefault(c, {})[k] = shared
    return {c: people[c] for c in cameras if c in people}


def _numbered(views: dict[str, dict[int, CameraTracks]], people: dict[str, dict[int, int]]) -> list[CameraTracks]:
    out = []
    for c, persons in views.items():
        mine = people.get(c)
        if not mine:
            out.append(persons[WALKER] if WALKER in persons else next(iter(persons.values())))
            continue
        first = persons[next(iter(mine))]
        tracks: dict[int, KeypointTrack] = {}
        for local, shared in mine.items():
            for joint, t in persons[local].tracks.items():
                if joint < PERSON_STRIDE:
                    tracks[shared * PERSON_STRIDE + joint] = t
        out.append(CameraTracks(c, first.camera, tracks, first.frame_period_ns))
    return out
