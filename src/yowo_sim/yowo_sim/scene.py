"""Static indoor scenes (rooms, doors, furniture, textures, lights) with ground truth.

World frame ``map``: metres, z up (REP 103); floor at z = 0, ceiling at
z = ``ceiling_height``. Rooms are axis-aligned rectangles given by their
*interior* wall faces; neighbouring rooms are ``WALL_THICKNESS`` apart and a door
is an opening through that gap. Only the surfaces visible from inside the rooms
are meshed (walls have no outer faces), which is all a camera inside can see.

UV convention: ``Scene.triangle_uvs`` are in units of the texture size, (0, 0) at
the top-left corner of the texture image and (1, 1) at its bottom-right corner;
values outside [0, 1] repeat (tiling), so large surfaces keep a constant texel
density of ``TEXELS_PER_METRE``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import shapely
from shapely.geometry import Point, Polygon, box
from shapely.geometry.polygon import orient
from shapely.ops import unary_union

LAYOUTS = ("room_4x4", "two_rooms", "office", "floor_40x20")
TEXTURE_MODES = ("rich", "poor", "symmetric")

WALL_THICKNESS = 0.1
TEXELS_PER_METRE = 256.0
DOOR_HEIGHT = 2.1
DOOR_WIDTH = 1.0
# Surfaces overlap by this much at junctions so that no ray slips through a crack
# between two triangles that only touch.
SEAM_OVERLAP = 1e-3
# Large surfaces are cut into patches no longer than this, so per-triangle data
# (the renderer's light map) keeps a uniform resolution.
MAX_PATCH = 4.0
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


@dataclass
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


@dataclass
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


@dataclass
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


@dataclass
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
                out.append(WallSegment(i, start, end, normal, room.ceiling_height, openings))
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
        return Door((i, j), axis, wall, (c - DOOR_WIDTH / 2, c + DOOR_WIDTH / 2), height)
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


# ----------------------------------------------------------------------------------
# Procedural textures (RGB uint8). Tiling textures wrap seamlessly.

_LETTERS = np.array(list("ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"))


def _noise(rng, h: int, w: int, beta: float) -> np.ndarray:
    """Tileable 1/f^beta noise with unit standard deviation (via FFT, so it wraps)."""
    ky = np.fft.fftfreq(h)[:, None]
    kx = np.fft.rfftfreq(w)[None, :]
    k = np.sqrt(kx * kx + ky * ky)
    k[0, 0] = 1.0
    amp = k ** (-beta / 2.0)
    amp[0, 0] = 0.0
    spectrum = amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape))
    n = np.fft.irfft2(spectrum, s=(h, w))
    return (n / (n.std() + 1e-12)).astype(np.float32)


def _colour(rng, hue=(0, 180), sat=(40, 200), val=(80, 220)) -> np.ndarray:
    hsv = np.array([[[rng.uniform(*hue), rng.uniform(*sat), rng.uniform(*val)]]], np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def _shade(base: np.ndarray, factor: np.ndarray) -> np.ndarray:
    return np.clip(base[None, None, :] * factor[..., None], 0, 255).astype(np.uint8)


def _wrapped(img: np.ndarray, draw) -> None:
    """Draw a shape and its 8 periodic copies, so the texture still tiles."""
    h, w = img.shape[:2]
    for dy in (-h, 0, h):
        for dx in (-w, 0, w):
            draw(dx, dy)


def _random_shapes(rng, img: np.ndarray, count: int, size: tuple[int, int], wrap: bool) -> None:
    h, w = img.shape[:2]
    for _ in range(count):
        col = tuple(int(c) for c in _colour(rng, val=(20, 250)))
        kind = int(rng.integers(5))
        cx, cy = int(rng.integers(w)), int(rng.integers(h))
        s = int(rng.integers(*size))
        thick = -1 if rng.random() < 0.6 else int(rng.integers(1, 5))
        pts = (rng.uniform(-s, s, (int(rng.integers(3, 7)), 2))).astype(np.int32)
        angle = float(rng.uniform(0, 180))
        text = "".join(rng.choice(_LETTERS, int(rng.integers(2, 6))))
        scale = s / 30.0

        def draw(dx, dy, kind=kind, col=col, cx=cx, cy=cy, s=s, thick=thick, pts=pts):
            c = (cx + dx, cy + dy)
            if kind == 0:
                cv2.circle(img, c, s, col, thick, cv2.LINE_AA)
            elif kind == 1:
                cv2.rectangle(img, (c[0] - s, c[1] - s // 2), (c[0] + s, c[1] + s // 2), col, thick, cv2.LINE_AA)
            elif kind == 2:
                cv2.fillPoly(img, [pts + np.array(c)], col, cv2.LINE_AA)
            elif kind == 3:
                cv2.ellipse(img, c, (s, max(2, s // 3)), angle, 0, 360, col, thick, cv2.LINE_AA)
            else:
                cv2.putText(
                    img, text, (c[0] - s, c[1]), cv2.FONT_HERSHEY_SIMPLEX, scale, col, max(1, s // 12), cv2.LINE_AA
                )

        if wrap:
            _wrapped(img, draw)
        else:
            draw(0, 0)


def _tex_flat(rng, size: int, colour: np.ndarray, amplitude: float) -> np.ndarray:
    """Nearly uniform surface: only a faint, smooth variation (texture-poor case)."""
    return _shade(colour, 1.0 + amplitude * _noise(rng, size, size, 4.0))


def _tex_plaster(rng, h: int, w: int) -> np.ndarray:
    img = _shade(
        _colour(rng, sat=(10, 70), val=(170, 225)), 1.0 + 0.05 * _noise(rng, h, w, 3.0) + 0.03 * _noise(rng, h, w, 1.0)
    )
    for _ in range(h * w // 15000):  # stains and scuffs
        col = tuple(int(c) for c in _colour(rng, sat=(0, 90), val=(60, 200)))
        c = rng.integers(0, (w, h))
        ax = tuple(int(a) for a in rng.integers(3, 25, 2))
        ang = float(rng.uniform(0, 180))
        _wrapped(
            img,
            lambda dx, dy: cv2.ellipse(img, (int(c[0]) + dx, int(c[1]) + dy), ax, ang, 0, 360, col, -1, cv2.LINE_AA),
        )
    for _ in range(h * w // 30000):  # cracks and scribbles
        pts = np.cumsum(rng.normal(0, 12, (int(rng.integers(4, 12)), 2)), axis=0) + rng.integers(0, (w, h))
        col = tuple(int(c) for c in _colour(rng, val=(30, 120)))
        _wrapped(
            img, lambda dx, dy: cv2.polylines(img, [(pts + [dx, dy]).astype(np.int32)], False, col, 1, cv2.LINE_AA)
        )
    return img


def _tex_brick(rng, h: int, w: int) -> np.ndarray:
    rows, per_row = max(2, 2 * round(h / 43)), max(1, round(w / 64))  # ~0.08 x 0.25 m bricks
    y = np.arange(h)[:, None] * rows / h
    x = np.arange(w)[None, :] * per_row / w
    row = np.floor(y).astype(int)
    xs = x + 0.5 * (row % 2)
    brick_id = row * per_row + np.floor(xs).astype(int) % per_row
    tint = rng.uniform(0.75, 1.2, rows * per_row)[brick_id]
    mortar = ((y - row) < 0.12) | ((xs - np.floor(xs)) < 0.04)
    base = _colour(rng, hue=(0, 15), sat=(120, 200), val=(120, 190))
    img = _shade(base, tint * (1.0 + 0.08 * _noise(rng, h, w, 1.5)))
    img[mortar] = _shade(np.array([190.0, 185.0, 175.0]), 1.0 + 0.05 * _noise(rng, h, w, 2.0))[mortar]
    return img


def _tex_wallpaper(rng, h: int, w: int) -> np.ndarray:
    img = _shade(_colour(rng, sat=(20, 120), val=(150, 220)), 1.0 + 0.04 * _noise(rng, h, w, 2.5))
    _random_shapes(rng, img, h * w // 6000, (5, 22), wrap=True)
    return img


def _tex_planks(rng, h: int, w: int, plank_px: int, vertical: bool) -> np.ndarray:
    """Wood boards ``plank_px`` wide with grain; ``vertical``: boards run top to bottom."""
    # Grain: noise stretched along the boards.
    ky = np.fft.fftfreq(h)[:, None]
    kx = np.fft.rfftfreq(w)[None, :]
    k = np.sqrt(kx**2 + (ky * 12.0) ** 2) if vertical else np.sqrt((kx * 12.0) ** 2 + ky**2)
    k[0, 0] = 1.0
    amp = k**-1.2
    amp[0, 0] = 0.0
    grain = np.fft.irfft2(amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape)), s=(h, w))
    grain = (grain / grain.std()).astype(np.float32)
    if vertical:
        tint = rng.uniform(0.75, 1.2, w // plank_px + 1)[np.arange(w) // plank_px][None, :]
        gap = np.broadcast_to(((np.arange(w) % plank_px) < 2)[None, :], (h, w))
    else:  # rows of 1/4-width boards, with the board ends staggered per row
        rows = np.arange(h) // plank_px
        along = (np.arange(w)[None, :] + rng.integers(0, w, rows.max() + 1)[rows][:, None]) % w
        board = rows[:, None] * 4 + along // (w // 4)
        tint = rng.uniform(0.75, 1.2, board.max() + 1)[board]
        gap = ((np.arange(h) % plank_px) < 2)[:, None] | ((along % (w // 4)) < 2)
    base = _colour(rng, hue=(8, 22), sat=(90, 170), val=(110, 200))
    img = _shade(base, tint * (1.0 + 0.12 * grain))
    img[gap] //= 2
    for _ in range(h * w // 40000):  # knots
        c = rng.integers(0, (w, h))
        ax = (int(rng.integers(3, 8)), int(rng.integers(6, 14)))
        angle = 0.0 if vertical else 90.0
        _wrapped(
            img,
            lambda dx, dy: cv2.ellipse(
                img, (int(c[0]) + dx, int(c[1]) + dy), ax, angle, 0, 360, (70, 45, 25), -1, cv2.LINE_AA
            ),
        )
    return img


def _tex_tiles(rng, h: int, w: int, cell: int, decorated: bool) -> np.ndarray:
    ny, nx = h // cell, w // cell
    iy, ix = np.arange(h) // cell, np.arange(w) // cell
    tile_id = iy[:, None] * nx + ix[None, :]
    base = _colour(rng, sat=(10, 150), val=(140, 230))
    img = _shade(base, rng.uniform(0.85, 1.12, ny * nx)[tile_id] * (1.0 + 0.03 * _noise(rng, h, w, 2.0)))
    img[(np.arange(h) % cell) < 3, :] = (110, 105, 100)  # grout
    img[:, (np.arange(w) % cell) < 3] = (110, 105, 100)
    if decorated:  # some tiles carry a motif
        for tile in rng.choice(ny * nx, ny * nx // 4, replace=False):
            ty, tx = divmod(int(tile), nx)
            sub = img[ty * cell + 3 : (ty + 1) * cell, tx * cell + 3 : (tx + 1) * cell]
            _random_shapes(rng, sub, 3, (3, max(4, cell // 4)), wrap=False)
    return img


def _tex_concrete(rng, h: int, w: int) -> np.ndarray:
    grey = float(rng.uniform(120, 175))
    img = _shade(
        np.array([grey, grey * 0.98, grey * 0.95]), 1.0 + 0.10 * _noise(rng, h, w, 2.2) + 0.05 * _noise(rng, h, w, 0.8)
    )
    step = 128  # form-tie holes every 0.5 m
    for y in range(step // 2, h, step):
        for x in range(step // 2, w, step):
            cv2.circle(img, (x, y), 5, (50, 50, 50), -1, cv2.LINE_AA)
    for _ in range(h * w // 25000):  # pores and stains
        c = rng.integers(0, (w, h))
        r = int(rng.integers(2, 14))
        v = int(rng.uniform(60, 200))
        _wrapped(img, lambda dx, dy: cv2.circle(img, (int(c[0]) + dx, int(c[1]) + dy), r, (v, v, v), -1, cv2.LINE_AA))
    return img


def _tex_carpet(rng, h: int, w: int) -> np.ndarray:
    a, b = _colour(rng, val=(70, 160)), _colour(rng, val=(70, 160))
    mix = (np.tanh(1.5 * _noise(rng, h, w, 2.5)) + 1.0) / 2.0
    fibres = 1.0 + 0.15 * _noise(rng, h, w, 0.3)
    img = (a[None, None] * mix[..., None] + b[None, None] * (1.0 - mix[..., None])) * fibres[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def _tex_ceiling(rng, size: int) -> np.ndarray:
    """Acoustic ceiling tiles (0.5 m grid) with speckles."""
    img = _shade(np.array([225.0, 225.0, 220.0]), 1.0 + 0.06 * _noise(rng, size, size, 0.5))
    cell = size // 4
    grid = (np.arange(size) % cell) < 3
    img[grid, :] = (170, 170, 170)
    img[:, grid] = (170, 170, 170)
    return img


def _tex_books(rng, size: int) -> np.ndarray:
    """Bookshelf front: boards every ~0.4 m with rows of books."""
    img = np.zeros((size, size, 3), np.uint8)
    wood = _tex_planks(rng, size, size, size // 4, vertical=False)
    shelves = 5
    gap = size // shelves
    for s in range(shelves):
        top = s * gap
        img[top : top + gap] = (wood[top : top + gap] * 0.35).astype(np.uint8)  # dark shelf interior
        img[top + gap - 10 : top + gap] = wood[top + gap - 10 : top + gap]  # the board
        x = 0
        while x < size:
            bw = int(rng.integers(6, 22))
            bh = int(rng.integers(gap // 2, gap - 14))
            col = tuple(int(c) for c in _colour(rng, val=(40, 230)))
            y1 = top + gap - 10
            cv2.rectangle(img, (x, y1 - bh), (x + bw - 2, y1 - 1), col, -1)
            if rng.random() < 0.7:  # title band
                band = tuple(int(255 - c) for c in col)
                yb = y1 - bh + int(rng.integers(5, max(6, bh // 2)))
                cv2.rectangle(img, (x + 1, yb), (x + bw - 3, yb + 3), band, -1)
            x += bw + int(rng.integers(0, 3)) + (int(rng.integers(10, 40)) if rng.random() < 0.1 else 0)
    return img


def _tex_cardboard(rng, size: int) -> np.ndarray:
    img = _shade(np.array([170.0, 130.0, 85.0]) * rng.uniform(0.8, 1.1), 1.0 + 0.06 * _noise(rng, size, size, 1.2))
    tape = int(rng.integers(size // 3, 2 * size // 3))
    img[:, tape - 12 : tape + 12] = (200, 180, 140)
    x, y = int(rng.integers(20, size // 2)), int(rng.integers(20, size // 2))
    cv2.rectangle(img, (x, y), (x + size // 3, y + size // 5), (235, 235, 230), -1)
    for k in range(3):
        text = "".join(rng.choice(_LETTERS, int(rng.integers(4, 8))))
        cv2.putText(img, text, (x + 4, y + 14 + 14 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (20, 20, 20), 1, cv2.LINE_AA)
    _random_shapes(rng, img, 4, (8, 30), wrap=False)
    return img


def _tex_poster(rng, w: int, h: int) -> np.ndarray:
    """A unique picture: gradient or cloudy background, random shapes and text, a frame."""
    c0, c1 = _colour(rng), _colour(rng)
    if rng.random() < 0.5:
        ramp = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None, None]
        img = (c0 * (1 - ramp) + c1 * ramp) * np.ones((1, w, 1), np.float32)
    else:
        mix = (np.tanh(_noise(rng, h, w, 3.0)) + 1.0)[..., None] / 2.0
        img = c0 * mix + c1 * (1.0 - mix)
    img = np.clip(img, 0, 255).astype(np.uint8)
    _random_shapes(rng, img, int(rng.integers(8, 20)), (max(4, min(w, h) // 20), max(6, min(w, h) // 5)), wrap=False)
    frame = max(3, min(w, h) // 25)
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), tuple(int(c) for c in _colour(rng, val=(10, 90))), 2 * frame)
    return img


def _tex_decal(rng, w: int, h: int) -> np.ndarray:
    """Small wall item: a sign, a note, a switch plate or a little picture."""
    kind = int(rng.integers(4))
    if kind == 3:
        return _tex_poster(rng, w, h)
    bg = _colour(rng, val=(60, 230)) if kind == 0 else np.array([235.0, 232.0, 220.0]) * rng.uniform(0.85, 1.0)
    img = np.empty((h, w, 3), np.uint8)
    img[:] = bg.astype(np.uint8)
    ink = tuple(int(c) for c in (_colour(rng, val=(0, 90)) if bg.mean() > 120 else _colour(rng, val=(200, 255))))
    if kind == 2:  # switch / socket plate
        for _ in range(int(rng.integers(1, 3))):
            x0, y0 = int(rng.integers(0, w // 2)), int(rng.integers(0, h // 2))
            cv2.rectangle(img, (x0 + w // 8, y0 + h // 8), (x0 + w // 2, y0 + h // 2), (150, 150, 150), -1, cv2.LINE_AA)
            cv2.circle(img, (x0 + w // 4, y0 + h // 4), max(2, min(w, h) // 12), (40, 40, 40), -1, cv2.LINE_AA)
    else:  # sign or note: lines of text
        line_h = max(8, h // int(rng.integers(2, 6)))
        for y in range(line_h, h - 2, line_h):
            text = "".join(rng.choice(_LETTERS, max(2, w // max(6, line_h // 2))))
            cv2.putText(
                img, text, (3, y - 2), cv2.FONT_HERSHEY_SIMPLEX, line_h / 40.0, ink, max(1, line_h // 16), cv2.LINE_AA
            )
    cv2.rectangle(img, (0, 0), (w - 1, h - 1), ink, max(1, min(w, h) // 30))
    return img


def _tex_motif_tiled(rng, size: int, repeats: int) -> np.ndarray:
    """One motif repeated on a regular grid: locally rich, globally ambiguous."""
    cell = size // repeats
    motif = _tex_poster(rng, cell, cell)
    return np.tile(motif, (repeats, repeats, 1))


# ----------------------------------------------------------------------------------
# Mesh assembly


class _MeshBuilder:
    def __init__(self):
        self.vertices: list[np.ndarray] = []
        self.uvs: list[np.ndarray] = []
        self.texture: list[int] = []
        self.room: list[int] = []
        self.textures: list[np.ndarray] = []

    def add_texture(self, img: np.ndarray) -> int:
        self.textures.append(img)
        return len(self.textures) - 1

    def rect(
        self,
        origin,
        ax_u,
        ax_v,
        a: tuple[float, float],
        b: tuple[float, float],
        tex: int,
        room: int,
        uv_scale=None,
        uv_offset=(0.0, 0.0),
        grow: float = 0.0,
        patch: float = MAX_PATCH,
    ) -> None:
        """Planar rectangle {origin + s ax_u + t ax_v : s in a, t in b}, with the
        texture mapped by u = (s + uv_offset[0]) * uv_scale[0] (same for v), so
        ax_u runs along the image's columns and ax_v down its rows. Cut into
        patches of at most ``patch`` metres, each grown by ``grow`` to seal seams."""
        origin, ax_u, ax_v = (np.asarray(x, dtype=float) for x in (origin, ax_u, ax_v))
        if uv_scale is None:
            th, tw = self.textures[tex].shape[:2]
            uv_scale = (TEXELS_PER_METRE / tw, TEXELS_PER_METRE / th)
        s_edges = np.linspace(a[0], a[1], max(1, math.ceil((a[1] - a[0]) / patch - 1e-9)) + 1)
        t_edges = np.linspace(b[0], b[1], max(1, math.ceil((b[1] - b[0]) / patch - 1e-9)) + 1)
        for s0, s1 in zip(s_edges[:-1] - grow, s_edges[1:] + grow):
            for t0, t1 in zip(t_edges[:-1] - grow, t_edges[1:] + grow):
                st = np.array([[s0, t0], [s1, t0], [s1, t1], [s0, t1]])
                corners = origin + st[:, :1] * ax_u + st[:, 1:] * ax_v
                uv = (st + uv_offset) * uv_scale
                for tri in ((0, 1, 2), (0, 2, 3)):
                    self.vertices.append(corners[list(tri)])
                    self.uvs.append(uv[list(tri)])
                    self.texture.append(tex)
                    self.room.append(room)

    def box(
        self,
        lo,
        hi,
        room: int,
        side_tex: int,
        top_tex: int,
        bottom: bool = False,
        front: tuple[float, float] | None = None,
        front_tex: int | None = None,
        rng=None,
    ) -> None:
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        half = np.array([(x1 - x0) / 2, (y1 - y0) / 2])
        offset = tuple(rng.uniform(0, 1, 2)) if rng is not None else (0.0, 0.0)
        for n in ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0)):
            n = np.array(n)
            u = np.array([-n[1], n[0]])  # viewer's right when facing this side
            corner = centre + n * (np.abs(n) @ half) - u * (np.abs(u) @ half)
            width = 2.0 * (np.abs(u) @ half)
            tex = front_tex if front is not None and np.allclose(n, front) else side_tex
            self.rect(
                (corner[0], corner[1], z1),
                (u[0], u[1], 0.0),
                (0, 0, -1),
                (0.0, width),
                (0.0, z1 - z0),
                tex,
                room,
                uv_offset=offset if tex != front_tex else (0.0, 0.0),
            )
        self.rect((x0, y0, z1), (1, 0, 0), (0, 1, 0), (0.0, x1 - x0), (0.0, y1 - y0), top_tex, room, uv_offset=offset)
        if bottom:
            self.rect((x0, y0, z0), (1, 0, 0), (0, 1, 0), (0.0, x1 - x0), (0.0, y1 - y0), top_tex, room)

    def mesh(self):
        tri_vertices = np.array(self.vertices, dtype=np.float32).reshape(-1, 3)
        triangles = np.arange(len(tri_vertices), dtype=np.int32).reshape(-1, 3)
        # Merge shared corners so the mesh is indexed, not a triangle soup.
        unique, inverse = np.unique(tri_vertices, axis=0, return_inverse=True)
        return (
            unique.astype(np.float32),
            inverse.reshape(-1)[triangles].astype(np.int32),
            np.array(self.uvs, dtype=np.float32).reshape(-1, 3, 2),
            np.array(self.texture, dtype=np.int32),
            np.array(self.room, dtype=np.int32),
        )


@dataclass
class _Palette:
    """Texture indices a scene draws from."""

    walls: list[int]
    floors: list[int]
    ceilings: list[int]
    wood: list[int]
    boxes: list[int]
    books: list[int]
    poster: int | None  # the one shared poster of the "symmetric" mode


def _make_palette(mode: str, rng, mb: _MeshBuilder) -> _Palette:
    S = 512
    add = mb.add_texture
    if mode == "rich":
        # Walls tile every 4 m x 3 m and floors every 4 m; unique posters and
        # decals on top keep each wall distinct.
        wh, ww, fs = 768, 1024, 1024
        walls = [
            add(_tex_plaster(rng, wh, ww)),
            add(_tex_brick(rng, wh, ww)),
            add(_tex_wallpaper(rng, wh, ww)),
            add(_tex_planks(rng, wh, ww, 32, vertical=True)),
            add(_tex_concrete(rng, wh, ww)),
            add(_tex_tiles(rng, wh, ww, 64, decorated=True)),
            add(_tex_wallpaper(rng, wh, ww)),
            add(_tex_plaster(rng, wh, ww)),
        ]
        floors = [
            add(_tex_planks(rng, fs, fs, 64, vertical=False)),
            add(_tex_tiles(rng, fs, fs, 128, decorated=False)),
            add(_tex_carpet(rng, fs, fs)),
            add(_tex_concrete(rng, fs, fs)),
        ]
        return _Palette(
            walls,
            floors,
            [add(_tex_ceiling(rng, S)), add(_tex_concrete(rng, S, S))],
            [add(_tex_planks(rng, 256, 256, 64, vertical=False)), add(_tex_planks(rng, 256, 256, 64, vertical=True))],
            [add(_tex_cardboard(rng, 256)), add(_tex_cardboard(rng, 256))],
            [add(_tex_books(rng, S))],
            None,
        )
    if mode == "poor":

        def flat(colour, amp=0.006):
            return add(_tex_flat(rng, 256, np.asarray(colour, np.float32), amp))

        return _Palette(
            [flat((200, 198, 192)), flat((192, 196, 200))],
            [flat((150, 145, 138))],
            [flat((225, 225, 225))],
            [flat((150, 110, 70))],
            [flat((170, 135, 90))],
            [flat((120, 90, 60))],
            None,
        )
    # symmetric: one pattern everywhere, posters identical and centred on each wall.
    wall = add(_tex_motif_tiled(rng, S, 4))
    wood = add(_tex_planks(rng, 256, 256, 64, vertical=False))
    return _Palette(
        [wall],
        [add(_tex_tiles(rng, S, S, 128, decorated=False))],
        [add(_tex_ceiling(rng, S))],
        [wood],
        [add(_tex_cardboard(rng, 256))],
        [add(_tex_books(rng, S))],
        add(_tex_poster(rng, 256, 192)),
    )


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
            placed.append(Furniture(kind, room_idx, bounds, round(float(h), 4), front))
            break
    return placed


def _furniture_mesh(mb: _MeshBuilder, f: Furniture, pal: _Palette, rng) -> None:
    x0, y0, x1, y1 = f.bounds
    if f.kind == "box":
        tex = pal.boxes[int(rng.integers(len(pal.boxes)))]
        mb.box((x0, y0, 0.0), (x1, y1, f.height), f.room, tex, tex, rng=rng)
    elif f.kind == "shelf":
        wood = pal.wood[int(rng.integers(len(pal.wood)))]
        mb.box(
            (x0, y0, 0.0),
            (x1, y1, f.height),
            f.room,
            wood,
            wood,
            front=f.front,
            front_tex=pal.books[int(rng.integers(len(pal.books)))],
            rng=rng,
        )
    else:
        wood = pal.wood[int(rng.integers(len(pal.wood)))]
        top = 0.04
        mb.box((x0, y0, f.height - top), (x1, y1, f.height), f.room, wood, wood, bottom=True, rng=rng)
        leg = 0.05
        for lx, ly in ((x0, y0), (x1 - leg, y0), (x0, y1 - leg), (x1 - leg, y1 - leg)):
            mb.box((lx, ly, 0.0), (lx + leg, ly + leg, f.height - top), f.room, wood, wood)


def _texels(metres: float) -> int:
    """Texture size for a surface of this length (a multiple of 16 texels)."""
    return max(16, int(round(metres * TEXELS_PER_METRE / 16)) * 16)


def _wall_pieces(length: float, openings: list[tuple[float, float]]) -> list[tuple[float, float]]:
    pieces, s = [], 0.0
    for o0, o1 in openings:
        if o0 > s:
            pieces.append((s, o0))
        s = max(s, o1)
    if s < length:
        pieces.append((s, length))
    return pieces


def _wall_items(rng, pieces, ceiling: float, symmetric: bool) -> list[tuple[float, float, float, float, str]]:
    """(s0, s1, z_top, z_bottom, kind) of posters and decals along one wall;
    "symmetric" walls get one identical poster centred on each long piece."""
    if symmetric:
        return [
            (0.5 * (p0 + p1) - 0.4, 0.5 * (p0 + p1) + 0.4, 1.8, 1.2, "poster") for p0, p1 in pieces if p1 - p0 >= 1.4
        ]
    out = []
    for p0, p1 in pieces:
        s = p0 + 0.25
        while True:  # posters side by side at eye height
            w = rng.uniform(0.4, 1.2)
            if s + w > p1 - 0.25:
                break
            h = rng.uniform(0.4, min(1.0, ceiling - 1.4))
            bottom = rng.uniform(0.9, min(1.4, ceiling - 0.2 - h))
            if rng.random() < 0.75:
                out.append((s, s + w, bottom + h, bottom, "poster"))
            s += w + rng.uniform(0.3, 1.5)
        for _ in range(int(2.5 * (p1 - p0))):  # decals anywhere that is still free
            w, h = rng.uniform(0.08, 0.4), rng.uniform(0.08, 0.35)
            if p1 - p0 < w + 0.2:
                continue
            s0 = rng.uniform(p0 + 0.1, p1 - 0.1 - w)
            bottom = rng.uniform(0.3, ceiling - 0.3 - h)
            if all(
                s0 > o[1] + 0.05 or s0 + w < o[0] - 0.05 or bottom > o[2] + 0.05 or bottom + h < o[3] - 0.05
                for o in out
            ):
                out.append((s0, s0 + w, bottom + h, bottom, "decal"))
    return out


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
    mb = _MeshBuilder()
    pal = _make_palette(spec.texture, rng, mb)

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
            pieces = _wall_pieces(length, openings)
            for s0, s1 in pieces:
                mb.rect(origin, ax_u, (0, 0, -1), (s0, s1), (0.0, H), tex, ri, uv_offset=off, grow=eps)
            for s0, s1 in openings:  # lintel above the door
                mb.rect(origin, ax_u, (0, 0, -1), (s0, s1), (0.0, H - door_h), tex, ri, uv_offset=off, grow=eps)
            if rich or symmetric:
                for s0, s1, z_top, z_bottom, kind in _wall_items(rng, pieces, H, symmetric):
                    if symmetric:
                        ptex = pal.poster
                    else:
                        make = _tex_poster if kind == "poster" else _tex_decal
                        ptex = mb.add_texture(make(rng, _texels(s1 - s0), _texels(z_top - z_bottom)))
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
        _door_mesh(mb, d, pal, door_h)
    for f in furniture:
        _furniture_mesh(mb, f, pal, rng)
    vertices, triangles, uvs, tex_idx, tri_room = mb.mesh()
    floor = unary_union([r.polygon() for r in rooms] + [d.polygon() for d in doors])
    polys = [floor] if floor.geom_type == "Polygon" else list(floor.geoms)
    floor_polygons = [np.asarray(orient(p, 1.0).exterior.coords)[:-1] for p in polys]
    return Scene(
        vertices,
        triangles,
        uvs,
        tex_idx,
        mb.textures,
        tri_room,
        rooms,
        doors,
        floor_polygons,
        lights,
        0.35 * li,
        furniture,
        spec,
    )


def _door_mesh(mb: _MeshBuilder, d: Door, pal: _Palette, door_h: float) -> None:
    """Reveal of the opening: two jambs, the lintel's underside and the floor strip."""
    eps = SEAM_OVERLAP
    room = d.rooms[0]
    wall_tex, floor_tex = pal.walls[0], pal.floors[0]
    lo, hi = d.wall
    e_axis = np.zeros(3)
    e_axis[d.axis] = 1.0  # across the wall
    e_span = np.zeros(3)
    e_span[1 - d.axis] = 1.0  # along the wall
    for s in d.span:
        origin = e_span * s + np.array([0, 0, door_h])
        mb.rect(origin, e_axis, (0, 0, -1), (lo, hi), (0.0, door_h), wall_tex, room, grow=eps)
    top = np.array([0, 0, door_h])
    mb.rect(top, e_axis, e_span, (lo, hi), d.span, wall_tex, room, grow=eps)
    mb.rect((0, 0, 0), e_axis, e_span, (lo, hi), d.span, floor_tex, room, grow=eps)
