"""A suggested second walk after a run (walk guidance, issue #48): from the final walk guidance
(per camera, what is missing: the image's ninths where the walker never showed, too few
observations, one depth only, no group), the registered cameras and the ego map's weak places,
the floor areas a second walk should pass or pause in, and an ordered path of waypoints through
them on the floor plan, for a walker or a robot to follow.

A missing ninth's floor area is where the walker's middle shows in that ninth: the ninth's
corner rays met with a horizontal plane at body height, on the mapped floor, less the floor the
first walk already passed. Waypoints are placed greedily so that each lies in as many areas as
possible; they are ordered as a nearest-neighbour tour improved by 2-opt, from the first walk's
point nearest to them, and joined by shortest paths inside the floor (a visibility graph on the
floor's corners). No ROS here: the final guidance message is read through its fields."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
import yaml
from scipy.sparse.csgraph import shortest_path
from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.ops import nearest_points, polylabel, unary_union

from yowo_cmc.coverage import COLS, NEEDS_MORE, ROWS, region_name
from yowo_cmc.params import CoverageParams
from yowo_fusion.records import RegisteredCmc

# What a need asks of the walker.
WALK_THROUGH = "walk through"  # a floor area the camera sees where the walker never showed
PAUSE = "pause"  # stand a while in the camera's view: it saw the walker too little
CLOSER = "closer"  # be seen from a depth it has not seen
WITH_ANOTHER = "with another camera"  # be seen by it and another camera at the same time
WEAK_PLACE = "weak place"  # a weak place of the ego map (yowo_fusion.weak_places)
AROUND = "around"  # walk around where a camera without a trusted pose saw the walker
EXPLORE = "explore"  # floor the first walk never came near, where a camera without a pose may look

NINTHS = {region_name(r, c): (r, c) for r in range(len(ROWS)) for c in range(len(COLS))}


@dataclass(frozen=True, kw_only=True)
class SecondWalkParams:
    body_height_m: float = 0.9  # an image region's floor area is where the walker's middle shows in it [m]
    max_range_m: float = 8.0  # a ray that never meets that plane is cut at this distance [m]
    walked_m: float = 0.4  # floor within this of the first walk counts as walked [m]
    floor_margin_m: float = 0.3  # waypoints and the path keep this far inside the floor's edge [m]
    min_area_m2: float = 0.1  # a floor area smaller than this is not worth a waypoint [m^2]
    pause_s: float = 5.0  # how long to stand for a camera that saw the walker too little [s]
    min_weak_place_radius_m: float = 0.25  # a weak place's area is at least this wide a disc [m]
    # A camera without a trusted pose: waypoints this far each way around where it saw the walker [m]
    around_m: float = 1.5
    min_sightings: int = 5  # fewer frames with the walker: where it saw the walker is not known [count]
    waypoint_radius_m: float = 0.3  # the floor area of a waypoint around a sighting [m]
    unwalked_m: float = 1.5  # floor farther than this from the first walk was never approached [m]
    explore_spacing_m: float = 2.0  # waypoints over never approached floor this far apart [m]


@dataclass(frozen=True, kw_only=True)
class CameraVerdict:
    """A camera's final walk guidance (yowo_msgs/CameraGuidance), as plain values."""

    name: str
    verdict: str  # "ok" or "needs more"
    reasons: tuple[str, ...] = ()
    regions_missing: tuple[str, ...] = ()  # the image's ninths where the walker never showed
    observations: int = 0
    depth_near: float = float("nan")  # the walker's depths, 5th and 95th percentile [depth_unit]
    depth_far: float = float("nan")
    depth_unit: str = ""
    covisible: dict[str, int] = field(default_factory=dict)  # other camera -> shared grid times
    in_group: bool = False

    @classmethod
    def from_msg(cls, cam) -> CameraVerdict:
        return cls(
            name=cam.name,
            verdict=cam.verdict,
            reasons=tuple(cam.reasons),
            regions_missing=tuple(cam.regions_missing),
            observations=int(cam.observations),
            depth_near=float(cam.depth_near),
            depth_far=float(cam.depth_far),
            depth_unit=cam.depth_unit,
            covisible=dict(zip(cam.covisible_cameras, map(int, cam.covisible_times))),
            in_group=bool(cam.in_group),
        )


@dataclass(frozen=True, kw_only=True)
class Need:
    """One thing the second walk should do, and the floor area where it is done."""

    kind: str  # WALK_THROUGH, PAUSE, CLOSER, WITH_ANOTHER or WEAK_PLACE
    camera: str  # the camera it serves ('' a weak place of the map)
    why: str
    area: Polygon | MultiPolygon  # map frame, on the floor where the floor is known
    pause_s: float = 0.0


@dataclass(frozen=True, kw_only=True)
class Waypoint:
    x_m: float  # map frame [m]
    y_m: float
    needs: tuple[Need, ...]  # the needs it serves (it lies in their areas)
    pause_s: float  # how long to stand there [s]

    @property
    def cameras(self) -> list[str]:
        return sorted({n.camera for n in self.needs if n.camera})


@dataclass(frozen=True, kw_only=True)
class SecondWalk:
    start_xy: tuple[float, float] | None  # where it starts: the first walk's point nearest to the waypoints
    waypoints: list[Waypoint]  # in walking order
    route_xy: np.ndarray  # (K, 2) the path from the start through every waypoint [m]
    needs: list[Need]
    unplaced: dict[str, str]  # camera -> why its needs are not on the floor plan

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.diff(self.route_xy, axis=0), axis=1).sum()) if len(self.route_xy) > 1 else 0.0

    def as_dict(self) -> dict:
        """second_walk.yaml's content."""
        return {
            "frame": "map",
            "start": None
            if self.start_xy is None
            else {"x_m": round(self.start_xy[0], 3), "y_m": round(self.start_xy[1], 3)},
            "length_m": round(self.length_m, 2),
            "waypoints": [
                {
                    "number": i + 1,
                    "x_m": round(w.x_m, 3),
                    "y_m": round(w.y_m, 3),
                    "pause_s": w.pause_s,
                    "cameras": w.cameras,
                    "why": [f"{n.camera}: {n.why}" if n.camera else n.why for n in w.needs],
                }
                for i, w in enumerate(self.waypoints)
            ],
            "path": [[round(float(x), 3), round(float(y), 3)] for x, y in self.route_xy],
            "not_placed": dict(self.unplaced),
        }


def box_on_plane(
    c: RegisteredCmc, box_uv: tuple[float, float, float, float], z: float, max_range_m: float
) -> np.ndarray:
    """(4, 3) where the rays through the corners of the image box (u0, v0, u1, v1) meet the
    horizontal plane at height z (a ray that does not reach it ends at max_range_m)."""
    cam, T = c.camera, c.T_world_cam
    u0, v0, u1, v1 = box_uv
    rays = cam.bearings(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], float)) @ T[:3, :3].T
    C = T[:3, 3]
    toward = rays[:, 2] * (z - C[2]) > 1e-9
    t = np.where(toward, (z - C[2]) / np.where(toward, rays[:, 2], 1.0), max_range_m)
    return C + rays * np.minimum(t, max_range_m)[:, None]


def ninth_box(c: RegisteredCmc, region: str) -> tuple[float, float, float, float]:
    """The pixel box (u0, v0, u1, v1) of one of the image's ninths, by its name."""
    r, k = NINTHS[region]
    w, h = c.camera.width / 3, c.camera.height / 3
    return k * w - 0.5, r * h - 0.5, (k + 1) * w - 0.5, (r + 1) * h - 0.5


def floor_region(floors: list[np.ndarray]) -> Polygon | MultiPolygon:
    """The mapped floor as one shape (rooms that touch joined)."""
    polys = [Polygon(p).buffer(0) for p in floors if len(p) >= 3]
    return unary_union(polys) if polys else Polygon()


def _on_floor(area, floor, walked, params: SecondWalkParams):
    """The area on the mapped floor and off the first walk; the area as it is where the floor
    map misses it (an incomplete floor is no reason to drop a camera's need)."""
    if floor.is_empty:
        on = area
    else:
        on = area.intersection(floor)
        if on.area < params.min_area_m2:
            on = area
    off_walk = on.difference(walked) if walked is not None else on
    return off_walk if off_walk.area >= params.min_area_m2 else on


def _view(c: RegisteredCmc, params: SecondWalkParams) -> Polygon:
    full = (-0.5, -0.5, c.camera.width - 0.5, c.camera.height - 0.5)
    return Polygon(box_on_plane(c, full, params.body_height_m, params.max_range_m)[:, :2]).buffer(0)


def camera_needs(
    v: CameraVerdict,
    c: RegisteredCmc,
    views: dict[str, Polygon],
    floor,
    walked,
    params: SecondWalkParams,
    coverage: CoverageParams,
) -> list[Need]:
    """What would bring a registered camera that needs more to ok, each with its floor area."""
    if v.verdict != NEEDS_MORE:
        return []
    view = views[c.name]
    needs = []
    for region in v.regions_missing:
        quad = Polygon(box_on_plane(c, ninth_box(c, region), params.body_height_m, params.max_range_m)[:, :2])
        area = _on_floor(quad.buffer(0), floor, walked, params)
        if area.area >= params.min_area_m2:
            why = f"never saw the walker in its image's {region}: walk through the floor it sees there"
            needs.append(Need(kind=WALK_THROUGH, camera=c.name, why=why, area=area))
    if v.observations < coverage.min_observations:
        centre = Polygon(box_on_plane(c, ninth_box(c, "centre"), params.body_height_m, params.max_range_m)[:, :2])
        why = (
            f"saw the walker too little ({v.observations} observations, needs {coverage.min_observations}): "
            f"stand {params.pause_s:g} s in the middle of its view, turning"
        )
        needs.append(
            Need(
                kind=PAUSE,
                camera=c.name,
                why=why,
                area=_on_floor(centre.buffer(0), floor, None, params),
                pause_s=params.pause_s,
            )
        )
    if np.isfinite(v.depth_near) and np.isfinite(v.depth_far):
        middle = (v.depth_near + v.depth_far) / 2
        if middle > 0 and v.depth_far - v.depth_near < coverage.min_depth_spread * middle:
            nadir = Point(c.T_world_cam[:2, 3])
            reach = (
                max(np.hypot(*(np.asarray(view.exterior.coords) - c.T_world_cam[:2, 3]).T))
                if not view.is_empty
                else 0.0
            )
            near = view.intersection(nadir.buffer(reach / 3))
            why = (
                f"saw the walker from one depth only ({v.depth_near:.1f}-{v.depth_far:.1f} {v.depth_unit}): "
                "walk close under it"
            )
            needs.append(Need(kind=CLOSER, camera=c.name, why=why, area=_on_floor(near, floor, None, params)))
    best = max(v.covisible.values(), default=0)
    if not v.in_group or best < coverage.min_covisible_times:
        shared = {o: view.intersection(w) for o, w in views.items() if o != c.name}
        partner = max(shared, key=lambda o: shared[o].area, default=None)
        if partner is not None and shared[partner].area >= params.min_area_m2:
            lack = (
                "is in no group of cameras"
                if not v.in_group
                else f"saw the walker with another camera only {best} times"
            )
            why = f"{lack}: walk where it and {partner} see you at once"
            needs.append(
                Need(kind=WITH_ANOTHER, camera=c.name, why=why, area=_on_floor(shared[partner], floor, None, params))
            )
    return needs


def weak_place_needs(places: list[dict], floor, params: SecondWalkParams) -> list[Need]:
    """A need per weak place of the ego map (weak_places.yaml's entries)."""
    out = []
    for w in places:
        disc = Point(w["x_m"], w["y_m"]).buffer(max(w["extent_m"] / 2, params.min_weak_place_radius_m))
        out.append(
            Need(kind=WEAK_PLACE, camera="", why=f"{w['kind']}: {w['why']}", area=_on_floor(disc, floor, None, params))
        )
    return out


def around_needs(name: str, seen_xy: np.ndarray, walkable, params: SecondWalkParams) -> list[Need]:
    """A camera without a trusted pose that saw the walker: its view is around where the walker
    was then, which way unknown: a waypoint around_m each way (the four of the floor plan, moved
    onto the walkable floor) from the middle of those places."""
    centre = np.median(seen_xy, axis=0)
    needs = []
    for angle in np.arange(4) * np.pi / 2:
        p = Point(centre + params.around_m * np.array([np.cos(angle), np.sin(angle)]))
        if not walkable.is_empty and not walkable.covers(p):
            p = nearest_points(walkable, p)[0]
        if p.distance(Point(centre)) < params.around_m / 2:  # that way is a wall close by
            continue
        why = "its pose is not trusted: walk around where it saw you, its view is there"
        needs.append(Need(kind=AROUND, camera=name, why=why, area=p.buffer(params.waypoint_radius_m)))
    return needs


def unwalked_needs(walkable, ego_xy, cameras: list[str], params: SecondWalkParams) -> list[Need]:
    """Cameras without a trusted pose may look at floor the first walk never came near: waypoints
    on a grid over that floor (each piece too small for the grid gets one in its middle)."""
    if walkable.is_empty or ego_xy is None or len(ego_xy) < 2 or not cameras:
        return []
    far = walkable.difference(LineString(ego_xy).buffer(params.unwalked_m))
    r = params.waypoint_radius_m
    far = far.buffer(-r).buffer(r)  # no strips along the walls the walk passed at a distance
    pieces = [g for g in getattr(far, "geoms", [far]) if isinstance(g, Polygon) and g.area >= params.min_area_m2]
    why = f"floor the first walk never came near: {', '.join(cameras)} may look there (where is unknown)"
    points = []
    for piece in pieces:
        x0, y0, x1, y1 = piece.bounds
        s = params.explore_spacing_m
        gx, gy = np.meshgrid(np.arange(x0 + s / 2, x1, s), np.arange(y0 + s / 2, y1, s))
        on = shapely.contains_xy(piece, gx.ravel(), gy.ravel())
        grid = np.column_stack([gx.ravel()[on], gy.ravel()[on]])
        points += [Point(p) for p in grid] if len(grid) else [polylabel(piece, tolerance=0.05)]
    return [Need(kind=EXPLORE, camera="", why=why, area=p.buffer(params.waypoint_radius_m)) for p in points]


def _inside(area, walkable) -> Point:
    """A point well inside the area, on the walkable floor where they meet."""
    part = area.intersection(walkable) if not walkable.is_empty else area
    if part.area < 1e-6:
        part = area
    if isinstance(part, MultiPolygon) or part.geom_type == "GeometryCollection":
        part = max((g for g in part.geoms if g.area > 0), key=lambda g: g.area)
    return polylabel(part, tolerance=0.05)


def place_waypoints(needs: list[Need], walkable) -> list[tuple[Point, list[int]]]:
    """Greedy cover: the candidate point lying in the most not yet served areas first, until every
    need has a waypoint. Candidates: a point inside each area and inside each overlap of two."""
    candidates = [_inside(n.area, walkable) for n in needs]
    for i, a in enumerate(needs):
        for b in needs[i + 1 :]:
            both = a.area.intersection(b.area)
            if both.area > 1e-3:
                candidates.append(_inside(both, walkable))
    reach = [[k for k, n in enumerate(needs) if n.area.buffer(1e-6).covers(p)] for p in candidates]
    open_needs, chosen = set(range(len(needs))), []
    while open_needs:
        best = max(range(len(candidates)), key=lambda j: len(open_needs.intersection(reach[j])))
        served = sorted(open_needs.intersection(reach[best]))
        if not served:  # a degenerate area that does not hold its own point
            served = [min(open_needs)]
        chosen.append((candidates[best], served))
        open_needs -= set(served)
    return chosen


class FloorPaths:
    """Shortest paths between points inside a walkable region: straight where the segment stays
    inside, else through the region's corners."""

    def __init__(self, walkable):
        self.walkable = walkable
        self.inside = walkable.buffer(0.01) if not walkable.is_empty else walkable
        corners = []
        if not walkable.is_empty:
            for poly in getattr(walkable, "geoms", [walkable]):
                simple = poly.simplify(0.005)
                for ring in [simple.exterior, *simple.interiors]:
                    corners += list(ring.coords)[:-1]
        self.corners = np.array(corners, float).reshape(-1, 2)

    def _entry(self, p: np.ndarray) -> np.ndarray:
        """The point itself where it is on the walkable floor, else the nearest floor point."""
        if self.walkable.is_empty or self.inside.covers(Point(p)):
            return p
        return np.array(nearest_points(self.walkable, Point(p))[0].coords[0])

    def paths(self, points: np.ndarray) -> tuple[np.ndarray, list[list[list[np.ndarray]]]]:
        """(n, n) path lengths between the points and each path's polyline."""
        n = len(points)
        if self.walkable.is_empty:
            d = np.linalg.norm(points[:, None] - points[None], axis=2)
            return d, [[[points[i], points[j]] for j in range(n)] for i in range(n)]
        entries = np.array([self._entry(p) for p in points])
        nodes = np.vstack([entries, self.corners])
        a, b = np.triu_indices(len(nodes), 1)
        segs = shapely.linestrings(np.stack([nodes[a], nodes[b]], axis=1))
        ok = shapely.covered_by(segs, self.inside)
        graph = np.zeros((len(nodes), len(nodes)))
        length = np.linalg.norm(nodes[a] - nodes[b], axis=1)
        graph[a[ok], b[ok]] = graph[b[ok], a[ok]] = np.maximum(length[ok], 1e-9)
        dist, pred = shortest_path(graph, directed=False, indices=range(n), return_predecessors=True)
        out_d = np.zeros((n, n))
        polylines = [[[] for _ in range(n)] for _ in range(n)]
        for i in range(n):
            for j in range(n):
                if i == j:
                    polylines[i][j] = [points[i]]
                    continue
                if np.isfinite(dist[i, j]):
                    chain, k = [j], j
                    while k != i:
                        k = pred[i, k]
                        chain.append(k)
                    inner = [nodes[k] for k in reversed(chain)]
                else:  # separate parts of the floor: the straight way
                    inner = [entries[i], entries[j]]
                line = [points[i], *inner, points[j]]
                line = [q for k, q in enumerate(line) if k == 0 or np.linalg.norm(q - line[k - 1]) > 1e-9]
                polylines[i][j] = line
                out_d[i, j] = float(np.linalg.norm(np.diff(np.array(line), axis=0), axis=1).sum())
        return out_d, polylines


def tour(dist: np.ndarray) -> list[int]:
    """An open tour from node 0 through every node: nearest neighbour, then 2-opt (reversing a
    stretch while that shortens it)."""
    n = len(dist)
    order, left = [0], set(range(1, n))
    while left:
        nxt = min(left, key=lambda j: dist[order[-1], j])
        order.append(nxt)
        left.remove(nxt)

    def length(o):
        return sum(dist[o[k], o[k + 1]] for k in range(len(o) - 1))

    improved = True
    while improved:
        improved = False
        for i in range(1, n - 1):
            for j in range(i + 1, n):
                candidate = order[:i] + order[i : j + 1][::-1] + order[j + 1 :]
                if length(candidate) < length(order) - 1e-9:
                    order, improved = candidate, True
    return order


def plan_second_walk(
    *,
    cameras: list[RegisteredCmc],
    verdicts: list[CameraVerdict],
    floors: list[np.ndarray],
    ego_xy: np.ndarray | None,
    weak_places: list[dict] | None,
    sightings: dict[str, np.ndarray] | None = None,
    params: SecondWalkParams = SecondWalkParams(),
    coverage: CoverageParams = CoverageParams(),
) -> SecondWalk:
    """The second walk that serves every camera the final guidance says needs more (where its
    pose places it on the floor; a camera without a trusted pose around where it saw the walker:
    `sightings`, the walker's floor positions at its frames with the walker) and every weak place
    of the ego map."""
    floor = floor_region(floors)
    # Mitred: the floor's inner corners (a doorway's sides) stay one corner each for the paths.
    walkable = floor.buffer(-params.floor_margin_m, join_style="mitre") if not floor.is_empty else floor
    if walkable.is_empty:
        walkable = floor
    walked = LineString(ego_xy).buffer(params.walked_m) if ego_xy is not None and len(ego_xy) > 1 else None
    # A weak or failed registration may be metres off: areas drawn from it would send the walker
    # to the wrong place.
    placed = {c.name: c for c in cameras if c.status == "ok" and c.T_world_cam is not None and c.camera is not None}
    views = {n: _view(c, params) for n, c in placed.items()}
    status = {c.name: c for c in cameras}
    needs, unplaced = [], {}
    for v in verdicts:
        if v.verdict != NEEDS_MORE:
            continue
        if v.name not in placed:
            c = status.get(v.name)
            pose = (
                "no pose in the map" if c is None or c.T_world_cam is None else f"its pose is {c.status} ({c.reason})"
            )
            unplaced[v.name] = f"{pose}, so its view cannot be placed on the floor: walk through all of its view"
            seen = (sightings or {}).get(v.name)
            if seen is not None and len(seen) >= params.min_sightings:
                found = around_needs(v.name, np.asarray(seen), walkable, params)
                unplaced[v.name] = (
                    f"{pose}: walk around where it saw you, its view is there" if found else unplaced[v.name]
                )
                needs += found
            continue
        found = camera_needs(v, placed[v.name], views, floor, walked, params, coverage)
        if not found:
            unplaced[v.name] = "nothing to walk for on the floor: " + "; ".join(v.reasons)
        needs += found
    needs += weak_place_needs(weak_places or [], floor, params)
    needs += unwalked_needs(walkable, ego_xy, sorted(unplaced), params)
    if not needs:
        return SecondWalk(start_xy=None, waypoints=[], route_xy=np.zeros((0, 2)), needs=[], unplaced=unplaced)
    chosen = place_waypoints(needs, walkable)
    stops = np.array([[p.x, p.y] for p, _ in chosen])
    if ego_xy is not None and len(ego_xy):
        gaps = np.linalg.norm(np.asarray(ego_xy)[:, None] - stops[None], axis=2)
        start = np.asarray(ego_xy)[np.unravel_index(np.argmin(gaps), gaps.shape)[0]]
    else:
        start = stops[0]
    points = np.vstack([start, stops])
    dist, polylines = FloorPaths(walkable).paths(points)
    order = tour(dist)
    route = [points[0]]
    for a, b in zip(order[:-1], order[1:]):
        route += polylines[a][b][1:]
    waypoints = []
    for k in order[1:]:
        p, served = chosen[k - 1]
        mine = tuple(needs[i] for i in served)
        waypoints.append(Waypoint(x_m=p.x, y_m=p.y, needs=mine, pause_s=max(n.pause_s for n in mine)))
    return SecondWalk(
        start_xy=(float(start[0]), float(start[1])),
        waypoints=waypoints,
        route_xy=np.array(route),
        needs=needs,
        unplaced=unplaced,
    )


SECOND_WALK_HEADER = """\
# A suggested second walk (walk guidance): waypoints in the map frame, in walking order, each with
# the cameras it serves and why (a camera's floor area to walk through or pause in, a weak place of
# the ego map); pause_s: how long to stand there [s]; path: the way from `start` through every
# waypoint, inside the mapped floor where it can be [m]; not_placed: cameras whose needs have no
# place on the floor plan, and why.
"""


def write_second_walk_yaml(path, walk: SecondWalk) -> None:
    path.write_text(SECOND_WALK_HEADER + yaml.safe_dump(walk.as_dict(), sort_keys=False))
