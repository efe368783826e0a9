"""The suggested second walk: every need of a camera that needs more gets a floor area where its
image region truly lies, a waypoint inside it, a tour that is short, and a path that stays on the
floor (through the doorway between two rooms, not through the wall)."""

import itertools

import numpy as np
import yaml
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union

from yowo_bringup.second_walk import (
    AROUND,
    EXPLORE,
    PAUSE,
    WALK_THROUGH,
    WEAK_PLACE,
    CameraVerdict,
    plan_second_walk,
    tour,
    write_second_walk_yaml,
)
from yowo_common.camera import CameraModel
from yowo_fusion.records import RegisteredCmc

ROOM_A, DOOR, ROOM_B = box(0, 0, 4, 4), box(4, 1.5, 5, 2.5), box(5, 0, 9, 4)
FLOORS = [np.asarray(p.exterior.coords)[:-1] for p in (ROOM_A, DOOR, ROOM_B)]
FLOOR = unary_union([ROOM_A, DOOR, ROOM_B])


def down_camera(name, x, y, status="ok"):
    """A camera 3 m up looking straight down, its image's top towards +y and its left towards -x."""
    T = np.diag([1.0, -1.0, -1.0, 1.0])
    T[:3, 3] = (x, y, 3.0)
    return RegisteredCmc(
        name=name,
        group="g0",
        method="group_sfm",
        status=status,
        reason="isolated: too few matches" if status != "ok" else "",
        T_world_cam=T,
        covariance=None,
        camera=CameraModel.from_fov(640, 480, 90.0),
        rmse_px=1.0,
        num_agent=500,
        num_scene=40,
    )


def verdict(name, missing=(), observations=800, ok=False):
    return CameraVerdict(
        name=name,
        verdict="ok" if ok else "needs more",
        reasons=() if ok else ("agent never seen in parts of the image",),
        regions_missing=tuple(missing),
        observations=observations,
        covisible={"other": 100},
        in_group=True,
    )


def first_walk():
    """The first walk stayed in room A, along its middle."""
    return np.column_stack([np.linspace(0.5, 3.5, 40), np.full(40, 2.0)])


def plan(**over):
    args = {
        "cameras": [down_camera("camA", 2, 2), down_camera("camB", 7, 2), down_camera("camW", 2, 2, status="weak")],
        "verdicts": [
            verdict("camA", ok=True),
            verdict("camB", missing=("top-left corner", "bottom-right corner", "centre"), observations=120),
            verdict("camW", missing=("centre",)),
        ],
        "floors": FLOORS,
        "ego_xy": first_walk(),
        "weak_places": [],
    }
    return plan_second_walk(**{**args, **over})


def test_each_missing_image_region_gets_the_floor_it_shows_and_a_waypoint_in_it():
    walk = plan()
    through = {n.why.split("image's ")[1].split(":")[0]: n for n in walk.needs if n.kind == WALK_THROUGH}
    assert set(through) == {"top-left corner", "bottom-right corner", "centre"}
    # camA is ok; camW's weak pose places nothing of its own (it may look at floor never approached)
    assert {n.camera for n in walk.needs if n.kind != EXPLORE} == {"camB"}
    # At body height (0.9 m) the view is 4.2 m x 3.15 m around (7, 2): its top-left ninth towards
    # -x and +y, its bottom-right one towards +x and -y.
    tl, br = through["top-left corner"].area.centroid, through["bottom-right corner"].area.centroid
    assert tl.distance(Point(7 - 1.4, 2 + 1.05)) < 0.1 and br.distance(Point(7 + 1.4, 2 - 1.05)) < 0.1
    assert through["centre"].area.centroid.distance(Point(7, 2)) < 0.1
    # Every need lies under a waypoint that serves it; a pause for the camera that saw too little.
    for need in walk.needs:
        (stop,) = [w for w in walk.waypoints if any(n is need for n in w.needs)]
        assert need.area.buffer(1e-6).covers(Point(stop.x_m, stop.y_m))
    assert any(w.pause_s > 0 and any(n.kind == PAUSE for n in w.needs) for w in walk.waypoints)
    assert "camW" in walk.unplaced and "weak" in walk.unplaced["camW"]
    assert all(w.cameras in (["camB"], []) for w in walk.waypoints)  # [] the floor explored for camW


def test_the_path_starts_on_the_first_walk_and_stays_on_the_floor_through_the_doorway():
    walk = plan()
    start = Point(walk.start_xy)
    assert LineString(first_walk()).distance(start) < 1e-9
    assert walk.start_xy[0] > 3.0  # the first walk's end nearest room B
    route = LineString(walk.route_xy)
    assert FLOOR.buffer(1e-3).covers(route)
    assert route.intersects(DOOR)
    for w in walk.waypoints:  # each stop is on the route and inside the floor, off its edge
        assert route.distance(Point(w.x_m, w.y_m)) < 1e-6
        assert FLOOR.buffer(-0.29).covers(Point(w.x_m, w.y_m))


def test_a_weak_place_of_the_map_is_a_stop_too_and_the_file_lists_the_walk(tmp_path):
    place = {"kind": "walked once", "x_m": 1.0, "y_m": 1.0, "extent_m": 1.0, "why": "never returned to"}
    walk = plan(weak_places=[place])
    (weak,) = [n for n in walk.needs if n.kind == WEAK_PLACE]
    assert weak.camera == "" and weak.area.centroid.distance(Point(1, 1)) < 0.05
    write_second_walk_yaml(tmp_path / "second_walk.yaml", walk)
    doc = yaml.safe_load((tmp_path / "second_walk.yaml").read_text())
    assert doc["frame"] == "map" and len(doc["waypoints"]) == len(walk.waypoints)
    assert [w["number"] for w in doc["waypoints"]] == list(range(1, len(walk.waypoints) + 1))
    assert any("walked once" in why for w in doc["waypoints"] for why in w["why"])
    assert doc["path"][0] == [round(walk.start_xy[0], 3), round(walk.start_xy[1], 3)]
    assert set(doc["not_placed"]) == {"camW"}


def test_nothing_to_do_when_every_camera_is_ok():
    walk = plan(verdicts=[verdict("camA", ok=True), verdict("camB", ok=True), verdict("camW", ok=True)])
    assert walk.waypoints == [] and walk.needs == [] and len(walk.route_xy) == 0


def test_the_tour_is_within_a_tenth_of_the_shortest_and_never_crosses_itself():
    rng = np.random.default_rng(4)
    for _ in range(20):
        pts = rng.uniform(0, 10, (8, 2))
        d = np.linalg.norm(pts[:, None] - pts[None], axis=2)

        def length(order, d=d):
            return sum(d[a, b] for a, b in zip(order[:-1], order[1:]))

        order = tour(d)
        assert order[0] == 0 and sorted(order) == list(range(8))
        best = min(length((0, *p)) for p in itertools.permutations(range(1, 8)))
        assert length(order) <= 1.1 * best
        legs = [LineString(pts[[a, b]]) for a, b in zip(order[:-1], order[1:])]
        for i, j in itertools.combinations(range(len(legs)), 2):
            if j > i + 1:
                assert not legs[i].crosses(legs[j])


def test_a_region_off_the_mapped_floor_keeps_its_area():
    # The floor map holds room A only: room B's camera still gets its areas, off the mapped floor.
    walk = plan(floors=[FLOORS[0]])
    assert {n.camera for n in walk.needs} == {"camB"}
    assert all(not Polygon(FLOORS[0]).contains(n.area.centroid) for n in walk.needs)


def test_a_camera_without_a_trusted_pose_is_sought_around_where_it_saw_the_walker():
    """camW's pose is weak: its view is not drawn from it, but the walker was seen at (3.2, 2.0)
    to (3.6, 2.0): waypoints 1.5 m each way from there, on the floor (east is the wall at 4 m
    in room A, but the doorway is there: that way goes through it)."""
    seen = np.column_stack([np.linspace(3.2, 3.6, 10), np.full(10, 2.0)])
    walk = plan(sightings={"camW": seen, "camA": seen})
    around = [n for n in walk.needs if n.kind == AROUND]
    assert {n.camera for n in around} == {"camW"}  # camA is ok: nothing to seek
    spots = [n.area.centroid for n in around]
    walkable = FLOOR.buffer(-0.3, join_style="mitre")
    assert all(walkable.buffer(1e-6).covers(p) for p in spots)
    assert all(0.75 <= p.distance(Point(3.4, 2.0)) <= 1.5 + 1e-6 for p in spots)
    assert len(spots) >= 3 and min(p.x for p in spots) < 2.5 and max(p.y for p in spots) > 3.0
    assert "walk around where it saw you" in walk.unplaced["camW"]
    for need in around:
        assert any(any(n is need for n in w.needs) for w in walk.waypoints)
    # Too few sightings: where it saw the walker is not known, nothing is placed for it.
    few = plan(sightings={"camW": seen[:3]})
    assert not [n for n in few.needs if n.kind == AROUND] and "cannot be placed" in few.unplaced["camW"]


def test_floor_the_first_walk_never_came_near_is_explored_for_a_camera_without_a_pose():
    """The first walk stayed in room A; camW's pose is weak and it saw the walker nowhere known:
    it may look at room B, so waypoints cover room B's floor, about 2 m apart; none are added
    when every camera that needs more has a trusted pose."""
    walk = plan()
    explore = [n for n in walk.needs if n.kind == EXPLORE]
    assert explore and all("camW" in n.why and n.camera == "" for n in explore)
    spots = [n.area.centroid for n in explore]
    assert all(ROOM_B.buffer(0.01).covers(p) for p in spots)
    assert all(LineString(first_walk()).distance(p) > 1.5 for p in spots)
    assert 2 <= len(spots) <= 6  # room B's walkable 3.4 m x 3.4 m at 2 m spacing
    for need in explore:
        assert any(any(n is need for n in w.needs) for w in walk.waypoints)
    trusted = plan(cameras=[down_camera("camA", 2, 2), down_camera("camB", 7, 2), down_camera("camW", 2, 2)])
    assert not [n for n in trusted.needs if n.kind == EXPLORE]
