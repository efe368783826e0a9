"""Everyone in view as evidence (yowo_cmc.people_identity): people matched across cameras
by their epipolar consistency, then the group SfM on all of them."""

import numpy as np

from cmc_synthetic import ceiling_camera, loop_walk, observe
from yowo_cmc.group_sfm import calibrate_groups
from yowo_cmc.params import SfmParams
from yowo_cmc.people_identity import WALKER, match_people
from yowo_cmc.scene_graph import PERSON_STRIDE
from yowo_eval.metrics import relative_pose_errors

CAMS = {
    "a": ceiling_camera(0.3, 0.3, (3.0, 2.5)),
    "b": ceiling_camera(5.7, 0.4, (3.0, 2.5), z=3.3),
    "c": ceiling_camera(3.0, 4.8, (3.0, 2.3), z=2.8),
}
PEOPLE = {
    # A short loop in one corner: alone, it pins the cameras' poses poorly.
    "walker": loop_walk((2.0, 1.8), (0.6, 0.4), period_s=12.0),
    "crossing": loop_walk((3.2, 2.6), (2.0, 1.4), period_s=17.0),
    "standing": lambda t: np.array([4.3, 3.4]),
}
# Each camera's own numbering of the people it sees; in c its tracker took the walking
# bystander for the walker (person 0), as a camera without the ego camera's evidence may.
LOCAL = {
    "a": {0: "walker", 1: "crossing", 2: "standing"},
    "b": {0: "walker", 1: "standing", 2: "crossing"},
    "c": {0: "crossing", 1: "walker", 2: "standing"},
}


def views(sigma_px=0.7):
    seen = {who: observe(CAMS, walk, 24.0, sigma_px=sigma_px, seed=i) for i, (who, walk) in enumerate(PEOPLE.items())}
    return {c: {k: next(t for t in seen[who] if t.name == c) for k, who in LOCAL[c].items()} for c in CAMS}


def relative_error(group):
    errs, _ = relative_pose_errors(group.T_local_cam, {n: CAMS[n][1] for n in group.names}, {"g": group.names})
    return max(e.eps_pos_m for e in errs), max(e.eps_rot_deg for e in errs)


def test_people_are_matched_across_cameras_whoever_each_tracker_took_for_the_walker():
    identity = match_people(views(), SfmParams())
    # One shared person per true person, consistent in all three cameras.
    for who in PEOPLE:
        shared = {identity.people[c][k] for c in CAMS for k, w in LOCAL[c].items() if w == who}
        assert len(shared) == 1, (who, identity.as_dict())
    assert len({identity.people["a"][k] for k in LOCAL["a"]}) == 3
    # The standing person matched under a walking pair's geometry, never as a seed.
    standing = [m for m in identity.matches if LOCAL[m.camera_a][m.person_a] == "standing"]
    assert standing and not any(m.seed for m in standing)
    assert all(m.inliers >= 0.8 * m.keypoints for m in identity.matches)
    # Every camera's tracks hold each person's joints apart.
    for t in identity.tracks:
        assert {i // PERSON_STRIDE for i in t.tracks} == {0, 1, 2}
    assert "3 people matched" in identity.summary()


def test_everyone_calibrates_better_than_the_walker_alone():
    v = views()
    alone = calibrate_groups([v[c][next(k for k, w in LOCAL[c].items() if w == "walker")] for c in CAMS])
    everyone = calibrate_groups(match_people(v, SfmParams()).tracks)
    (g_alone,), (g_all,) = alone.groups, everyone.groups
    pos_alone, rot_alone = relative_error(g_alone)
    pos_all, rot_all = relative_error(g_all)
    assert pos_all < 0.7 * pos_alone and rot_all < rot_alone
    assert pos_all < 0.01 and rot_all < 0.2


def test_one_person_per_camera_is_left_as_it_is():
    v = {c: {WALKER: p[WALKER]} for c, p in views().items()}
    identity = match_people(v, SfmParams())
    assert identity.people == {} and identity.matches == []
    assert [t.tracks for t in identity.tracks] == [v[c][WALKER].tracks for c in v]


def test_people_who_never_move_are_not_matched_by_guess():
    """Two people standing still: any pairing fits some epipolar geometry, so none is made."""
    still = {"p": lambda t: np.array([2.0, 2.0]), "q": lambda t: np.array([4.0, 3.0])}
    seen = {who: observe(CAMS, walk, 10.0, sigma_px=0.5, seed=i) for i, (who, walk) in enumerate(still.items())}
    v = {c: {0: next(t for t in seen["p"] if t.name == c), 1: next(t for t in seen["q"] if t.name == c)} for c in CAMS}
    identity = match_people(v, SfmParams())
    assert identity.people == {}
    assert [t.name for t in identity.tracks] == list(CAMS)
