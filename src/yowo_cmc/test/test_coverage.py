"""The coverage model per ceiling camera (issue #48, part 1): a camera that sees the agent
only in one corner of its image and at one depth is named with that corner and depth; a
well covered camera is ok; a camera that never sees the agent with another says so."""

import numpy as np

from yowo_cmc.coverage import NEEDS_MORE, OK, coverage_entry, group_coverage, tracks_coverage
from yowo_cmc.group_sfm import CameraGroupResult, GroupingResult
from yowo_cmc.keypoint_tracks import CameraTracks, KeypointTrack
from yowo_common.camera import CameraModel

PERIOD_NS = 100_000_000
IDS = (2, 3, 4, 5, 6)
CAMERA = CameraModel(640, 480, np.array([[400.0, 0, 319.5], [0, 400.0, 239.5], [0, 0, 1]]))


def _tracks(name: str, t_s: np.ndarray, u: np.ndarray, v: np.ndarray) -> CameraTracks:
    stamps = np.round(t_s * 1e9).astype(np.int64)
    tracks = {
        i: KeypointTrack(stamps, np.column_stack([u + 3 * k, v + 4 * k]), np.ones(len(t_s))) for k, i in enumerate(IDS)
    }
    return CameraTracks(name, CAMERA, tracks, PERIOD_NS)


def _scene():
    wide_t = np.arange(0, 400) * 0.1  # 0-40 s over the whole image
    corner_t = np.arange(100, 300) * 0.1  # 10-30 s in the top-left corner only
    alone_t = np.arange(450, 600) * 0.1  # 45-60 s, when no other camera sees the agent
    cams = [
        _tracks(
            "wide", wide_t, 320 + 270 * np.sin(2 * np.pi * wide_t / 20), 240 + 200 * np.sin(2 * np.pi * wide_t / 13)
        ),
        _tracks(
            "corner",
            corner_t,
            60 + 30 * np.sin(2 * np.pi * corner_t / 7),
            50 + 25 * np.sin(2 * np.pi * corner_t / 5),
        ),
        _tracks(
            "alone", alone_t, 320 + 270 * np.sin(2 * np.pi * alone_t / 6), 240 + 200 * np.sin(2 * np.pi * alone_t / 4)
        ),
    ]
    # The group of "wide" and "corner": one point per (time both see the agent, keypoint id).
    rng = np.random.default_rng(0)
    stamps = np.repeat(np.round(corner_t * 1e9).astype(np.int64), len(IDS))
    ids = np.tile(IDS, len(corner_t))
    # "wide" looks along local z (depths 2-4), "corner" along local x (depths 2.1-2.4)
    points = np.column_stack(
        [rng.uniform(2.1, 2.4, len(stamps)), rng.uniform(-1, 1, len(stamps)), rng.uniform(2.0, 4.0, len(stamps))]
    )
    T_corner = np.eye(4)
    T_corner[:3, :3] = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float)  # columns: x, y, z axes
    T_corner[:3, 3] = [0.0, 0.0, 3.0]  # the points in its view
    group = CameraGroupResult(
        group_id="g0",
        reference="wide",
        names=["wide", "corner"],
        T_local_cam={"wide": np.eye(4), "corner": T_corner},
        point_stamps_ns=stamps,
        point_ids=ids,
        points=points,
        rmse_px={"wide": 1.0, "corner": 1.2},
        num_observations={"wide": len(stamps), "corner": len(stamps)},
        sigma_px_by_id={},
        initial_pair=("wide", "corner"),
    )
    ungrouped = {"alone": "seen in 150 frames; shares no view of the agent with another camera"}
    return cams, GroupingResult([group], ungrouped, [])


def test_the_verdict_names_the_camera_its_corner_and_its_depth():
    cams, grouping = _scene()
    cov = {c.name: c for c in tracks_coverage(cams, grouping, scales={"g0": 1.0})}
    corner = cov["corner"]
    assert corner.verdict == NEEDS_MORE
    assert "agent seen only in the image's top-left corner" in corner.reasons
    assert "seen from one depth only (2.1-2.4 m)" in corner.reasons
    assert any("of the image's grid cells" in r for r in corner.reasons)
    assert corner.covisible == {"wide": 200} and corner.group == "g0"
    assert corner.regions_seen == ["top-left corner"]
    assert 2.1 <= corner.depth[0] < corner.depth[1] <= 2.4

    wide = cov["wide"]
    assert wide.verdict == OK and wide.reasons == [], wide.reasons
    assert wide.cell_share > 0.5 and wide.regions_missing == []
    assert wide.depth[1] - wide.depth[0] > 1.0 and wide.depth_unit == "m"

    alone = cov["alone"]
    assert alone.verdict == NEEDS_MORE
    assert "no other camera saw the agent at the same time" in alone.reasons
    assert any(r.startswith("in no group of cameras: seen in 150 frames") for r in alone.reasons)
    assert alone.covisible == {} and alone.depth is None
    # Without the group's scale the depths are named in its units.
    unscaled = {c.name: c for c in tracks_coverage(cams, grouping)}["corner"]
    assert "seen from one depth only (2.1-2.4 group units)" in unscaled.reasons


def test_cameras_yaml_entry_from_the_group_result_alone():
    """The results writer has the group results but not the tracks: each member's coverage
    from the group's points projected into its image."""
    _, grouping = _scene()
    group = grouping.groups[0]
    # Points that project into both images: in front of "wide" (z > 0) and of "corner" (x > 0).
    cov = group_coverage(grouping.groups, grouping.ungrouped, cameras={"wide": CAMERA, "corner": CAMERA})
    assert set(cov) == {"wide", "corner", "alone"}
    entry = coverage_entry(cov["corner"])["coverage"]
    assert entry["in_group"] and entry["depth_range"]["unit"] == "group units"
    assert entry["verdict"] == NEEDS_MORE
    assert any(r.startswith("seen from one depth only (2.1-2.4") for r in entry["reasons"])
    assert entry["covisible_cameras"]["wide"] > 0
    assert entry["agent_observations"] == len(group.points)
    alone = coverage_entry(cov["alone"])["coverage"]
    assert alone["verdict"] == NEEDS_MORE and not alone["in_group"] and alone["grid_cell_share"] is None
    assert any("in no group of cameras" in r for r in alone["reasons"])


def test_a_share_just_short_of_the_bar_does_not_read_as_reaching_it():
    from yowo_cmc.coverage import NEEDS_MORE, Coverage, judge
    from yowo_cmc.params import CoverageParams

    params = CoverageParams()
    short = Coverage(
        name="cam00", source="test", observations=1000, cell_share=params.min_cell_share - 0.004, overlap=None
    )
    judged = judge(short, params, "")
    assert judged.verdict == NEEDS_MORE
    low = f"{round(params.min_cell_share * 100) - 1}%"
    assert any(f"seen in {low} of the image's grid cells" in r for r in judged.reasons), judged.reasons
