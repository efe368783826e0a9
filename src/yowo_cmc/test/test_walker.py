"""Person tracks through a crossing, and the walker told from the ego camera's motion."""

import cv2
import numpy as np
import pytest

from yowo_cmc.params import PeopleParams
from yowo_cmc.person_tracks import PersonTracker, appearance, appearance_distance
from yowo_cmc.pose_keypoints import PersonPose
from yowo_cmc.walker import EgoMotion, choose_walker

HZ = 10.0
H_PX = 120.0  # a person's box height in the image


def schedule(duration_s: float, legs: list[tuple[float, bool]], t: np.ndarray) -> np.ndarray:
    """Walking (True) or standing along repeated legs (seconds, walking)."""
    period = sum(s for s, _ in legs)
    phase = np.mod(t, period)
    out = np.zeros(len(t), bool)
    start = 0.0
    for s, walking in legs:
        out[(phase >= start) & (phase < start + s)] = walking
        start += s
    return out


def path(walking: np.ndarray, speed: float, dt: float) -> np.ndarray:
    """Distance along a line, integrated from walking/standing."""
    return np.concatenate([[0.0], np.cumsum(walking[:-1] * speed * dt)])


def pose_at(x: float, y: float, h: float = H_PX) -> PersonPose:
    box = np.array([x - 0.2 * h, y - h, x + 0.2 * h, y])
    ids = np.arange(3)
    uv = np.array([[x, y - h], [x, y], [x, y - h / 2]])
    return PersonPose(score=0.9, box=box, ids=ids, uv=uv, confidence=np.ones(3))


def ego_from(walking: np.ndarray, t: np.ndarray) -> EgoMotion:
    x = path(walking, 1.2, t[1] - t[0])
    positions = np.column_stack([x, np.zeros_like(x), np.full_like(x, 1.6)])
    return EgoMotion(stamps_ns=np.round(t * 1e9).astype(np.int64), positions=positions)


def tracks_of(people: dict[str, np.ndarray], stamps_ns: np.ndarray, params=PeopleParams(), clothes=None):
    """Tracks of people given as (x, y) pixel paths (NaN: not in view); `clothes`: name ->
    (shirt, trousers) colours drawn at their boxes (else a blank image: everyone looks alike)."""
    tracker = PersonTracker(params)
    names = {}
    for i, stamp in enumerate(stamps_ns):
        seen = [(n, xy[i]) for n, xy in people.items() if np.isfinite(xy[i]).all()]
        image = np.full((480, 2000, 3), 128, np.uint8)
        for n, (x, y) in seen:
            if clothes and n in clothes:
                dressed(image, pose_at(x, y), *clothes[n])
        for (n, _), (track, _, _) in zip(seen, tracker.update(int(stamp), image, [pose_at(*xy) for _, xy in seen])):
            names.setdefault(track.track_id, n)
    return tracker.tracks, names


T = np.arange(0, 40, 1 / HZ)
WALKER_LEGS = [(5.0, True), (3.0, False), (7.0, True), (2.0, False), (4.0, True), (4.0, False)]


def test_the_walker_is_the_person_who_stops_when_the_head_camera_stops():
    offset_s = 1.3  # the camera's clock runs ahead of the ego camera's
    ego_walking = schedule(40, WALKER_LEGS, T)
    ego = ego_from(ego_walking, T)
    cam_t = T + offset_s
    walker_x = 100 + path(ego_walking, 0.5 * H_PX, 1 / HZ)
    other_walking = schedule(40, [(2.0, True), (4.0, False), (3.0, True)], T + 0.7)
    other_x = 1900 - path(other_walking, 0.5 * H_PX, 1 / HZ)
    people = {
        "walker": np.column_stack([walker_x, np.full_like(T, 300.0)]),
        "other": np.column_stack([other_x, np.full_like(T, 420.0)]),
    }
    tracks, names = tracks_of(people, np.round(cam_t * 1e9))
    choice = choose_walker(tracks, ego, PeopleParams())
    assert [names[k] for k in choice.track_ids] == ["walker"], choice.summary()
    assert choice.clock_offset_s == pytest.approx(offset_s, abs=0.25)
    walker = next(e for e in choice.evidence if names[e.track_ids[0]] == "walker")
    other = next(e for e in choice.evidence if names[e.track_ids[0]] == "other")
    assert walker.agreement > 0.9 and other.agreement < 0.7 and not walker.alone
    assert "walker: track" in choice.summary()


def test_a_camera_that_sees_only_a_bystander_is_not_given_a_walker():
    ego = ego_from(schedule(40, WALKER_LEGS, T), T)
    other = 100 + path(np.ones(len(T), bool), 0.5 * H_PX, 1 / HZ)  # walks all along while the walker stops
    tracks, _ = tracks_of({"other": np.column_stack([other, np.full_like(T, 300.0)])}, np.round(T * 1e9))
    choice = choose_walker(tracks, ego, PeopleParams())
    assert choice.track_ids == [] and "no track is clearly the walker" in choice.summary()
    assert "moves unlike the head camera" in choice.evidence[0].why


def test_two_people_walking_together_are_not_told_apart():
    walking = schedule(40, WALKER_LEGS, T)
    ego = ego_from(walking, T)
    x = 100 + path(walking, 0.5 * H_PX, 1 / HZ)
    people = {"a": np.column_stack([x, np.full_like(T, 250.0)]), "b": np.column_stack([x + 60, np.full_like(T, 420.0)])}
    tracks, _ = tracks_of(people, np.round(T * 1e9))
    choice = choose_walker(tracks, ego, PeopleParams())
    assert len(tracks) == 2 and choice.track_ids == []
    assert all("as much like the head camera" in e.why for e in choice.evidence)


def test_a_person_alone_in_view_without_motion_evidence_is_the_walker():
    ego = ego_from(np.ones(len(T), bool), T)  # the head camera walks all along: no stops to compare
    x = 100 + path(np.ones(len(T), bool), 0.5 * H_PX, 1 / HZ)
    tracks, _ = tracks_of({"walker": np.column_stack([x, np.full_like(T, 300.0)])}, np.round(T * 1e9))
    choice = choose_walker(tracks, ego, PeopleParams())
    assert choice.track_ids == [tracks[0].track_id] and choice.evidence[0].agreement is None
    # Without any ego trajectory (CMC-only): alone in view, or else the longest track.
    assert choose_walker(tracks, None, PeopleParams()).track_ids == [tracks[0].track_id]


def test_a_recording_shorter_than_a_judgeable_track_still_has_its_one_person_as_the_walker():
    """A real 1.5 s recording (a lab trial): one person, too short to compare with any motion."""
    t = T[T < 1.5]
    x = 100 + path(np.ones(len(t), bool), 0.5 * H_PX, 1 / HZ)
    tracks, _ = tracks_of({"walker": np.column_stack([x, np.full_like(t, 300.0)])}, np.round(t * 1e9))
    assert sum(tr.seconds() for tr in tracks) < PeopleParams().min_track_s
    ids = [tr.track_id for tr in tracks]
    assert choose_walker(tracks, None, PeopleParams()).track_ids == ids  # CMC-only
    with_ego = choose_walker(tracks, ego_from(np.ones(len(T), bool), T), PeopleParams())
    assert with_ego.track_ids == ids and "too briefly" in with_ego.evidence[0].why
    # Two people that briefly: which one walked cannot be told.
    both = {"a": np.column_stack([x, np.full_like(t, 300.0)]), "b": np.column_stack([x + 900, np.full_like(t, 420.0)])}
    tracks, _ = tracks_of(both, np.round(t * 1e9))
    choice = choose_walker(tracks, ego_from(np.ones(len(T), bool), T), PeopleParams())
    assert choice.track_ids == [] and choice.reason == "no person seen long enough"
    # CMC-only, one of them is taken, and the choice says it is a guess (the camera is then weak).
    guess = choose_walker(tracks, None, PeopleParams())
    assert len(guess.track_ids) == 1 and "nothing tells them apart" in guess.doubt
    assert guess.as_dict()["doubt"] == guess.doubt
    assert choose_walker(tracks[:1], None, PeopleParams()).doubt == ""  # alone in view: no doubt


def test_a_walker_leaving_and_coming_back_is_one_walker_in_several_tracks():
    walking = schedule(40, WALKER_LEGS, T)
    ego = ego_from(walking, T)
    x = 100 + path(walking, 0.5 * H_PX, 1 / HZ)
    xy = np.column_stack([x, np.full_like(T, 300.0)])
    xy[(T > 15) & (T < 19)] = np.nan  # out of view for 4 s
    tracks, _ = tracks_of({"walker": xy}, np.round(T * 1e9))
    assert len(tracks) == 2
    assert sorted(choose_walker(tracks, ego, PeopleParams()).track_ids) == sorted(t.track_id for t in tracks)


def dressed(image: np.ndarray, pose: PersonPose, shirt, trousers) -> None:
    x0, y0, x1, y1 = pose.box.astype(int)
    mid = (y0 + y1) // 2
    cv2.rectangle(image, (x0, y0), (x1, mid), shirt, -1)
    cv2.rectangle(image, (x0, mid), (x1, y1), trousers, -1)


def test_identities_hold_through_a_crossing_by_their_clothes():
    """Two people walk towards each other along one line and cross: the one in front hides
    the other. Each track keeps its own person on both sides of the crossing; the images
    where the boxes overlap are marked crowded."""
    params = PeopleParams()
    tracker = PersonTracker(params)
    t = np.arange(0, 6, 1 / HZ)
    xa, xb = 200 + 100 * t, 800 - 100 * t  # cross at t = 3 s
    first: dict[str, int] = {}
    crowded_seen = 0
    for i, ti in enumerate(t):
        image = np.full((480, 1000, 3), 90, np.uint8)
        a, b = pose_at(xa[i], 400), pose_at(xb[i], 405)
        dressed(image, b, (40, 160, 40), (200, 200, 40))
        dressed(image, a, (220, 40, 40), (40, 40, 200))  # a walks in front
        # The pose model finds one person where they overlap most.
        people = [a] if abs(xa[i] - xb[i]) < 20 else [a, b]
        for track, pose, others in tracker.update(int(ti * 1e9), image, people):
            who = "a" if pose is a else "b"
            first.setdefault(who, track.track_id)
            assert track.track_id == first[who], f"{who} taken over by track {track.track_id} at {ti:.1f} s"
            crowded_seen += len(others) > 0
    assert len(tracker.tracks) == 2 and crowded_seen > 0


def test_appearance_tells_clothes_apart():
    image = np.full((200, 200, 3), 90, np.uint8)
    p, q = pose_at(50, 150), pose_at(150, 150)
    dressed(image, p, (220, 40, 40), (40, 40, 200))
    dressed(image, q, (40, 160, 40), (200, 200, 40))
    a, b = appearance(image, p.box), appearance(image, q.box)
    shifted = appearance(np.roll(image, 2, axis=1), p.box)
    assert appearance_distance(a, shifted) < 0.2 < 0.8 < appearance_distance(a, b)
    assert appearance_distance(a, None) == 0.5


def test_keypoints_inside_another_persons_box_are_left_out():
    from yowo_cmc.keypoint_input import KeypointFrame
    from yowo_cmc.pose_source import _outside

    frame = KeypointFrame(5, np.array([0, 1, 2]), np.array([[10.0, 10.0], [50.0, 60.0], [12.0, 90.0]]), np.ones(3))
    kept = _outside(frame, np.array([[40.0, 40.0, 80.0, 100.0]]))
    assert kept.ids.tolist() == [0, 2] and kept.stamp_ns == 5
    assert _outside(frame, None) is frame


def test_glimpses_too_short_to_judge_are_the_walkers_only_where_nobody_else_was_seen():
    walking = schedule(40, WALKER_LEGS, T)
    ego = ego_from(walking, T)
    x = 100 + path(walking, 0.5 * H_PX, 1 / HZ)
    xy = np.column_stack([x, np.full_like(T, 300.0)])
    xy[T > 15] = np.nan
    glimpse = np.full_like(xy, np.nan)
    glimpse[(T > 20) & (T < 21)] = [1500.0, 300.0]  # 1 s at the view's edge, half seen: too short to judge
    clothes = {"walker": ((220, 40, 40), (40, 40, 200)), "glimpse": ((40, 160, 40), (200, 200, 40))}
    tracks, names = tracks_of({"walker": xy, "glimpse": glimpse}, np.round(T * 1e9), clothes=clothes)
    assert len(tracks) == 2 and min(t.seconds() for t in tracks) < PeopleParams().min_track_s
    assert len(choose_walker(tracks, ego, PeopleParams()).track_ids) == 2
    # With someone else in view at some time, a glimpse is nobody's.
    other = np.full_like(xy, np.nan)
    other[(T > 1) & (T < 6)] = [1900.0, 420.0]
    clothes["other"] = ((200, 200, 200), (30, 30, 30))
    people = {"walker": xy, "glimpse": glimpse, "other": other}
    tracks, names = tracks_of(people, np.round(T * 1e9), clothes=clothes)
    assert [names[k] for k in choose_walker(tracks, ego, PeopleParams()).track_ids] == ["walker"]


def test_a_bystander_walking_the_walkers_way_later_does_not_move_the_cameras_offset():
    """A bystander who stops and walks as the walker did 2 s earlier agrees at offset +2 s; with
    the walker's own partial agreement there (long stops), a sum over people picked that offset.
    (Seen longer than the walker, such a copy would win: motion alone cannot tell them apart.)"""
    legs = [(8.0, True), (5.0, False), (9.0, True), (4.0, False), (7.0, True), (6.0, False)]
    walking = schedule(40, legs, T)
    ego = ego_from(walking, T)
    walker = np.column_stack([100 + path(walking, 0.5 * H_PX, 1 / HZ), np.full_like(T, 250.0)])
    walker[T > 25] = np.nan
    later = schedule(40, legs, T - 2.0)
    follower = np.column_stack([1900 - path(later, 0.5 * H_PX, 1 / HZ), np.full_like(T, 420.0)])
    follower[T < 12] = np.nan
    clothes = {"walker": ((220, 40, 40), (40, 40, 200)), "follower": ((40, 160, 40), (200, 200, 40))}
    tracks, names = tracks_of({"walker": walker, "follower": follower}, np.round(T * 1e9), clothes=clothes)
    choice = choose_walker(tracks, ego, PeopleParams())
    assert [names[k] for k in choice.track_ids] == ["walker"], choice.summary()
    assert abs(choice.clock_offset_s) < 0.15
