"""Deficient walks on purpose (issue #48, the walk guidance's benchmark): a walk whose
shortcomings are known by construction, so the guidance can be scored against them.

- corner: one ceiling camera sees the walker only in one corner ninth of its image (where no
  camera's ninth is reachable, a corner quadrant). The walk keeps off every floor point from
  which the walker's keypoints would show elsewhere in that camera's image (depth-tested against
  the camera's agent-free view, as the simulated detector does) and stands once in the floor
  area that the corner sees.
- doorway: two rooms are joined by one pass through a doorway. The walk visits every target
  outside a room that has a single door first, then crosses that door once and visits the
  room's targets; it ends there.
- covering (the reference, sufficient on purpose): the walk passes, for every camera and every
  ninth of its image, a floor point where the walker shows in that ninth (depth-tested as the
  simulated detector does), where one is reachable.

Both are off by default; a recording with neither is the seed's recording as before. What was
made deficient is recorded on /gt/deficient (ground truth, never read by the pipeline)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
import yaml
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from .body import FOOT_LIFT, LEG_SWING
from .detector import visible_points
from .walk import CORNER_CLEARANCE_M, FloorRoutes, Walk, WalkSpec, _timeline, plan_walk

RNG_STREAM = 48  # default_rng([seed, RNG_STREAM]): the camera drawn for "any"
CORNERS = {"top-left": (0, 0), "top-right": (0, 2), "bottom-left": (2, 0), "bottom-right": (2, 2)}
GRID_M = 0.1  # floor grid on which the corner camera's view is mapped [m]
FEET_SLACK_M = 0.05  # the feet's ring is this much wider than their reach from the axis [m]
KEEP_OFF_M = 0.15  # the walk keeps this far from floor where the walker would show elsewhere [m]
CORNER_MARGIN_PX = 6.0  # the corner's inner sides moved in by this, so keypoint noise stays inside [px]
AXIS_SAMPLES = 4  # the first body samples: keypoints on the walker's axis, whatever its heading
MIN_AXIS_SEEN = 2  # the corner's floor: where at least this many of them show in the corner
CORNER_SHARES = (1 / 3, 1 / 2)  # a corner ninth is tried first, then a corner quadrant
MIN_CORNER_AREA_M2 = 0.2  # a corner whose reachable floor area is smaller is not chosen [m^2]
COVERING_STOP_S = 0.5  # the covering walk's stop at each of a camera's ninths [s]


@dataclass(frozen=True, kw_only=True)
class DeficientSpec:
    corner_camera: str = ""  # this camera sees the walker in one image corner only ('' none, 'any': drawn) [name]
    corner: str = ""  # that corner: top-left, top-right, bottom-left or bottom-right ('' the best reachable) [name]
    doorway: bool = False  # the walk crosses once between two rooms joined by a doorway [flag]
    covering: bool = False  # the walk passes every camera's image ninths where it can (sufficient) [flag]

    @property
    def active(self) -> bool:
        return bool(self.corner_camera or self.doorway or self.covering)


def parse_deficient(values: list[str]) -> DeficientSpec:
    """`yowo simulate --deficient` values: corner, corner:CAM, corner:CAM:CORNER, doorway, covering."""
    corner_camera, corner, doorway, covering = "", "", False, False
    for v in values:
        kind, _, rest = v.partition(":")
        if kind == "doorway" and not rest:
            doorway = True
        elif kind == "covering" and not rest:
            covering = True
        elif kind == "corner":
            cam, _, which = rest.partition(":")
            corner_camera, corner = cam or "any", which
            if corner and corner not in CORNERS:
                raise ValueError(f"--deficient {v}: the corner is one of {', '.join(CORNERS)}")
        else:
            raise ValueError(f"--deficient {v}: expected corner, corner:CAM, corner:CAM:CORNER, doorway or covering")
    if sum([bool(corner_camera), doorway, covering]) > 1:
        raise ValueError("--deficient: one kind of walk at a time (corner, doorway or covering)")
    return DeficientSpec(corner_camera=corner_camera, corner=corner, doorway=doorway, covering=covering)


@dataclass(kw_only=True)
class CornerPlan:
    camera: str
    corner: str
    share: float  # the corner's width and height, fraction of the image's
    free: Polygon  # where the walk may go
    spot: np.ndarray  # (2,) where the walker stands in the corner's floor area


def _body_samples(xy: np.ndarray, height_m: float) -> np.ndarray:
    """(N, S, 3) points covering the walker's keypoints (body.agent_keypoints_3d) at each floor
    point, whatever its heading and gait phase: its axis, and a ring where the feet may be."""
    H = height_m
    reach = float(np.hypot(0.06 * H, LEG_SWING * H)) + FEET_SLACK_M
    ring = [(reach * np.cos(a), reach * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)]
    offsets = [(0.0, 0.0, z) for z in (0.0, 0.53 * H, 0.845 * H, H)]  # AXIS_SAMPLES: ground, pelvis, neck, head top
    offsets += [(dx, dy, z) for dx, dy in ring for z in (0.0, FOOT_LIFT * H)]
    off = np.array(offsets)
    return np.column_stack([xy, np.zeros(len(xy))])[:, None, :] + off[None]


def _cells(xy: np.ndarray):
    """The union of the grid cells centred on xy (runs along x merged: far fewer boxes)."""
    if not len(xy):
        return Polygon()
    half = GRID_M / 2
    keys = np.round(xy / GRID_M).astype(np.int64)
    order = np.lexsort((keys[:, 0], keys[:, 1]))
    keys = keys[order]
    boxes, start = [], 0
    for i in range(1, len(keys) + 1):
        if i == len(keys) or keys[i, 1] != keys[i - 1, 1] or keys[i, 0] != keys[i - 1, 0] + 1:
            x0, x1, y = keys[start, 0] * GRID_M, keys[i - 1, 0] * GRID_M, keys[start, 1] * GRID_M
            boxes.append(box(x0 - half, y - half, x1 + half, y + half))
            start = i
    return unary_union(boxes)


def corner_box(camera, corner: str, share: float) -> tuple[float, float, float, float]:
    """(u0, v0, u1, v1) of the image's corner `share` of its width and height wide (a ninth:
    a third; a quadrant: a half), its two inner sides moved in by CORNER_MARGIN_PX."""
    r, c = CORNERS[corner]
    w, h, m = camera.width * share, camera.height * share, CORNER_MARGIN_PX
    u = (-0.5, w - m) if c == 0 else (camera.width - w + m, camera.width - 0.5)  # the image spans -0.5 .. w - 0.5
    v = (-0.5, h - m) if r == 0 else (camera.height - h + m, camera.height - 0.5)
    return u[0], v[0], u[1], v[1]


def _corner_floor(cmc, depth: np.ndarray, free, height_m: float, share: float) -> dict:
    """Per corner: (where the walk may go, the floor points seeing the walker in that corner)."""
    xy = _floor_grid(free)
    pts = _body_samples(xy, height_m)
    n, s = pts.shape[:2]
    uv, vis = visible_points(cmc.camera, cmc.T_world_cam, pts.reshape(-1, 3), depth, 0.05)
    uv, vis = uv.reshape(n, s, 2), vis.reshape(n, s)
    out = {}
    for name in CORNERS:
        u0, v0, u1, v1 = corner_box(cmc.camera, name, share)
        inside = (uv[..., 0] >= u0) & (uv[..., 0] <= u1) & (uv[..., 1] >= v0) & (uv[..., 1] <= v1)
        bad = (vis & ~inside).any(axis=1)
        seen = (vis[:, :AXIS_SAMPLES].sum(axis=1) >= MIN_AXIS_SEEN) & ~bad  # keypoints on its axis in view
        blocked = _cells(xy[bad])
        allowed = free.difference(blocked.buffer(KEEP_OFF_M))
        out[name] = (allowed, xy[seen])
    return out


def _floor_grid(free) -> np.ndarray:
    """(N, 2) the GRID_M grid's points on and near the free floor."""
    x0, y0, x1, y1 = free.bounds
    gx, gy = np.meshgrid(
        GRID_M * np.arange(np.floor(x0 / GRID_M), np.ceil(x1 / GRID_M) + 1),
        GRID_M * np.arange(np.floor(y0 / GRID_M), np.ceil(y1 / GRID_M) + 1),
    )
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    return xy[shapely.contains_xy(free.buffer(KEEP_OFF_M + GRID_M), xy[:, 0], xy[:, 1])]


def covering_targets(scene, cmcs, free, height_m: float) -> list[np.ndarray]:
    """For every camera and every ninth of its image, the reachable floor point farthest inside
    the floor where the walker's axis shows in that ninth (its pelvis in the ninth, at least
    MIN_AXIS_SEEN of its axis keypoints in view); a ninth no reachable floor shows is left out."""
    from .render import Renderer

    inner = free.buffer(-CORNER_CLEARANCE_M)
    xy = _floor_grid(free)
    xy = xy[shapely.contains_xy(inner, xy[:, 0], xy[:, 1])]
    if not len(xy):
        return []
    room = shapely.distance(inner.boundary, shapely.points(xy))
    pts = _body_samples(xy, height_m)[:, :AXIS_SAMPLES]
    renderer, targets = Renderer(scene), []
    for cmc in cmcs:
        depth = renderer.render(cmc.camera, cmc.T_world_cam).depth
        uv, vis = visible_points(cmc.camera, cmc.T_world_cam, pts.reshape(-1, 3), depth, 0.05)
        uv, vis = uv.reshape(len(xy), AXIS_SAMPLES, 2), vis.reshape(len(xy), AXIS_SAMPLES)
        seen = vis.sum(axis=1) >= MIN_AXIS_SEEN
        pelvis = uv[:, 1]
        row = np.floor(pelvis[:, 1] * 3 / cmc.camera.height)
        col = np.floor(pelvis[:, 0] * 3 / cmc.camera.width)
        for r in range(3):
            for c in range(3):
                at = np.flatnonzero(seen & vis[:, 1] & (row == r) & (col == c))
                if len(at):
                    targets.append(xy[at[int(np.argmax(room[at]))]])
    return targets


def plan_covering_walk(scene, cmcs, routes: FloorRoutes, start_xy, spec: WalkSpec, rng) -> tuple[Walk, dict]:
    """The walk through every covering target (nearest first, a short stop at each), then
    every camera's target with the usual pause."""
    start = routes.nearest_free(start_xy)
    ninths = covering_targets(scene, cmcs, routes.free, spec.agent_height_m)
    points = [start] + _nearest_first(start, ninths)
    points += _nearest_first(points[-1], [routes.nearest_free(c.target_xy) for c in cmcs])
    pauses = [0.0] + [COVERING_STOP_S] * len(ninths) + [spec.pause_s] * len(cmcs)
    truth = {"kind": "covering", "ninth_stops": len(ninths)}
    return routes.walk_through(points, pauses, spec, rng), truth


def _walkable(piece):
    """The piece without its necks too narrow for the routes' corner clearance, largest part."""
    opened = piece.buffer(-CORNER_CLEARANCE_M - 0.02).buffer(CORNER_CLEARANCE_M + 0.02).intersection(piece)
    parts = [g for g in getattr(opened, "geoms", [opened]) if isinstance(g, Polygon) and not g.is_empty]
    return max(parts, key=lambda g: g.area) if parts else None


def plan_corner(scene, cmcs, spec: DeficientSpec, free, height_m: float, seed: int) -> CornerPlan:
    """The camera (named, or the first of a seeded order with a reachable corner) and its
    corner: a corner ninth where one is reachable, else a corner quadrant."""
    from .render import Renderer

    if spec.corner_camera == "any":
        order = [cmcs[i] for i in np.random.default_rng([seed, RNG_STREAM]).permutation(len(cmcs))]
    else:
        order = [c for c in cmcs if c.name == spec.corner_camera]
        if not order:
            raise ValueError(f"no camera '{spec.corner_camera}' (the recording has {', '.join(c.name for c in cmcs)})")
    renderer = Renderer(scene)
    depths = {}
    for share in CORNER_SHARES:
        for cmc in order:
            if cmc.name not in depths:
                depths[cmc.name] = renderer.render(cmc.camera, cmc.T_world_cam).depth
            best = None
            for name, (allowed, seen) in _corner_floor(cmc, depths[cmc.name], free, height_m, share).items():
                if spec.corner and name != spec.corner:
                    continue
                pieces = [g for g in getattr(allowed, "geoms", [allowed]) if isinstance(g, Polygon) and not g.is_empty]
                piece = _walkable(max(pieces, key=lambda g: g.area)) if pieces else None
                if piece is None:
                    continue
                inner = piece.buffer(-CORNER_CLEARANCE_M)
                at = seen[shapely.contains_xy(inner, seen[:, 0], seen[:, 1])] if len(seen) else seen
                if len(at) * GRID_M**2 < MIN_CORNER_AREA_M2:
                    continue
                # The spot: the corner's floor point farthest inside the walkable piece.
                inside = shapely.distance(piece.boundary, shapely.points(at))
                key = (piece.area, len(at))
                if best is None or key > best[0]:
                    spot = at[int(np.argmax(inside))]
                    best = (key, CornerPlan(camera=cmc.name, corner=name, share=share, free=piece, spot=spot))
            if best is not None:
                return best[1]
    raise ValueError(
        f"no camera of {', '.join(c.name for c in order)} has a corner of its image that the walk can reach "
        "without crossing the rest of its view (another seed may have one)"
    )


def camera_of(cmcs, name: str):
    return next(c.camera for c in cmcs if c.name == name)


def _nearest_first(start: np.ndarray, targets: list[np.ndarray]) -> list[np.ndarray]:
    order, current, remaining = [], start, list(targets)
    while remaining:
        current = remaining.pop(int(np.argmin([np.linalg.norm(r - current) for r in remaining])))
        order.append(current)
    return order


def doorway_room(scene, cmcs, start_xy) -> int:
    """The room the doorway walk ends in: one with a single door, not the start's, with
    the most cameras (then the lowest index)."""
    start = scene.room_at(start_xy)
    doors = [sum(i in d.rooms for d in scene.doors) for i in range(len(scene.rooms))]
    cams = [sum(c.room == r.name for c in cmcs) for r in scene.rooms]
    candidates = [i for i in range(len(scene.rooms)) if doors[i] == 1 and i != start]
    if not candidates:
        raise ValueError(f"layout '{scene.spec.layout if scene.spec else '?'}' has no room with a single door")
    return max(candidates, key=lambda i: (cams[i], -i))


def plan_doorway_walk(scene, cmcs, routes: FloorRoutes, start_xy, spec: WalkSpec, rng) -> tuple[Walk, dict]:
    """The walk through every camera's target outside the end room, then once through its
    door into it; and the ground truth of the doorway."""
    j = doorway_room(scene, cmcs, start_xy)
    room = scene.rooms[j]
    door = next(d for d in scene.doors if j in d.rooms)
    inside_poly = routes.free.intersection(room.polygon())
    outside_poly = routes.free.difference(room.polygon().buffer(0.05))
    inside, outside = FloorRoutes(inside_poly), FloorRoutes(outside_poly)
    start = outside.nearest_free(start_xy)
    before = [outside.nearest_free(c.target_xy) for c in cmcs if c.room != room.name]
    after = [inside.nearest_free(c.target_xy) for c in cmcs if c.room == room.name] or [
        inside.nearest_free(room.center_xy())
    ]
    points = [start] + _nearest_first(start, before)
    points += _nearest_first(points[-1], after)
    n_before = len(before)
    long_at = int(rng.integers(len(points) - 1)) if spec.long_pause_s > 0 else -1
    pauses = [0.0] + [spec.pause_s + (spec.long_pause_s if k == long_at else 0.0) for k in range(len(points) - 1)]
    legs, stops = [points[0][None]], [pauses[0]]
    for k, (a, b) in enumerate(zip(points[:-1], points[1:])):
        via = outside if k < n_before else inside if k > n_before else routes
        leg = via.path(a, b)
        legs.append(leg[1:])
        stops += [0.0] * (len(leg) - 2) + [float(pauses[k + 1])]
    walk = _timeline(np.vstack(legs), np.array(stops), spec, rng)
    mid = door.segment().mean(axis=0)
    truth = {
        "kind": "doorway",
        "rooms": [scene.rooms[i].name for i in door.rooms],
        "room_entered": room.name,
        "door_x_m": round(float(mid[0]), 3),
        "door_y_m": round(float(mid[1]), 3),
        "cameras_beyond": [c.name for c in cmcs if c.room == room.name],
    }
    return walk, truth


def plan_deficient_walk(scene, cmcs, free, start_xy, preset, seed: int, rng) -> tuple[Walk, list[dict]]:
    """The walk of a preset whose `deficient` option is on, and what it made deficient."""
    spec = preset.deficient
    if spec.covering:
        walk, truth = plan_covering_walk(scene, cmcs, FloorRoutes(free), start_xy, preset.walk, rng)
        return walk, [truth]
    if spec.doorway:
        walk, door = plan_doorway_walk(scene, cmcs, FloorRoutes(free), start_xy, preset.walk, rng)
        return walk, [door]
    plan = plan_corner(scene, cmcs, spec, free, preset.walk.agent_height_m, seed)
    routes = FloorRoutes(plan.free)
    truth = [
        {
            "kind": "corner",
            "camera": plan.camera,
            "corner": plan.corner,
            "region": "ninth" if plan.share < 0.4 else "quadrant",
            "image_box_px": [
                round(float(v), 1) for v in corner_box(camera_of(cmcs, plan.camera), plan.corner, plan.share)
            ],
            "spot_x_m": round(float(plan.spot[0]), 3),
            "spot_y_m": round(float(plan.spot[1]), 3),
        }
    ]
    targets = [c.target_xy for c in cmcs if c.name != plan.camera] + [plan.spot]
    return plan_walk(routes, start_xy, targets, preset.walk, rng), truth


def truth_yaml(truth: list[dict]) -> str:
    """/gt/deficient: what the walk made deficient, one entry per option."""
    return yaml.safe_dump({"deficient": truth}, sort_keys=False)
