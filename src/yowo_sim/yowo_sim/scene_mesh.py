"""Triangle meshes of the simulated scenes: textured rectangles and boxes, the
texture palette of each texture mode, furniture, door reveals and wall items.

Triangles carry their texture index, their UVs (texture units, see ``scene``)
and the room that lights them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import textures

if TYPE_CHECKING:
    from .scene import Door, Furniture

TEXELS_PER_METRE = 256.0
# Surfaces overlap by this much at junctions so that no ray slips through a crack
# between two triangles that only touch.
SEAM_OVERLAP = 1e-3
# Large surfaces are cut into patches no longer than this, so per-triangle data
# (the renderer's light map) keeps a uniform resolution.
MAX_PATCH = 4.0


class MeshBuilder:
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


@dataclass(kw_only=True)
class Palette:
    """Texture indices a scene draws from."""

    walls: list[int]
    floors: list[int]
    ceilings: list[int]
    wood: list[int]
    boxes: list[int]
    books: list[int]
    poster: int | None  # the one shared poster of the "symmetric" mode


def make_palette(mode: str, rng, mb: MeshBuilder) -> Palette:
    S = 512
    add = mb.add_texture
    if mode == "rich":
        # Walls tile every 4 m x 3 m and floors every 4 m; unique posters and
        # decals on top keep each wall distinct.
        wh, ww, fs = 768, 1024, 1024
        walls = [
            add(textures.plaster(rng, wh, ww)),
            add(textures.brick(rng, wh, ww)),
            add(textures.wallpaper(rng, wh, ww)),
            add(textures.planks(rng, wh, ww, 32, vertical=True)),
            add(textures.concrete(rng, wh, ww)),
            add(textures.tiles(rng, wh, ww, 64, decorated=True)),
            add(textures.wallpaper(rng, wh, ww)),
            add(textures.plaster(rng, wh, ww)),
        ]
        floors = [
            add(textures.planks(rng, fs, fs, 64, vertical=False)),
            add(textures.tiles(rng, fs, fs, 128, decorated=False)),
            add(textures.carpet(rng, fs, fs)),
            add(textures.concrete(rng, fs, fs)),
        ]
        return Palette(
            walls=walls,
            floors=floors,
            ceilings=[add(textures.ceiling(rng, S)), add(textures.concrete(rng, S, S))],
            wood=[
                add(textures.planks(rng, 256, 256, 64, vertical=False)),
                add(textures.planks(rng, 256, 256, 64, vertical=True)),
            ],
            boxes=[add(textures.cardboard(rng, 256)), add(textures.cardboard(rng, 256))],
            books=[add(textures.books(rng, S))],
            poster=None,
        )
    if mode == "poor":

        def flat(colour, amp=0.006):
            return add(textures.flat(rng, 256, np.asarray(colour, np.float32), amp))

        return Palette(
            walls=[flat((200, 198, 192)), flat((192, 196, 200))],
            floors=[flat((150, 145, 138))],
            ceilings=[flat((225, 225, 225))],
            wood=[flat((150, 110, 70))],
            boxes=[flat((170, 135, 90))],
            books=[flat((120, 90, 60))],
            poster=None,
        )
    # symmetric: one pattern everywhere, posters identical and centred on each wall.
    wall = add(textures.motif_tiled(rng, S, 4))
    wood = add(textures.planks(rng, 256, 256, 64, vertical=False))
    return Palette(
        walls=[wall],
        floors=[add(textures.tiles(rng, S, S, 128, decorated=False))],
        ceilings=[add(textures.ceiling(rng, S))],
        wood=[wood],
        boxes=[add(textures.cardboard(rng, 256))],
        books=[add(textures.books(rng, S))],
        poster=add(textures.poster(rng, 256, 192)),
    )


def furniture_mesh(mb: MeshBuilder, f: Furniture, pal: Palette, rng) -> None:
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


def texels(metres: float) -> int:
    """Texture size for a surface of this length (a multiple of 16 texels)."""
    return max(16, int(round(metres * TEXELS_PER_METRE / 16)) * 16)


def wall_pieces(length: float, openings: list[tuple[float, float]]) -> list[tuple[float, float]]:
    pieces, s = [], 0.0
    for o0, o1 in openings:
        if o0 > s:
            pieces.append((s, o0))
        s = max(s, o1)
    if s < length:
        pieces.append((s, length))
    return pieces


def wall_items(rng, pieces, ceiling: float, symmetric: bool) -> list[tuple[float, float, float, float, str]]:
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


def door_mesh(mb: MeshBuilder, d: Door, pal: Palette, door_h: float) -> None:
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
