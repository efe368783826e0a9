"""Walks deficient on purpose (issue #48): a camera that sees the walker only in one corner of its
image, two rooms joined by one pass through a doorway; recorded on /gt/deficient, and nothing of
a default recording changes."""

from collections import defaultdict

import numpy as np
import pytest
import shapely
import yaml

from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import message_fields
from yowo_common.topics import GT_DEFICIENT
from yowo_sim.body import agent_keypoints_3d
from yowo_sim.capture import build_capture, generate
from yowo_sim.deficient import CORNERS, DeficientSpec, parse_deficient
from yowo_sim.detector import visible_points
from yowo_sim.presets import get_preset
from yowo_sim.render import Renderer


def _keypoint_pixels(setup, name: str, step_s: float = 0.05) -> np.ndarray:
    """The true pixels of the walker's keypoints that camera `name` sees (in its image, not hidden
    by the scene, as the simulated detector decides) over the whole walk."""
    cmc = next(c for c in setup.cmcs if c.name == name)
    depth = Renderer(setup.scene).render(cmc.camera, cmc.T_world_cam).depth
    out = []
    for t in np.arange(0.0, setup.walk.duration_s, step_s):
        xy, heading, phase = setup.walk.state_at(t)
        kps = agent_keypoints_3d(xy, heading, setup.walk.height_m, phase)
        uv, ok = visible_points(cmc.camera, cmc.T_world_cam, np.array(list(kps.values())), depth, 0.05)
        out += list(uv[ok])
    return np.array(out).reshape(-1, 2)


def _ninth(uv: np.ndarray, camera) -> np.ndarray:
    """(row, column) of the image's ninth of each pixel."""
    rc = np.column_stack([(uv[:, 1] * 3 // camera.height), (uv[:, 0] * 3 // camera.width)]).astype(int)
    return np.clip(rc, 0, 2)  # the image spans -0.5 .. size - 0.5


@pytest.mark.parametrize("seed, option", [(1, "corner:cam00"), (3, "corner")])
def test_the_corner_camera_sees_the_walker_in_one_corner_only(seed, option):
    default = build_capture(get_preset("small"), seed)
    setup = build_capture(get_preset("small", deficient=parse_deficient([option])), seed)
    ((truth,),) = [setup.deficient]
    assert truth["kind"] == "corner" and truth["corner"] in CORNERS
    if option != "corner":
        assert truth["camera"] == option.split(":")[1]
    cam = next(c.camera for c in setup.cmcs if c.name == truth["camera"])
    uv = _keypoint_pixels(setup, truth["camera"])
    assert len(uv) >= 100, len(uv)  # it does see the walker (it stands there once)
    u0, v0, u1, v1 = truth["image_box_px"]
    assert ((uv[:, 0] >= u0) & (uv[:, 0] <= u1) & (uv[:, 1] >= v0) & (uv[:, 1] <= v1)).all()
    if truth["region"] == "ninth":
        assert len({tuple(rc) for rc in _ninth(uv, cam)}) == 1
        assert tuple(_ninth(uv, cam)[0]) == CORNERS[truth["corner"]]
    # In the usual walk the same camera sees the walker in several parts of its image.
    assert len({tuple(rc) for rc in _ninth(_keypoint_pixels(default, truth["camera"], 0.1), cam)}) >= 3
    # Only the walk changed: the same scene and cameras.
    assert [c.T_world_cam.tolist() for c in setup.cmcs] == [c.T_world_cam.tolist() for c in default.cmcs]
    assert not np.array_equal(setup.walk.xy[: len(default.walk.xy)], default.walk.xy[: len(setup.walk.xy)])


def _rooms_along(setup) -> list[int]:
    """The rooms the walk is in, in order (doorway samples belong to the room before)."""
    seq = []
    for xy in setup.walk.xy[::5]:
        inside = [i for i, r in enumerate(setup.scene.rooms) if r.polygon().contains(shapely.Point(xy))]
        if inside and (not seq or seq[-1] != inside[0]):
            seq.append(inside[0])
    return seq


@pytest.mark.parametrize("seed", [0, 2])
def test_the_doorway_walk_crosses_between_the_two_rooms_once(seed):
    setup = build_capture(get_preset("small", deficient=DeficientSpec(doorway=True)), seed)
    ((truth,),) = [setup.deficient]
    assert truth["kind"] == "doorway" and truth["rooms"] == ["room_a", "room_b"] and truth["room_entered"] == "room_b"
    assert _rooms_along(setup) == [0, 1]
    door = setup.scene.doors[0]
    np.testing.assert_allclose([truth["door_x_m"], truth["door_y_m"]], door.segment().mean(axis=0), atol=1e-3)
    # Every camera's target is visited: the walk passes within a metre of each.
    for c in setup.cmcs:
        assert np.linalg.norm(setup.walk.xy - c.target_xy, axis=1).min() < 1.0, c.name
    # Through the door: the walk's samples in the opening.
    assert shapely.contains_xy(door.polygon().buffer(0.05), setup.walk.xy[:, 0], setup.walk.xy[:, 1]).any()


def test_a_doorway_walk_needs_a_room_with_one_door():
    with pytest.raises(ValueError, match="single door"):
        build_capture(get_preset("tiny", deficient=DeficientSpec(doorway=True)), 0)


def test_the_covering_walk_shows_the_walker_in_every_ninth_it_can_reach():
    """The reference walk: each camera sees the walker in the ninths of its image a stop was
    found for, and in more of them than on the seed's usual walk."""
    default = build_capture(get_preset("small"), 1)
    setup = build_capture(get_preset("small", deficient=parse_deficient(["covering"])), 1)
    ((truth,),) = [setup.deficient]
    assert truth["kind"] == "covering" and truth["ninth_stops"] >= 30  # of 5 cameras x 9 ninths
    reached = 0
    for cmc in setup.cmcs:
        seen = {tuple(rc) for rc in _ninth(_keypoint_pixels(setup, cmc.name, 0.1), cmc.camera)}
        usual = {tuple(rc) for rc in _ninth(_keypoint_pixels(default, cmc.name, 0.1), cmc.camera)}
        assert len(seen) >= len(usual), cmc.name
        reached += len(seen)
    assert reached >= truth["ninth_stops"]


@pytest.mark.parametrize(
    "values, spec",
    [
        ([], DeficientSpec()),
        (["doorway"], DeficientSpec(doorway=True)),
        (["corner"], DeficientSpec(corner_camera="any")),
        (["corner:cam02:bottom-left"], DeficientSpec(corner_camera="cam02", corner="bottom-left")),
        (["covering"], DeficientSpec(covering=True)),
    ],
)
def test_the_option_parses(values, spec):
    assert parse_deficient(values) == spec


@pytest.mark.parametrize("values", [["door"], ["corner:cam00:middle"], ["doorway:x"], ["covering", "doorway"]])
def test_a_bad_option_is_named(values):
    with pytest.raises(ValueError, match="--deficient"):
        parse_deficient(values)


def _messages(path) -> dict:
    out = defaultdict(list)
    for topic, t, msg in read_messages(path):
        out[topic].append((t, message_fields(msg)))
    return out


def test_the_recording_says_what_was_made_deficient_and_the_default_has_nothing(tmp_path):
    fast = {"cmc_images": False, "ego_hz": 2.0, "imu": False, "ego_width": 160, "ego_height": 120}
    generate(get_preset("small", **fast), 1, tmp_path / "default")
    deficient = get_preset("small", deficient=DeficientSpec(corner_camera="cam00"), **fast)
    generate(deficient, 1, tmp_path / "corner")
    a, b = _messages(tmp_path / "default"), _messages(tmp_path / "corner")
    assert GT_DEFICIENT not in a and set(b) - set(a) == {GT_DEFICIENT}
    ((_, msg),) = b[GT_DEFICIENT]
    assert yaml.safe_load(msg["data"])["deficient"] == build_capture(deficient, 1).deficient
    for topic in a:  # the static ground truth (cameras, floor) alike; the walk's messages differ
        if topic.startswith(("/gt/cmc/", "/gt/layout/")):
            assert a[topic] == b[topic], topic
    assert a["/gt/ego/pose"] != b["/gt/ego/pose"]
