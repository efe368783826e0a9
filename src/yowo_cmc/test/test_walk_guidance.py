"""Guidance during the walk (issue #48, part 3): the coverage of every camera on the keypoints
received so far names a camera that saw the agent only in one corner of its image with that
corner, calls a well covered one ok, is the same whether updated often or once, and survives
the trip through yowo_msgs/WalkGuidance."""

import math

import numpy as np

from yowo_cmc.coverage import FROM_RECEIVED, NEEDS_MORE, OK
from yowo_cmc.group_sfm import CameraGroupResult, GroupingResult
from yowo_cmc.messages import guidance_from_msg, guidance_to_msg
from yowo_cmc.walk_guidance import NO_CAMERA_INFO, NOTHING_YET, WalkGuide
from yowo_common.camera import CameraModel
from yowo_msgs.msg import CameraGuidance

CAMERA = CameraModel(640, 480, np.array([[400.0, 0, 319.5], [0, 400.0, 239.5], [0, 0, 1]]))
IDS = 5  # keypoints per frame
PERIOD_NS = 100_000_000


def _frames(t_s: np.ndarray, u: np.ndarray, v: np.ndarray):
    """(stamp, uv) per frame: a skeleton of IDS keypoints around (u, v)."""
    for t, a, b in zip(t_s, u, v):
        yield int(round(t * 1e9)), np.array([[a + 3 * k, b + 4 * k] for k in range(IDS)])


def _walk():
    """'wide' sees the agent all over its image for 40 s; 'corner' only in its top-left
    corner from 10 s to 30 s (both at 10 Hz); 'blind' sees frames but never the agent."""
    t = np.arange(0, 400) * 0.1
    wide = _frames(t, 320 + 270 * np.sin(2 * np.pi * t / 20), 240 + 200 * np.sin(2 * np.pi * t / 13))
    tc = t[100:300]
    corner = _frames(tc, 60 + 30 * np.sin(2 * np.pi * tc / 7), 50 + 25 * np.sin(2 * np.pi * tc / 5))
    blind = ((int(round(s * 1e9)), np.zeros((0, 2))) for s in t)
    return {"wide": list(wide), "corner": list(corner), "blind": list(blind)}


def _guide(update_every: int | None = None) -> WalkGuide:
    """The walk's frames in time order (as they arrive); an update every `update_every` frames."""
    guide = WalkGuide(["wide", "corner", "blind"])
    for name in guide.names:
        guide.set_camera(name, CAMERA)
    arrivals = sorted((stamp, name, uv) for name, frames in _walk().items() for stamp, uv in frames)
    for k, (stamp, name, uv) in enumerate(arrivals):
        guide.add(name, stamp, uv)
        if update_every and k % update_every == 0:
            guide.coverages()
    return guide


def test_a_camera_seen_in_one_corner_needs_more_there_a_covered_one_is_ok():
    cov = {c.name: c for c in _guide().coverages()}
    wide, corner, blind = cov["wide"], cov["corner"], cov["blind"]

    assert corner.verdict == NEEDS_MORE
    assert "agent seen only in the image's top-left corner" in corner.reasons
    assert corner.regions_seen == ["top-left corner"]
    assert "bottom-right corner" in corner.regions_missing and len(corner.regions_missing) == 8
    assert any("of the image's grid cells" in r for r in corner.reasons)
    assert corner.covisible == {"wide": 200}  # 10-30 s at the common 10 Hz
    assert corner.observations == 200 * IDS

    assert wide.verdict == OK, wide.reasons
    assert wide.reasons == [] and wide.regions_missing == [] and wide.cell_share > 0.5
    assert wide.covisible == {"corner": 200} and wide.observations == 400 * IDS

    # No group during the walk: no camera is faulted for it; the ungrouped one is told by its view.
    assert not any("group" in r for c in cov.values() for r in c.reasons)
    assert blind.verdict == NEEDS_MORE and "agent never seen in the image" in blind.reasons
    assert blind.observations == 0 and blind.covisible == {}
    assert all(c.source == FROM_RECEIVED for c in cov.values())


def test_updating_every_few_frames_gives_what_one_update_at_the_end_gives():
    once = _guide().coverages()
    often = _guide(update_every=7).coverages()
    assert [(c.name, c.verdict, c.reasons, c.covisible, c.observations, c.cell_share) for c in often] == [
        (c.name, c.verdict, c.reasons, c.covisible, c.observations, c.cell_share) for c in once
    ]


def test_a_faster_camera_counts_a_slower_ones_frame_on_each_slot_it_spans():
    guide = WalkGuide(["fast", "slow"])
    for name in guide.names:
        guide.set_camera(name, CAMERA)
    uv = np.array([[100.0, 100.0]])
    for k in range(90):  # 30 Hz and 10 Hz over the same 3 s
        guide.add("fast", k * PERIOD_NS // 3, uv)
        if k % 3 == 0:
            guide.add("slow", k * PERIOD_NS // 3, uv)
    cov = {c.name: c for c in guide.coverages()}
    assert cov["slow"].covisible == {"fast": 90} and cov["slow"].observations == 90
    assert guide.grid_ns == PERIOD_NS // 3


def test_without_camera_info_it_says_so_and_counts_the_keypoints_once_it_comes():
    guide = WalkGuide(["a", "b"])
    guide.set_camera("b", CAMERA)
    guide.add("b", 0, np.zeros((0, 2)))
    a, b = guide.coverages()
    assert a.reasons == [NOTHING_YET] and NOTHING_YET not in b.reasons
    for stamp, uv in _walk()["wide"]:
        guide.add("a", stamp, uv)
        guide.add("b", stamp, uv)
    a = guide.coverages()[0]
    assert a.verdict == NEEDS_MORE and a.reasons[0] == NO_CAMERA_INFO and a.covisible == {"b": 400}
    guide.set_camera("a", CAMERA)
    a, b = guide.coverages()
    assert (a.verdict, a.reasons, a.cell_share) == (b.verdict, b.reasons, b.cell_share) == (OK, [], b.cell_share)


def test_the_final_guidance_takes_the_groups_and_depths_and_faults_the_ungrouped():
    guide = _guide()
    stamps = np.repeat(np.arange(100, 300) * PERIOD_NS, IDS)
    rng = np.random.default_rng(0)
    points = np.column_stack(
        [rng.uniform(-1, 1, len(stamps)), rng.uniform(-1, 1, len(stamps)), rng.uniform(2.0, 4.0, len(stamps))]
    )
    group = CameraGroupResult(
        group_id="g0",
        reference="wide",
        names=["wide", "corner"],
        T_local_cam={"wide": np.eye(4), "corner": np.eye(4)},
        point_stamps_ns=stamps,
        point_ids=np.tile(np.arange(IDS), 200),
        points=points,
        rmse_px={"wide": 1.0, "corner": 1.2},
        num_observations={"wide": len(stamps), "corner": len(stamps)},
        sigma_px_by_id={},
        initial_pair=("wide", "corner"),
        cameras={"wide": CAMERA, "corner": CAMERA},
    )
    grouping = GroupingResult([group], {"blind": "seen in 0 frames"}, [])
    cov = {c.name: c for c in guide.coverages(grouping)}
    assert cov["wide"].group == "g0" and cov["wide"].verdict == OK, cov["wide"].reasons
    assert cov["wide"].depth_unit == "group units" and 2.0 < cov["wide"].depth[0] < cov["wide"].depth[1] < 4.0
    assert "in no group of cameras: seen in 0 frames" in cov["blind"].reasons
    msg = guidance_to_msg(list(cov.values()), guide.last_stamp_ns, final=True)
    assert msg.final and msg.needs_more == 2 and [c.in_group for c in msg.cameras] == [True, True, False]


def test_the_guidance_message_round_trip():
    coverages = _guide().coverages()
    msg = guidance_to_msg(coverages, 39_900_000_000, final=False)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (39, 900_000_000)
    assert not msg.final and msg.source == FROM_RECEIVED and msg.needs_more == 2
    assert [c.name for c in msg.cameras] == ["wide", "corner", "blind"]
    corner = msg.cameras[1]
    assert corner.verdict == CameraGuidance.VERDICT_NEEDS_MORE and msg.cameras[0].verdict == CameraGuidance.VERDICT_OK
    assert list(corner.covisible_cameras) == ["wide"] and list(corner.covisible_times) == [200]
    assert math.isnan(corner.depth_near) and corner.depth_unit == "" and not corner.in_group
    back = guidance_from_msg(msg)
    for a, b in zip(coverages, back):
        assert (a.name, a.verdict, a.reasons, a.regions_seen, a.regions_missing, a.covisible, a.observations) == (
            b.name,
            b.verdict,
            b.reasons,
            b.regions_seen,
            b.regions_missing,
            b.covisible,
            b.observations,
        )
        assert b.cell_share == np.float32(a.cell_share) and b.overlap == np.float32(a.overlap)
        assert b.group == "" and b.depth is None and not b.groups_known
