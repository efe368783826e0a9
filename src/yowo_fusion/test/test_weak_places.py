"""The ego map's weak places on a synthetic walk: a loop walked twice, then a corridor walked
once; a stretch tracked weakly and a gap; a group's track off the walk for two seconds."""

import numpy as np

from yowo_common.geometry import se3
from yowo_fusion.records import AgentTrack
from yowo_fusion.weak_places import (
    TRACK_MISSES,
    WALKED_ONCE,
    WEAK_TRACKING,
    WeakPlaceParams,
    weak_places,
)

HZ = 10


def walk():
    """Twice round a 4 x 4 m loop (32 s at 1 m/s), then 8 m down a corridor."""
    loop = []
    corners = [(0, 0), (4, 0), (4, 4), (0, 4), (0, 0)]
    for _ in range(2):
        for a, b in zip(corners[:-1], corners[1:]):
            for s in np.arange(0, 4, 1 / HZ):
                loop.append(np.add(a, np.subtract(b, a) * s / 4))
    corridor = [np.array([-s, 0.0]) for s in np.arange(0, 8, 1 / HZ)]
    xy = np.array(loop + corridor)
    stamps = (np.arange(len(xy)) * 1e9 / HZ).astype(np.int64)
    T = np.array([se3(np.eye(3), [x, y, 1.6]) for x, y in xy])
    return stamps, T


def test_the_corridor_walked_once_is_found_and_the_loop_walked_twice_is_not():
    stamps, T = walk()
    none = np.zeros(len(stamps), bool)
    empty = AgentTrack(np.zeros(0, np.int64), np.zeros(0, int), np.zeros((0, 3)))
    places = weak_places(stamps, T, (none, none), empty, np.zeros(0, int), {}, np.zeros(3), WeakPlaceParams())
    assert [p.kind for p in places] == [WALKED_ONCE], places
    once = places[0]
    assert once.start_s >= 31.0 and once.x_m < -2.0 and abs(once.y_m) < 0.6
    assert "walked once (6.9 m of path)" in once.why  # the corridor beyond the loop's corner cell


def test_weak_tracking_and_a_gap_are_stretches_of_their_own():
    stamps, T = walk()
    weak, gap = np.zeros(len(stamps), bool), np.zeros(len(stamps), bool)
    weak[50:70] = True  # 2 s of weak tracking on the first lap
    weak[200:203] = True  # a short weak blip: too short alone
    gap[250] = weak[250] = True  # a lost track: always said
    empty = AgentTrack(np.zeros(0, np.int64), np.zeros(0, int), np.zeros((0, 3)))
    places = [
        p
        for p in weak_places(stamps, T, (weak, gap), empty, np.zeros(0, int), {}, np.zeros(3), WeakPlaceParams())
        if p.kind == WEAK_TRACKING
    ]
    assert len(places) == 2, places
    first, lost = places
    assert 4.8 <= first.start_s <= 5.0 and 6.8 <= first.end_s <= 7.0 and "weakly" in first.why
    assert "lost track 1 time" in lost.why and 24.8 <= lost.start_s <= 25.0


def test_a_group_whose_track_leaves_the_walk_is_named_where_it_does():
    stamps, T = walk()
    offset = np.array([0.0, -0.1, 0.0])
    tops = T[:, :3, 3] + offset
    sel = np.arange(100, 200)  # the group saw 10 s of the first lap's second half
    points = tops[sel].copy()
    points[30:50] += [0.0, 0.0, 0.3]  # 2 s of it 0.3 m off the walk
    agent = AgentTrack(stamps[sel], np.zeros(len(sel), int), points)
    none = np.zeros(len(stamps), bool)
    chain = np.full(len(sel), 3)
    places = weak_places(stamps, T, (none, none), agent, chain, {"g1": 3}, offset, WeakPlaceParams())
    misses = [p for p in places if p.kind == TRACK_MISSES]
    assert len(misses) == 1 and misses[0].group == "g1", places
    m = misses[0]
    assert 12.9 <= m.start_s <= 13.1 and 14.8 <= m.end_s <= 15.0 and "0.30 m" in m.why
    # Where: the stretch of the walk at those stamps.
    assert np.hypot(m.x_m - T[140, 0, 3], m.y_m - T[140, 1, 3]) < 1.0
