"""Static indoor scenes (rooms, doors, furniture, textures, lights) with ground truth:
the scene types, the layouts and ``build_scene``; the meshing is in ``scene_mesh``,
the textures in ``textures``.

World frame ``map``: metres, z up (REP 103); floor at z = 0, ceiling at
z = ``ceiling_height``. Rooms are axis-aligned rectangles given by their
*interior* wall faces; neighbouring rooms are ``WALL_THICKNESS`` apart and a door
is an opening through that gap. Only the surfaces visible from inside the rooms
are meshed (walls have no outer faces), which is all a camera inside can see.

UV convention: ``Scene.triangle_uvs`` are in units of the texture size, (0, 0) at
the top-left corner of the texture image and (1, 1) at its bottom-right corner;
values outside [0, 1] repeat (tiling), so large surfaces keep a constant texel
density of ``scene_mesh.TEXELS_PER_METRE``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import Point, Polygon, box
from shapely.geometry.polygon import orient
from shapely.ops import unary_union

from . import textures
from .scene_mesh import (
    SEAM_OVERLAP,
    MeshBuilder,
    door_mesh,
    furniture_mesh,
    make_palette,
    texels,
    wall_items,
    wall_pieces,
)

LAYOUTS = ("room_4x4", "two_rooms", "office", "floor_40x20")
TEXTURE_MODES = ("rich", "poor", "symmetric")

WALL_THICKNESS = 0.1
DOOR_HEIGHT = 2.1
DOOR_WIDTH = 1.0
# A light's contribution fades to zero at this distance.
LIGHT_RANGE = 6.0
# Posters hang this far in front of their wall (no coplanar fighting with it).
POSTER_OFFSET = 3e-3
FURNITURE_KINDS = ("box", "table", "shelf")


@dataclass
class SceneSpec:
    layout: str = "room_4x4"
    ceiling_height: float = 2.8
    texture: str = "rich"
    num_furniture: int = 3
    light_intensity: float = 1.0
    seed: int = 0

    def __post_init__(self):
        if self.layout not in LAYOUTS:
            raise ValueError(f"SceneSpec.layout '{self.layout}' is not one of {LAYOUTS}")
        if self.texture not in TEXTURE_MODES:
            raise ValueError(f"SceneSpec.texture '{self.texture}' is not one of {TEXTURE_MODES}")
        if not 2.2 <= self.ceiling_height <= 10.0:
            raise ValueError(f"SceneSpec.ceiling_height {self.ceiling_height} m is outside [2.2, 10] m")
        if self.num_furniture < 0:
            raise ValueError("SceneSpec.num_furniture must be >= 0")
        if self.light_intensity < 0:
            raise ValueError("SceneSpec.light_intensity must be >= 0")


@dataclass
class Room:
    name: str
    bounds: tuple[float, float, float, float]  # interior (x0, y0, x1, y1), metres
    ceiling_height: float
    kind: str = "room"  # "room" or "corridor" (corridors stay free of furniture)

    @property
    def area(self) -> float:
        x0, y0, x1, y1 = self.bounds
        return (x1 - x0) * (y1 - y0)

    def center_xy(self) -> np.ndarray:
        x0, y0, x1, y1 = self.bounds
        return np.array([(x0 + x1) / 2, (y0 + y1) / 2])

    def polygon(self) -> Polygon:
        return box(*self.bounds)


@dataclass(kw_only=True)
class Door:
    """An opening through the wall between ``rooms[0]`` and ``rooms[1]``.

    ``axis`` 0: the wall is a plane x = const (the door is crossed along x);
    ``axis`` 1: y = const. ``wall`` holds the two wall faces' coordinates on that
    axis (low, high), ``span`` the opening's extent along the other axis.
    """

    rooms: tuple[int, int]
    axis: int
    wall: tuple[float, float]
    span: tuple[float, float]
    height: float

    @property
    def width(self) -> float:
        return self.span[1] - self.span[0]

    def segment(self) -> np.ndarray:
        """(2, 2) end points of the opening on the wall's mid-plane."""
        mid = 0.5 * (self.wall[0] + self.wall[1])
        pts = np.array([[mid, self.span[0]], [mid, self.span[1]]])
        return pts if self.axis == 0 else pts[:, ::-1].copy()

    def polygon(self) -> Polygon:
        """Floor area of the opening (through the wall thickness)."""
        if self.axis == 0:
            return box(self.wall[0], self.span[0], self.wall[1], self.span[1])
        return box(self.span[0], self.wall[0], self.span[1], self.wall[1])


@dataclass(kw_only=True)
class Furniture:
    kind: str  # "box", "table" or "shelf"
    room: int
    bounds: tuple[float, float, float, float]  # footprint (x0, y0, x1, y1)
    height: float
    front: tuple[float, float]  # horizontal unit normal of the side facing the room

    def polygon(self) -> Polygon:
        return box(*self.bounds)


@dataclass
class Light:
    position: np.ndarray  # (3,) metres
    intensity: float  # already scaled by SceneSpec.light_intensity
    room: int


@dataclass(kw_only=True)
class WallSegment:
    """Interior face of one room wall, as seen from inside the room: ``start`` is
    on the viewer's left, ``normal`` points into the room."""

    room: int
    start: np.ndarray  # (2,)
    end: np.ndarray  # (2,)
    normal: np.ndarray  # (2,)
    height: float
    openings: list[tuple[float, float]]  # door intervals, metres along start -> end

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))


@dataclass(kw_only=True)
class Scene:
    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (T, 3) int32
    triangle_uvs: np.ndarray  # (T, 3, 2) float32, texture units (see module doc)
    triangle_texture: np.ndarray  # (T,) int32 index into textures
    textures: list[np.ndarray]  # H x W x 3 uint8 RGB
    triangle_room: np.ndarray | None = None  # (T,) int32, -1: no room (lit by ambient only)
    rooms: list[Room] = field(default_factory=list)
    doors: list[Door] = field(default_factory=list)
    # Outer outline(s) of floor_geometry(), (N, 2) counter-clockwise; wall pieces
    # enclosed by doors on both ends (holes) are not subtracted.
    floor_polygons: list[np.ndarray] = field(default_factory=list)
    lights: list[Light] = field(default_factory=list)
    ambient: float = 0.35  # shading floor, already scaled by SceneSpec.light_intensity
    furniture: list[Furniture] = field(default_factory=list)
    spec: SceneSpec | None = None

    def __post_init__(self):
        if self.triangle_room is None:
            self.triangle_room = np.full(len(self.triangles), -1, np.int32)

    def floor_geometry(self):
        """Exact walkable-floor area before furniture: rooms plus door openings
        (shapely; interior wall pieces enclosed by doors on both ends are holes)."""
        return unary_union([r.polygon() for r in self.rooms] + [d.polygon() for d in self.doors])

    def free_space_polygon(self, margin: float = 0.3):
        """Where the centre of an agent of radius ``margin`` may walk: the floor
        minus furniture footprints, shrunk by ``margin`` (shapely geometry)."""
        blocked = unary_union([f.polygon() for f in self.furniture])
        return self.floor_geometry().difference(blocked).buffer(-margin)

    def wall_segments(self) -> list[WallSegment]:
        out = []
        for i, room in enumerate(self.rooms):
            for start, direction, length, normal in _room_walls(room):
                end = start + length * direction
                openings = _door_intervals(i, room, start, direction, length, normal, self.doors)
                out.append(
                    WallSegment(
                        room=i, start=start, end=end, normal=normal, height=room.ceiling_height, openings=openings
                    )
                )
        return out

    def room_at(self, xy) -> int:
        """Index of the room containing ``xy`` or, outside all rooms (doorways), the nearest one."""
        p = Point(float(xy[0]), float(xy[1]))
        if not self.rooms:
            return -1
        dists = [r.polygon().distance(p) for r in self.rooms]
        return int(np.argmin(dists))


# ----------------------------------------------------------------------------------
# Layouts


def _split_span(rng, a: float, b: float, min_w: float, max_w: float) -> list[tuple[float, float]]:
    """Cut [a, b] into rooms about [min_w, max_w] wide, separated by walls."""
    t = WALL_THICKNESS
    n_lo = math.ceil((b - a + t) / (max_w + t))
    n_hi = max(n_lo, math.floor((b - a + t) / (min_w + t)))
    n = int(rng.integers(n_lo, n_hi + 1))
    widths = rng.uniform(0.8, 1.2, n)
    widths *= (b - a - (n - 1) * t) / widths.sum()
    spans, x = [], a
    for i, w in enumerate(widths):
        hi = b if i == n - 1 else round(x + w, 3)
        spans.append((x, hi))
        x = round(hi + t, 3)  # the next room starts exactly one wall further
    return spans


def _layout(spec: SceneSpec, rng) -> tuple[list[Room], list[tuple[int, int]]]:
    """Rooms and which pairs get a door."""
    h = spec.ceiling_height
    t = WALL_THICKNESS
    if spec.layout == "room_4x4":
        return [Room("room", (0.0, 0.0, 4.0, 4.0), h)], []
    if spec.layout == "two_rooms":
        return [Room("room_a", (0.0, 0.0, 6.0, 5.0), h), Room("room_b", (6.0 + t, 0.0, 12.0 + t, 5.0), h)], [(0, 1)]
    if spec.layout == "office":
        # A corridor along x with two offices on each side; the south offices
        # are also connected to each other.
        rooms = [Room("corridor", (0.0, 4.0 + t, 16.0, 6.0 - t), h, "corridor")]
        for y0, y1 in ((0.0, 4.0), (6.0, 10.0)):
            for x0, x1 in _split_span(rng, 0.0, 16.0, 6.0, 9.0):
                rooms.append(Room(f"office_{len(rooms) - 1}", (x0, y0, x1, y1), h))
        return rooms, [(0, i) for i in range(1, len(rooms))] + [(1, 2)]
    # floor_40x20: a corridor along x, rows of rooms north and south of it; deep
    # rooms are split into a front room (on the corridor) and a back room.
    rooms = [Room("corridor", (0.0, 9.05, 40.0, 10.95), h, "corridor")]
    pairs: list[tuple[int, int]] = []
    for y_outer, y_corr in ((0.0, 8.95), (20.0, 11.05)):
        front_prev = None
        for x0, x1 in _split_span(rng, 0.0, 40.0, 4.0, 7.5):
            lo, hi = min(y_outer, y_corr), max(y_outer, y_corr)
            if rng.random() < 0.5:
                depth = float(rng.uniform(3.6, 5.2))  # of the back room
                if y_outer < y_corr:
                    back, front = (lo, round(lo + depth, 3)), (round(lo + depth + t, 3), hi)
                else:
                    back, front = (round(hi - depth, 3), hi), (lo, round(hi - depth - t, 3))
                rooms.append(Room(f"room_{len(rooms) - 1}", (x0, front[0], x1, front[1]), h))
                front_idx = len(rooms) - 1
                rooms.append(Room(f"room_{len(rooms) - 1}", (x0, back[0], x1, back[1]), h))
                pairs.append((front_idx, front_idx + 1))
            else:
                rooms.append(Room(f"room_{len(rooms) - 1}", (x0, lo, x1, hi), h))
                front_idx = len(rooms) - 1
            pairs.append((0, front_idx))
            if front_prev is not None and rng.random() < 0.35:
                pairs.append((front_prev, front_idx))
            front_prev = front_idx
    return rooms, pairs


def _place_door(rooms: list[Room], i: int, j: int, rng, height: float) -> Door:
    a, b = rooms[i].bounds, rooms[j].bounds
    margin = 0.3
    for axis in (0, 1):
        other = 1 - axis
        if abs(a[axis + 2] + WALL_THICKNESS - b[axis]) < 1e-6:
            wall = (a[axis + 2], b[axis])
        elif abs(b[axis + 2] + WALL_THICKNESS - a[axis]) < 1e-6:
            wall = (b[axis + 2], a[axis])
        else:
            continue
        lo, hi = max(a[other], b[other]), min(a[other + 2], b[other + 2])
        if hi - lo < DOOR_WIDTH + 2 * margin:
            continue
        c = round(float(rng.uniform(lo + margin + DOOR_WIDTH / 2, hi - margin - DOOR_WIDTH / 2)), 3)
        return Door(rooms=(i, j), axis=axis, wall=wall, span=(c - DOOR_WIDTH / 2, c + DOOR_WIDTH / 2), height=height)
    raise ValueError(f"rooms {rooms[i].name} and {rooms[j].name} share no wall wide enough for a door")


def _room_walls(room: Room):
    """(start, direction, length, inward normal) of the four walls, each running
    left to right as seen from inside the room."""
    x0, y0, x1, y1 = room.bounds
    return [
        (np.array([x1, y0]), np.array([-1.0, 0.0]), x1 - x0, np.array([0.0, 1.0])),
        (np.array([x0, y0]), np.array([0.0, 1.0]), y1 - y0, np.array([1.0, 0.0])),
        (np.array([x0, y1]), np.array([1.0, 0.0]), x1 - x0, np.array([0.0, -1.0])),
        (np.array([x1, y1]), np.array([0.0, -1.0]), y1 - y0, np.array([-1.0, 0.0])),
    ]


def _door_intervals(room_idx, room, start, direction, length, normal, doors) -> list[tuple[float, float]]:
    """Door openings on one wall of a room, as sorted intervals along the wall."""
    out = []
    for d in doors:
        if room_idx not in d.rooms or abs(normal[d.axis]) < 0.5:
            continue
        # The room's wall face on the door's axis: its low face has an inward
        # normal of +1, which must touch the door's high wall coordinate.
        face = room.bounds[d.axis] if normal[d.axis] > 0 else room.bounds[d.axis + 2]
        if abs(face - (d.wall[1] if normal[d.axis] > 0 else d.wall[0])) > 1e-6:
            continue
        other = 1 - d.axis
        s = sorted((c - start[other]) * direction[other] for c in d.span)
        out.append((max(0.0, s[0]), min(length, s[1])))
    return sorted(out)


def _place_furniture(rng, room_idx: int, room: Room, doors: list[Door], count: int) -> list[Furniture]:
    """Put up to ``count`` pieces in the room, keeping every door reachable and the
    walkable floor in one piece."""
    rp = room.polygon()
    x0, y0, x1, y1 = room.bounds
    clear, approach = [], []
    for d in doors:
        if room_idx not in d.rooms:
            continue
        seg = d.segment()
        mid = seg.mean(axis=0)
        inward = np.sign(room.center_xy()[d.axis] - mid[d.axis])
        step = np.zeros(2)
        step[d.axis] = inward
        approach.append(Point(*(mid + 0.5 * step)))
        clear.append(shapely.LineString([seg[0], seg[1]]).buffer(1.3, cap_style="flat"))
    keep_clear = unary_union(clear) if clear else Polygon()
    placed: list[Furniture] = []
    for _ in range(count):
        for _attempt in range(40):
            kind = FURNITURE_KINDS[int(rng.integers(len(FURNITURE_KINDS)))]
            if kind == "shelf":
                w, d, h = rng.uniform(0.8, 1.6), rng.uniform(0.3, 0.45), rng.uniform(1.6, 2.1)
            elif kind == "table":
                w, d, h = rng.uniform(1.0, 1.8), rng.uniform(0.6, 0.9), rng.uniform(0.72, 0.78)
            else:
                w, d, h = rng.uniform(0.35, 0.8), rng.uniform(0.35, 0.7), rng.uniform(0.3, 0.9)
            against_wall = kind == "shelf" or rng.random() < 0.6
            if against_wall:
                start, direction, length, normal = _room_walls(room)[int(rng.integers(4))]
                if length < w + 0.2:
                    continue
                s = rng.uniform(0.1 + w / 2, length - 0.1 - w / 2)
                centre = start + s * direction + normal * (0.03 + d / 2)
                half = np.abs(direction) * w / 2 + np.abs(normal) * d / 2
                front = tuple(normal)
            else:
                if x1 - x0 < w + 1.2 or y1 - y0 < d + 1.2:
                    continue
                centre = np.array(
                    [rng.uniform(x0 + 0.6 + w / 2, x1 - 0.6 - w / 2), rng.uniform(y0 + 0.6 + d / 2, y1 - 0.6 - d / 2)]
                )
                half = np.array([w / 2, d / 2]) if rng.random() < 0.5 else np.array([d / 2, w / 2])
                front = (0.0, 1.0)
            bounds = tuple(round(float(v), 4) for v in (*(centre - half), *(centre + half)))
            fp = box(*bounds)
            if not rp.contains(fp) or fp.intersects(keep_clear) or any(fp.distance(o.polygon()) < 0.7 for o in placed):
                continue
            free = rp.difference(unary_union([o.polygon() for o in placed] + [fp])).buffer(-0.3)
            if free.geom_type != "Polygon" or free.area < 0.4 * rp.area or not all(free.contains(p) for p in approach):
                continue
            placed.append(Furniture(kind=kind, room=room_idx, bounds=bounds, height=round(float(h), 4), front=front))
            break
    return placed


def _lights(room_idx: int, room: Room, intensity: float, jitter) -> list[Light]:
    """Ceiling lights: one per ~5 m along corridors, a 1x1 to 2x2 grid in rooms."""
    x0, y0, x1, y1 = room.bounds
    w, h = x1 - x0, y1 - y0
    if room.kind == "corridor":
        n_long = max(1, math.ceil(max(w, h) / 5.0))
        nx, ny = (n_long, 1) if w >= h else (1, n_long)
    else:
        nx = 2 if w > 5.0 else 1
        ny = 2 if h > 5.0 else 1
    z = room.ceiling_height - 0.05
    return [
        Light(np.array([x0 + (i + 0.5) * w / nx, y0 + (j + 0.5) * h / ny, z]), intensity * jitter(), room_idx)
        for j in range(ny)
        for i in range(nx)
    ]


def build_scene(spec: SceneSpec) -> Scene:
    """Build the static scene of ``spec``; the same spec (seed) gives the same scene."""
    # Separate streams: the geometry (rooms, doors, furniture, lights) of a seed
    # is the same whatever the texture mode.
    geo_rng, rng = (np.random.default_rng(s) for s in np.random.SeedSequence(spec.seed).spawn(2))
    rooms, pairs = _layout(spec, geo_rng)
    door_h = min(DOOR_HEIGHT, spec.ceiling_height - 0.3)
    doors = [_place_door(rooms, i, j, geo_rng, door_h) for i, j in pairs]
    furniture = [
        f
        for ri, room in enumerate(rooms)
        if room.kind == "room"
        for f in _place_furniture(geo_rng, ri, room, doors, spec.num_furniture)
    ]
    li = spec.light_intensity
    symmetric = spec.texture == "symmetric"
    jitter = (lambda: 1.0) if symmetric else (lambda: float(geo_rng.uniform(0.85, 1.15)))
    lights = [light for ri, room in enumerate(rooms) for light in _lights(ri, room, 1.0 * li, jitter)]
    mb = MeshBuilder()
    pal = make_palette(spec.texture, rng, mb)

    def pick(seq: list[int]) -> int:
        return seq[int(rng.integers(len(seq)))]

    rich = spec.texture == "rich"
    eps = SEAM_OVERLAP
    for ri, room in enumerate(rooms):
        x0, y0, x1, y1 = room.bounds
        H = room.ceiling_height
        floor_tex, ceil_tex = pick(pal.floors), pick(pal.ceilings)
        floor_off = tuple(rng.uniform(0, 2, 2)) if rich else (0.0, 0.0)
        mb.rect((0, 0, 0), (1, 0, 0), (0, 1, 0), (x0, x1), (y0, y1), floor_tex, ri, uv_offset=floor_off, grow=eps)
        mb.rect((0, 0, H), (1, 0, 0), (0, 1, 0), (x0, x1), (y0, y1), ceil_tex, ri, grow=eps)
        for start, direction, length, normal in _room_walls(room):
            tex = pick(pal.walls)
            off = tuple(rng.uniform(0, 2, 2)) if rich else (0.0, 0.0)
            origin = (start[0], start[1], H)
            ax_u = (direction[0], direction[1], 0.0)
            openings = _door_intervals(ri, room, start, direction, length, normal, doors)
            pieces = wall_pieces(length, openings)
            for s0, s1 in pieces:
                mb.rect(origin, ax_u, (0, 0, -1), (s0, s1), (0.0, H), tex, ri, uv_offset=off, grow=eps)
            for s0, s1 in openings:  # lintel above the door
                mb.rect(origin, ax_u, (0, 0, -1), (s0, s1), (0.0, H - door_h), tex, ri, uv_offset=off, grow=eps)
            if rich or symmetric:
                for s0, s1, z_top, z_bottom, kind in wall_items(rng, pieces, H, symmetric):
                    if symmetric:
                        ptex = pal.poster
                    else:
                        make = textures.poster if kind == "poster" else textures.decal
                        ptex = mb.add_texture(make(rng, texels(s1 - s0), texels(z_top - z_bottom)))
                    p_origin = (start[0] + normal[0] * POSTER_OFFSET, start[1] + normal[1] * POSTER_OFFSET, z_top)
                    mb.rect(
                        p_origin,
                        ax_u,
                        (0, 0, -1),
                        (s0, s1),
                        (0.0, z_top - z_bottom),
                        ptex,
                        ri,
                        uv_scale=(1.0 / (s1 - s0), 1.0 / (z_top - z_bottom)),
                        uv_offset=(-s0, 0.0),
                    )
    for d in doors:
        door_mesh(mb, d, pal, door_h)
    for f in furniture:
        furniture_mesh(mb, f, pal, rng)
    vertices, triangles, uvs, tex_idx, tri_room = mb.mesh()
    floor = unary_union([r.polygon() for r in rooms] + [d.polygon() for d in doors])
    polys = [floor] if floor.geom_type == "Polygon" else list(floor.geoms)
    floor_polygons = [np.asarray(orient(p, 1.0).exterior.coords)[:-1] for p in polys]
    return Scene(
        vertices=vertices,
        triangles=triangles,
        triangle_uvs=uvs,
        triangle_texture=tex_idx,
        textures=mb.textures,
        triangle_room=tri_room,
        rooms=rooms,
        doors=doors,
        floor_polygons=floor_polygons,
        lights=lights,
        ambient=0.35 * li,
        furniture=furniture,
        spec=spec,
    )
