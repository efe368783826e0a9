import networkx as nx
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cmc_synthetic import ceiling_camera, loop_walk, observe
from yowo_cmc.group_sfm import agreement_px, calibrate_groups, geometric_gate_scales
from yowo_cmc.keypoint_tracks import KeypointTrack, TrackParams
from yowo_cmc.params import SfmParams
from yowo_cmc.scene_graph import overlap_score, sample_on_grid, weak_cut_parts
from yowo_common.camera import CameraModel
from yowo_common.geometry import se3
from yowo_eval.metrics import relative_pose_errors

EXACT = SfmParams(tracks=TrackParams(window_s=0.0, gate_px=1e9))


def three_camera_rig(D=None):
    return {
        "a": ceiling_camera(0.3, 0.3, (3.0, 2.5), D=D),
        "b": ceiling_camera(5.7, 0.4, (3.0, 2.5), z=3.3, D=D),
        "c": ceiling_camera(3.0, 4.8, (3.0, 2.3), z=2.8, D=D),
    }


def check_relative(group, cams, pos_tol, rot_tol_deg):
    est = group.T_local_cam
    gt = {n: cams[n][1] for n in est}
    errs, _ = relative_pose_errors(est, gt, {"g": list(est)})
    assert max(e.eps_pos_m for e in errs) < pos_tol
    assert max(e.eps_rot_deg for e in errs) < rot_tol_deg


def test_noise_free_three_camera_rig_is_exact():
    cams = three_camera_rig()
    tracks = observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 20.0)
    result = calibrate_groups(tracks, EXACT)
    assert result.ungrouped == {}
    (group,) = result.groups
    assert sorted(group.names) == ["a", "b", "c"]
    check_relative(group, cams, 1e-6, 1e-6)
    assert max(group.rmse_px.values()) < 1e-6


def test_noisy_distorted_unequal_rates():
    cams = three_camera_rig(D=[-0.2, 0.04, 0, 0, 0])
    tracks = observe(
        cams,
        loop_walk((3.0, 2.5), (2.0, 1.5)),
        40.0,
        rate_hz={"a": 10.0, "b": 15.0, "c": 7.5},
        offsets_s=[0.0, 0.031, 0.057],
        sigma_px=1.0,
        seed=3,
    )
    (group,) = calibrate_groups(tracks).groups
    check_relative(group, cams, 0.03, 0.3)
    assert max(group.rmse_px.values()) < 2.0


def test_two_rooms_split_and_isolated_camera_reported():
    cams = {
        "a1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "a2": ceiling_camera(4.7, 0.3, (2.5, 2.5)),
        "a3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
        "b1": ceiling_camera(10.3, 0.3, (12.5, 2.5)),
        "b2": ceiling_camera(14.7, 4.7, (12.5, 2.5)),
        "iso": ceiling_camera(20.3, 0.3, (22.5, 2.5)),
    }
    room_of = lambda x: "a" if x < 5 else ("b" if 10 <= x < 15 else ("i" if x >= 20 else "-"))  # noqa: E731

    def walk(t):  # 15 s in each room
        base = [2.5, 12.5, 22.5][min(int(t // 15), 2)]
        return loop_walk((base, 2.5), (1.5, 1.5), 7.5)(t)

    tracks = observe(cams, walk, 45.0, sigma_px=0.5, visible=lambda n, xy: room_of(xy[0]) == n[0], seed=1)
    result = calibrate_groups(tracks)
    assert sorted(sorted(g.names) for g in result.groups) == [["a1", "a2", "a3"], ["b1", "b2"]]
    assert set(result.ungrouped) == {"iso"}
    assert "shares no view" in result.ungrouped["iso"]
    for g in result.groups:
        check_relative(g, cams, 0.03, 0.3)


def test_camera_that_never_sees_the_agent():
    cams = three_camera_rig()
    cams["blind"] = ceiling_camera(30.0, 30.0, (35.0, 35.0))
    result = calibrate_groups(observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 20.0, sigma_px=0.5))
    assert result.ungrouped["blind"].startswith("seen in 0 frames")


def test_stationary_agent_does_not_drive_initial_pair():
    """A long stop seen only by a and b gives that pair the most inliers, but all at one
    spot; the overlap-based match score (eq. match) prefers the well-spread pair."""
    cams = {
        "a": ceiling_camera(0.3, 0.3, (3.0, 2.5)),
        "b": ceiling_camera(1.0, 0.2, (1.2, 1.2), hfov=60),
        "c": ceiling_camera(5.7, 4.7, (3.0, 2.5)),
    }
    loop = loop_walk((3.0, 2.5), (2.0, 1.5))

    def walk(t):
        return np.array([1.2, 1.2]) if t < 60 else loop(t)

    vis = {"a": lambda xy: True, "b": lambda xy: True, "c": lambda xy: np.linalg.norm(xy - [1.2, 1.2]) > 0.5}
    tracks = observe(cams, walk, 80.0, sigma_px=0.5, visible=lambda n, xy: vis[n](xy), seed=2)
    result = calibrate_groups(tracks)
    pairs = {tuple(sorted((result.groups[0].initial_pair)))}
    inliers = {(tracks[p.a].name, tracks[p.b].name): p.num_inliers for p in result.pairs}
    assert inliers[("a", "b")] > inliers[("a", "c")]  # the trap is real
    assert pairs == {("a", "c")}
    check_relative(result.groups[0], cams, 0.03, 0.3)


def test_overlap_score_prefers_spread():
    cam = CameraModel.from_fov(640, 480, 80)
    params = SfmParams()
    clustered = np.full((100, 2), 320.0)
    spread = np.random.default_rng(0).uniform([0, 0], [640, 480], (30, 2))
    assert overlap_score(clustered, cam, params) == 0.0
    assert overlap_score(spread, cam, params) > 10.0


def test_camera_seeing_through_a_doorway_does_not_merge_two_rooms():
    """b1 sees room a only through a 1 m doorway: many matches with a1-a3, all in one
    strip of its image. Such edges must not join the rooms (without the overlap gate the
    merged group cannot even register room a's cameras)."""
    cams = {
        "a1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "a2": ceiling_camera(4.7, 0.3, (2.5, 2.5)),
        "a3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
        "b1": ceiling_camera(9.7, 2.5, (6.5, 2.5)),
        "b2": ceiling_camera(5.3, 4.7, (7.5, 2.5)),
        "b3": ceiling_camera(7.5, 0.3, (7.5, 2.5)),
    }

    def walk(t):  # 20 s in room a (x < 5, passing the doorway), then 20 s in room b
        return loop_walk((2.7, 2.5), (2.2, 1.5), 10.0)(t) if t < 20 else loop_walk((7.5, 2.5), (1.5, 1.5), 10.0)(t)

    def visible(name, xy):
        if name[0] == "b" and xy[0] < 5:
            return name == "b1" and 2.0 <= xy[1] <= 3.0
        return (xy[0] < 5) == (name[0] == "a")

    tracks = observe(cams, walk, 40.0, sigma_px=0.5, visible=visible, seed=2)
    result = calibrate_groups(tracks)
    door = [p for p in result.pairs if p.b == 3 and p.a < 3]
    assert all(p.num_inliers >= 50 and min(p.overlap) < 1.0 for p in door)  # strong in count, weak in cover
    assert sorted(sorted(g.names) for g in result.groups) == [["a1", "a2", "a3"], ["b1", "b2", "b3"]]
    for g in result.groups:
        check_relative(g, cams, 0.03, 0.3)
    merged = calibrate_groups(tracks, SfmParams(min_edge_overlap=0.0))
    assert sum(len(g.names) for g in merged.groups) < 6


def test_rooms_joined_by_a_weak_cut_are_split():
    """Two rooms of three cameras (~1000 inliers per camera pair) joined by doorway glimpses
    (two edges of 60): two parts; joined as strongly as within a room: one. A camera that
    shares less with its room's others (300 against 1000) is not cut off, nor is a lone
    room ever split, and 0 switches the rule off."""

    def rooms(join: float, n_join: int = 2) -> nx.Graph:
        G = nx.Graph()
        for room in "ab":
            G.add_weighted_edges_from(
                [(f"{room}1", f"{room}2", 1000), (f"{room}1", f"{room}3", 1100), (f"{room}2", f"{room}3", 900)]
            )
        G.add_weighted_edges_from([("a1", "b1", join), ("a3", "b2", join)][:n_join])
        return G

    assert sorted(sorted(p) for p in weak_cut_parts(rooms(60), 0.1)) == [["a1", "a2", "a3"], ["b1", "b2", "b3"]]
    assert [len(p) for p in weak_cut_parts(rooms(800), 0.1)] == [6]
    assert [len(p) for p in weak_cut_parts(rooms(60), 0.0)] == [6]
    G = nx.complete_graph(["c1", "c2", "c3", "c4"])
    nx.set_edge_attributes(G, 1000, "weight")
    for other in ("c1", "c2", "c3"):
        G["c4"][other]["weight"] = 300
    assert [len(p) for p in weak_cut_parts(G, 0.1)] == [4]
    # Three rooms in a row: both doorways cut.
    G = rooms(60)
    G.add_weighted_edges_from(
        [("c1", "c2", 1000), ("c1", "c3", 1000), ("c2", "c3", 1000), ("b3", "c1", 50), ("b2", "c3", 50)]
    )
    assert sorted(sorted(p) for p in weak_cut_parts(G, 0.1)) == [
        ["a1", "a2", "a3"],
        ["b1", "b2", "b3"],
        ["c1", "c2", "c3"],
    ]


def test_cameras_chained_by_single_edges_still_pair_up():
    """c1 and c3 see different halves of the room, c2 all of it: a chain c1 - c2 - c3 has
    no two paths between members; with pair_leftovers its strongest edge makes a
    two-camera group (the third camera is left for the isolated registration, with the reason)."""
    cams = {
        "c1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "c2": ceiling_camera(4.7, 0.3, (2.5, 2.5)),
        "c3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
    }
    halves = {"c1": lambda xy: xy[0] < 2.3, "c2": lambda xy: True, "c3": lambda xy: xy[0] > 2.7}
    tracks = observe(
        cams, loop_walk((2.5, 2.5), (1.5, 1.2), 10.0), 30.0, sigma_px=0.5, visible=lambda n, xy: halves[n](xy), seed=5
    )
    assert calibrate_groups(tracks).groups == []  # the paper's rule (default)
    result = calibrate_groups(tracks, SfmParams(pair_leftovers=True))
    (group,) = result.groups
    assert "c2" in group.names and len(group.names) == 2
    (left,) = set(cams) - set(group.names)
    assert result.ungrouped == {left: "joined to a group by a single camera pair (needs two paths to its members)"}
    check_relative(group, cams, 0.03, 0.3)


def test_weak_detections_are_down_weighted_in_the_bundle_adjustment():
    """The image detector's ground point from the feet alone (head out of view) is rated
    0.3x a full detection and biased by several pixels. Its sigma is scaled by the
    confidence ratio, which must pull the poses back towards the truth."""
    from dataclasses import replace

    from yowo_cmc.keypoint_tracks import KeypointTrack, sigma_factors

    cams = three_camera_rig()
    tracks = observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 40.0, sigma_px=1.0, seed=5)
    rng = np.random.default_rng(7)
    for i, cam in enumerate(tracks):
        g = cam.tracks[1]
        weak = np.sin((g.stamps_ns - g.stamps_ns[0]) / 1e9 * 0.9 + 2 * i) > 0.1  # stretches, as when the head leaves
        bias = rng.normal(0, 1, 2)
        uv = g.uv + np.outer(weak, 7.0 * bias / np.linalg.norm(bias))
        conf = np.where(weak, 0.27, g.confidence)
        cam.tracks[1] = KeypointTrack(g.stamps_ns, uv, conf)
    factors = sigma_factors(tracks[0].tracks[1], tracks[0].tracks[1].stamps_ns, TrackParams())
    assert np.allclose(factors[tracks[0].tracks[1].confidence == 0.27], 0.9 / 0.27)
    assert np.all(factors[tracks[0].tracks[1].confidence == 0.9] == 1.0)

    def rotation_error(params):
        (group,) = calibrate_groups(tracks, params).groups
        errs, _ = relative_pose_errors(
            group.T_local_cam, {n: cams[n][1] for n in group.T_local_cam}, {"g": list(group.T_local_cam)}
        )
        return np.mean([e.eps_rot_deg for e in errs])

    weighted = rotation_error(SfmParams())
    unweighted = rotation_error(SfmParams(tracks=replace(TrackParams(), weak_confidence_ratio=0.0)))
    assert weighted < 0.6 * unweighted, (weighted, unweighted)


def test_each_keypoint_ids_sigma_is_re_estimated_until_it_settles():
    """Real pose keypoints differ in noise by an order of magnitude across ids. The group
    BA's per-id sigmas come from the residuals of a BA weighted by the previous estimate;
    one re-estimate from the first, equally weighted round is pulled towards the noisy id
    (its residuals bend the poses every id is measured against). What the weighting needs
    is the ratio between ids (the residuals' own spread is below the noise by a common
    factor: each point is fitted to its observations)."""
    cams = three_camera_rig()
    walk = loop_walk((3.0, 2.5), (2.0, 1.5))
    clean, noisy = observe(cams, walk, 30.0, sigma_px=0.3, seed=7), observe(cams, walk, 30.0, sigma_px=6.0, seed=8)
    for c, n in zip(clean, noisy):
        c.tracks[1] = n.tracks[1]  # head top at 0.3 px, ground point at 6 px: ratio 20
    unsmoothed = TrackParams(window_s=0.0, gate_px=1e9)
    # The rounds alone, with the gates held (geometric_gates would reconstruct again at wider ones).
    (group,) = calibrate_groups(clean, SfmParams(tracks=unsmoothed, geometric_gates=False)).groups
    assert abs(group.sigma_px_by_id[1] / group.sigma_px_by_id[0] / 20.0 - 1) < 0.1
    check_relative(group, cams, 0.003, 0.06)
    (once,) = calibrate_groups(clean, SfmParams(tracks=unsmoothed, sigma_rounds=2, geometric_gates=False)).groups
    assert once.sigma_px_by_id[1] / once.sigma_px_by_id[0] < 0.85 * 20.0


def test_ids_of_one_keypoint_class_share_one_sigma():
    """Sigmas are estimated per keypoint class (cmc.sfm.sigma_class_bounds: hands are ids
    100-499), not per id: a seated person's id carries one view-dependent error in every frame,
    too few numbers for a sigma of its own. Two hand ids at 3 px share the class's sigma, 10x
    the head top's (0.3 px)."""
    cams = three_camera_rig()
    walk = loop_walk((3.0, 2.5), (2.0, 1.5))
    clean, noisy = observe(cams, walk, 30.0, sigma_px=0.3, seed=7), observe(cams, walk, 30.0, sigma_px=3.0, seed=8)
    for c, n in zip(clean, noisy):
        c.tracks[102], c.tracks[103] = n.tracks[0], n.tracks[1]
    (group,) = calibrate_groups(clean, SfmParams(tracks=TrackParams(window_s=0.0, gate_px=1e9))).groups
    sigma = group.sigma_px_by_id
    assert sigma[102] == sigma[103]
    assert abs(sigma[102] / sigma[0] / 10.0 - 1) < 0.15, sigma
    check_relative(group, cams, 0.003, 0.06)


def with_biased_body_joints(cams, walk, tracks, bias_px: float, seed: int):
    """Adds body joints (ids 2-4: shoulders, hip) to each camera's tracks, each with an error of
    bias_px per axis that is constant in time and differs between views (as a pose model's are)."""
    rng = np.random.default_rng(seed)
    for ct in tracks:
        cam, T = cams[ct.name]
        stamps = ct.tracks[0].stamps_ns
        xy = np.array([walk(t) for t in (stamps - stamps[0]) / 1e9])
        for kid, (dx, z) in {2: (0.2, 1.4), 3: (-0.2, 1.4), 4: (0.0, 1.0)}.items():
            uv, front = cam.project_world(T, np.column_stack([xy[:, 0] + dx, xy[:, 1], np.full(len(xy), z)]))
            ok = front & cam.in_image(uv)
            uv = uv + rng.normal(size=2) * bias_px + rng.normal(size=uv.shape) * 0.3
            ct.tracks[kid] = KeypointTrack(stamps[ok], uv[ok], np.full(ok.sum(), 0.9))
    return tracks


def test_a_noisier_keypoint_class_gets_wider_gates_in_a_second_reconstruction():
    """Body joints whose views disagree by ~8 px (constant per view) measure a class sigma above
    the nominal 1.5 px; the group is reconstructed again with their gates widened by
    sigma / 1.5 and keeps far more of their views, the poses as exact as before. The guard:
    new poses that explain the first reconstruction's points worse than max_agreement_ratio
    times are not taken (ratio 0 rejects any)."""
    cams = three_camera_rig()
    walk = loop_walk((3.0, 2.5), (2.0, 1.5))
    tracks = with_biased_body_joints(cams, walk, observe(cams, walk, 30.0, sigma_px=0.3, seed=7), 8.0, seed=0)
    (wide,) = calibrate_groups(tracks).groups
    (nominal,) = calibrate_groups(tracks, SfmParams(geometric_gates=False)).groups
    (rejected,) = calibrate_groups(tracks, SfmParams(max_agreement_ratio=0.0)).groups
    assert sorted(wide.gate_scales) == [2, 3, 4] and len(set(wide.gate_scales.values())) == 1
    assert wide.gate_scales[2] > 1.5
    assert nominal.gate_scales == {} and rejected.gate_scales == {}
    assert sum(wide.num_observations.values()) > 1.3 * sum(nominal.num_observations.values())
    check_relative(wide, cams, 0.003, 0.06)
    for n in nominal.T_local_cam:
        np.testing.assert_allclose(rejected.T_local_cam[n], nominal.T_local_cam[n], atol=1e-12)
    # Keypoints at the nominal noise (the simulator's) never trigger the second reconstruction.
    (clean,) = calibrate_groups(observe(cams, walk, 30.0, sigma_px=1.0, seed=7)).groups
    assert clean.gate_scales == {}


def test_gates_widen_only_for_classes_clearly_above_the_nominal_noise():
    sigmas = {0: 1.0, 1: 1.52, 2: 1.79, 3: 1.8, 4: 4.5}  # nominal 1.5 px, min_gate_scale 1.2: from 1.8 px
    assert geometric_gate_scales(sigmas, SfmParams()) == {3: pytest.approx(1.2), 4: pytest.approx(3.0)}
    assert geometric_gate_scales(sigmas, SfmParams(min_gate_scale=1.0)) == {
        1: pytest.approx(1.52 / 1.5),
        2: pytest.approx(1.79 / 1.5),
        3: pytest.approx(1.2),
        4: pytest.approx(3.0),
    }
    assert geometric_gate_scales({0: 1.0, 1: 1.6}, SfmParams()) == {}


def test_agreement_rises_when_a_camera_is_turned():
    """The guard's measure: the median reprojection residual of the agent points triangulated
    with a group's poses; one camera turned by 2 degrees raises it several-fold."""
    cams = three_camera_rig()
    tracks = observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 20.0, sigma_px=0.5, seed=2)
    (group,) = calibrate_groups(tracks).groups
    obs = sample_on_grid(tracks, SfmParams().tracks)
    keys = np.array(sorted(set(obs.per_camera[0]) | set(obs.per_camera[1])), dtype=np.int64)
    good = agreement_px(obs, keys, group)
    turn = se3(Rotation.from_euler("y", 2.0, degrees=True).as_matrix(), np.zeros(3))
    group.T_local_cam["b"] = group.T_local_cam["b"] @ turn
    assert 0.1 < good < 0.5
    assert agreement_px(obs, keys, group) > 5 * good
