"""CMC clock offsets from the agent's motion (yowo_cmc.clock): synthetic views with known
offsets, and a simulated recording with unsynchronised clocks."""

from dataclasses import replace

import numpy as np
import pytest

from cmc_synthetic import ceiling_camera, loop_walk, observe
from yowo_cmc.clock import ClockParams, combine, estimate_clock_offsets
from yowo_cmc.clock_pairs import PairOffset
from yowo_cmc.config import CmcParams
from yowo_cmc.group_sfm import calibrate_groups
from yowo_cmc.keypoint_tracks import interpolate
from yowo_cmc.pipeline import calibrate_cmcs
from yowo_common.geometry import inv_se3, rotation_angle_deg

D = [-0.1, 0.02, 0.0, 0.0, 0.0]
CAMS = {
    "a": ceiling_camera(0.3, 0.3, (3.0, 2.5), D=D),
    "b": ceiling_camera(5.7, 0.4, (3.0, 2.5), z=3.3, D=D),
    "c": ceiling_camera(3.0, 4.8, (3.0, 2.3), z=2.8, D=D),
    "d": ceiling_camera(5.5, 4.6, (3.0, 2.5), z=3.1, D=D),
}
# Not multiples of the 0.1 s frame period; b-c and c-d are 1.35 s and 1.91 s apart.
OFFSETS = {"a": 0.0, "b": 0.437, "c": -0.9132, "d": 1.0}
PHASES = [0.0, 0.031, 0.067, 0.05]  # the cameras' frames are not simultaneous either


def views(offsets, sigma_px=0.0, seed=0, cams=CAMS, walk=None, visible=None):
    tracks = observe(
        cams,
        walk or loop_walk((3.0, 2.5), (2.0, 1.5)),
        40.0,
        offsets_s=PHASES[: len(cams)],
        sigma_px=sigma_px,
        seed=seed,
        visible=visible,
    )
    # Each camera's clock runs its offset ahead: its stamps are later by as much.
    return [c.shifted(-offsets.get(c.name, 0.0)) for c in tracks]


def errors_ms(est, truth):
    """Each camera's error [ms] relative to its reference camera's true offset."""
    return {n: (c.offset_s - (truth[n] - truth[c.reference])) * 1e3 for n, c in est.cameras.items()}


def test_noise_free_offsets_are_recovered_to_a_fraction_of_a_millisecond():
    est = estimate_clock_offsets(views(OFFSETS))
    assert {c.reference for c in est.cameras.values()} == {"a"}
    err = errors_ms(est, OFFSETS)
    assert max(abs(e) for e in err.values()) < 0.5, err
    assert all(p.used for p in est.pairs) and len(est.pairs) == 6
    assert all(c.sigma_s < 1e-3 for c in est.cameras.values())


def test_zero_offsets_give_zero():
    est = estimate_clock_offsets(views({}))
    assert max(abs(c.offset_s) for c in est.cameras.values()) < 0.5e-3


def test_pixel_noise_gives_millisecond_offsets_and_honest_sigmas():
    normalised = []
    for seed in range(2):
        est = estimate_clock_offsets(views(OFFSETS, sigma_px=1.0, seed=seed))
        err = errors_ms(est, OFFSETS)
        assert max(abs(e) for e in err.values()) < 5.0, err
        for n, c in est.cameras.items():
            assert c.sigma_s < 3e-3
            if n != c.reference:
                normalised.append(err[n] / (c.sigma_s * 1e3))
    # The sigmas are neither wildly optimistic nor wildly pessimistic.
    assert 0.3 < np.sqrt(np.mean(np.square(normalised))) < 2.0, normalised


def test_a_two_camera_groups_refined_offset_has_an_honest_sigma():
    """The group refinement's sigma counts the unknowns fitted to its residuals: a point
    seen by two cameras keeps 1 of its 4 residual dof, so the residuals' spread alone was
    half the noise: normalised errors RMS 1.39 on these seeds (1.65 over 24; 2.8 on the
    simulator's recordings), enough for a synchronised pair to get a "significant" offset."""
    normalised = []
    for seed in range(12):
        grouping = calibrate_cmcs(views(OFFSETS, sigma_px=1.0, seed=seed, cams={k: CAMS[k] for k in "ab"}))
        (group,) = grouping.groups
        (member,) = [n for n in group.names if n != group.reference]
        truth = OFFSETS[member] - OFFSETS[group.reference]
        normalised.append((group.clock_offsets_s[member] - truth) / group.clock_sigmas_s[member])
    assert 0.5 < np.sqrt(np.mean(np.square(normalised))) < 1.3, normalised


def test_an_agent_that_barely_moves_gives_no_offset():
    """An agent swaying 2 cm on the spot, keypoints with 2 px noise: no shift fits clearly
    better than the others (caliscope's seated person). Without the prominence check the
    cost curve's lowest dip became offsets that are wrong by 70-800 ms."""
    raw = views(OFFSETS, sigma_px=2.0, seed=1, walk=loop_walk((3.0, 2.5), (0.02, 0.02)))
    est = estimate_clock_offsets(raw)
    assert all(p.offset_s is None and p.reason.startswith("no clear minimum over the shifts") for p in est.pairs)
    assert all(c.offset_s is None for c in est.cameras.values())
    unchecked = estimate_clock_offsets(raw, ClockParams(min_prominence=0.0))
    wrong = [abs(p.offset_s - (OFFSETS[p.b] - OFFSETS[p.a])) for p in unchecked.pairs if p.offset_s is not None]
    assert wrong and max(wrong) > 0.05, wrong


def test_a_clock_no_pair_pins_is_not_refined():
    """The group refinement corrects clocks the pairs estimated; it does not create offsets
    where every pair of a camera found no clear minimum (a seated person's view-dependent
    keypoint errors then look like a 2-5 sigma offset). Offsets of 30-60 ms, within the
    refinement's reach: found when the pairs pin them, kept at 0 when no pair counts."""
    small = {"a": 0.0, "b": 0.031, "c": -0.047, "d": 0.058}
    raw = views(small, sigma_px=1.0)
    (pinned,) = calibrate_cmcs(raw).groups
    truth = {n: small[n] - small[pinned.reference] for n in CAMS}
    assert all(abs(pinned.clock_offsets_s[n] - truth[n]) < 5e-3 for n in CAMS), (pinned.clock_offsets_s, truth)
    refused = replace(CmcParams(), clock=replace(ClockParams(), min_prominence=1e9))
    (unpinned,) = calibrate_cmcs(raw, refused).groups
    assert all(v == 0.0 for v in unpinned.clock_offsets_s.values()), unpinned.clock_offsets_s


def test_camera_that_never_coobserves_has_no_estimate():
    cams = {**{k: CAMS[k] for k in "abc"}, "iso": ceiling_camera(20.3, 0.3, (22.5, 2.5))}

    def walk(t):  # 25 s in the room of a, b, c; 5 s in a corridor nobody sees; then in iso's room
        return (
            loop_walk((3.0, 2.5), (2.0, 1.5))(t)
            if t < 25.0
            else np.array([12.0, 2.5])
            if t < 30.0
            else np.array([22.5, 2.5])
        )

    def visible(name, xy):  # walls: each room's cameras see only their room
        return xy[0] > 15.0 if name == "iso" else xy[0] < 10.0

    est = estimate_clock_offsets(views({"b": 0.25, "iso": 0.6}, walk=walk, cams=cams, visible=visible))
    iso = est.cameras["iso"]
    assert iso.offset_s is None and iso.sigma_s is None and iso.reference is None
    assert "no pair" in iso.reason
    assert est.cameras["b"].reference == "a" and abs(est.cameras["b"].offset_s - 0.25) < 0.5e-3
    assert not any("iso" in (p.a, p.b) for p in est.pairs)  # no search where nobody co-observes


def test_inconsistent_pair_is_dropped():
    truth = {"a": 0.0, "b": 0.2, "c": -0.3, "d": 0.45}
    names = list(truth)
    pairs = [
        PairOffset(a=x, b=y, offset_s=truth[y] - truth[x], sigma_s=0.002, correspondences=500, rms_px=1.0)
        for i, x in enumerate(names)
        for y in names[i + 1 :]
    ]
    pairs[1].offset_s += 0.1  # a - c: a wrong minimum a frame away
    out = combine(names, pairs, ClockParams())
    assert not pairs[1].used and "inconsistent" in pairs[1].reason
    assert all(p.used for k, p in enumerate(pairs) if k != 1)
    for n in names:
        assert out[n].offset_s == pytest.approx(truth[n], abs=1e-9)


@pytest.mark.parametrize("preset_seed", [2])
def test_simulated_recording_with_unsynchronised_clocks(tmp_path, preset_seed):
    """A tiny recording, keypoints only, CMC clocks up to +-1 s off: through the offline
    reader, against the recording's ground truth. Its 8 s walk at 320x240 holds far less
    of the agent's motion than the synthetic views (pair sigmas 5-20 ms): the check is the
    stated sigma and less than half a frame period (the frames still pair up right)."""
    from yowo_bringup.offline import read_cmc_tracks
    from yowo_common.ros.bag import read_messages
    from yowo_common.topics import gt_cmc_clock_offset_topic
    from yowo_sim.capture import generate
    from yowo_sim.presets import get_preset

    bag = tmp_path / "tiny"
    summary = generate(replace(get_preset("tiny"), cmc_images=False, cmc_clock_offset_s=1.0), preset_seed, bag)
    wanted = {gt_cmc_clock_offset_topic(c.name): c.name for c in summary.cmcs}
    truth = {wanted[t]: m.data for t, _, m in read_messages(bag, wanted)}
    est = estimate_clock_offsets(read_cmc_tracks(bag, "keypoints"))
    assert all(c.offset_s is not None for c in est.cameras.values()), est.cameras
    err = errors_ms(est, truth)
    for n, c in est.cameras.items():
        assert abs(err[n]) <= max(3.0, 4 * c.sigma_s * 1e3) and abs(err[n]) < 40.0, (n, err, c)


def relative_rotation_errors_deg(grouping) -> dict[str, float]:
    errors = {}
    for g in grouping.groups:
        for n in g.names:
            T_true = inv_se3(CAMS[g.reference][1]) @ CAMS[n][1]
            errors[n] = rotation_angle_deg(T_true[:3, :3], g.T_local_cam[n][:3, :3])
    return errors


def test_the_group_sfm_calibrates_on_corrected_stamps_as_if_synchronised():
    """Offsets up to 1.9 s apart: estimated, applied, refined with the group's geometry;
    the relative rotations are those of the synchronised recording, the points are on the
    reference camera's clock."""
    synced = relative_rotation_errors_deg(calibrate_groups(views({}, sigma_px=1.0)))
    raw = views(OFFSETS, sigma_px=1.0)
    grouping = calibrate_cmcs(raw)
    (g,) = grouping.groups
    assert sorted(g.names) == sorted(CAMS) and g.clocks_applied
    for n in CAMS:
        true = OFFSETS[n] - OFFSETS[g.reference]
        assert abs(g.clock_offsets_s[n] - true) < max(3e-3, 4 * g.clock_sigmas_s[n]), (n, g.clock_offsets_s, true)
        assert (g.clock_sigmas_s[n] == 0.0) == (n == g.reference) and g.clock_sigmas_s[n] < 3e-3
    errors = relative_rotation_errors_deg(grouping)
    assert all(errors[n] < synced[n] + 0.03 for n in CAMS), (errors, synced)
    # The points' stamps are the reference camera's: projected into it (its frame is the
    # group's), they land where its own track was at those stamps.
    (ref,) = [c for c in raw if c.name == g.reference]
    for kp_id, track in ref.tracks.items():
        sel = g.point_ids == kp_id
        uv, ok = interpolate(track, g.point_stamps_ns[sel], 2 * ref.frame_period_ns)
        proj, _ = ref.camera.project(g.points[sel])
        assert ok.sum() > 50 and np.median(np.linalg.norm(proj[ok] - uv[ok], axis=1)) < 2.0, kp_id
    # Only reported, not applied: the raw stamps pair up wrong instants.
    reported = calibrate_cmcs(raw, replace(CmcParams(), clock=ClockParams(apply=False)))
    assert not any(g.clocks_applied for g in reported.groups)
    assert max(relative_rotation_errors_deg(reported).values(), default=90.0) > 1.0


def rooms_one_after_the_other():
    """Three cameras in room A, two in room B, whose clocks run 1.3 s behind A's."""
    cams = {
        "a1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "a2": ceiling_camera(4.7, 0.3, (2.5, 2.5), z=3.4),
        "a3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
        "b1": ceiling_camera(10.3, 0.3, (12.5, 2.5)),
        "b2": ceiling_camera(14.7, 4.7, (12.5, 2.5)),
    }

    def walk(t):  # a different loop in each room (a copy of one loop would fit at some shift: a mirror world)
        return loop_walk((2.5, 2.5), (1.5, 1.2), 10.0)(t) if t < 20 else loop_walk((12.5, 2.5), (1.0, 1.6), 7.0)(t)

    room = {"a": lambda x: x < 5, "b": lambda x: x > 10}
    tracks = observe(
        cams,
        walk,
        40.0,
        sigma_px=0.7,
        visible=lambda n, xy: room[n[0]](xy[0]),
        seed=4,
        offsets_s=[0.0, 0.03, 0.05, 0.01, 0.07],
    )
    return [t.shifted(1.3 if t.name.startswith("b") else 0.0) for t in tracks]


def test_rooms_walked_one_after_the_other_stay_apart_when_their_clocks_differ():
    """Room B's cameras run 1.3 s behind room A's. No camera sees both rooms, so their
    offset is unknown: no pair across the rooms is trusted (the end of one room's walk
    fits the start of the other's at some shift), and the rooms are not matched."""
    behind = rooms_one_after_the_other()
    grouping = calibrate_cmcs(behind)
    assert sorted(sorted(g.names) for g in grouping.groups) == [["a1", "a2", "a3"], ["b1", "b2"]]
    est = estimate_clock_offsets(behind)
    assert {c.reference for n, c in est.cameras.items() if n.startswith("a")} != {
        c.reference for n, c in est.cameras.items() if n.startswith("b")
    }


def test_offsets_within_their_noise_of_zero_are_not_applied():
    """Synchronised cameras: the estimated offsets are noise (a fraction of a millisecond
    here; a frame period on a real recording of a person barely moving), so the group SfM
    runs on the stamps as recorded, exactly as without the clock stage."""
    raw = views({}, sigma_px=1.0, seed=5)
    grouping = calibrate_cmcs(raw)
    (g,) = grouping.groups
    assert all(g.clock_offsets_s[n] == 0.0 for n in CAMS) and all(
        0 < g.clock_sigmas_s[n] < 3e-3 for n in CAMS if n != g.reference
    )
    (synced,) = calibrate_groups(raw).groups
    assert all(np.array_equal(g.T_local_cam[n], synced.T_local_cam[n]) for n in CAMS)
    (applied,) = calibrate_cmcs(raw, replace(CmcParams(), clock=ClockParams(min_significance=0.0))).groups
    assert any(applied.clock_offsets_s[n] != 0.0 for n in CAMS)


@pytest.mark.parametrize("case", ["noisy", "rooms"])
def test_the_coarse_to_fine_search_keeps_the_minimum_of_the_full_search(case):
    """The cheap first pass (ClockParams.search_*) leaves the full cost to a few windows:
    every pair ends where the full cost at every shift of the grid takes it (the same
    offsets, the same reasons), also across rooms walked one after the other, where the
    wrong shifts that fit some stretch of the walk are what the search must rank right."""
    raw = views(OFFSETS, sigma_px=1.0, seed=1) if case == "noisy" else rooms_one_after_the_other()
    full = estimate_clock_offsets(raw, ClockParams(search_candidates=0))
    fast = estimate_clock_offsets(raw)
    assert len(fast.pairs) == len(full.pairs) >= 6
    for p, q in zip(fast.pairs, full.pairs):
        assert (p.a, p.b, p.offset_s, p.sigma_s, p.reason) == (q.a, q.b, q.offset_s, q.sigma_s, q.reason)
    assert any(p.offset_s is not None for p in fast.pairs)
