"""Ray-cast renderer for the synthetic captures: RGB, z-depth and the agent mask.

Rays: pixel (u, v) looks along the undistorted bearing of the pixel centre at
(u, v) (OpenCV/ROS convention), so ``CameraModel.project`` of a rendered point
lands on the pixel that shows it, with lens distortion included. Open3D's
``create_rays_pinhole`` is not used because its pixel centres are half a pixel off.

Colour: texture lookup at the barycentric UV of the hit, from a mip-mapped
texture atlas (mip level by the pixel's footprint, bilinear within the level via
``cv2.remap``), times Lambertian shading by the lights of the hit's room with a
smooth distance falloff, plus an ambient term (no shadows). The static scene's
lighting never changes, so it is baked once into a two-sided light map (one
texel per ``LIGHTMAP_TEXEL`` metres on every triangle) and looked up like a
texture; only the agent is shaded per pixel.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import cv2
import numpy as np
import open3d as o3d

from yowo_common.camera import CameraModel

from .body import AgentMesh
from .scene import LIGHT_RANGE, Scene

# Falloff I * R0^2 / (R0^2 + d^2) * window(d): roughly inverse-square beyond R0 but
# finite at the lamp, and windowed to zero at LIGHT_RANGE so a corridor's far lamps
# do not add up to a flat glow.
_R0_SQ = 2.5**2
_MIP_LEVELS = 7
_ATLAS_WIDTH = 4096
LIGHTMAP_TEXEL = 0.1  # metres
_LIGHTMAP_MAX = 256  # texels along one triangle edge
# Per-triangle table columns (float32): UV of corner 0, UV edges to corners 1 and 2,
# texture index, texel density, light-map origin (x, y) and size (n1, n2),
# and the unit normal (v1 - v0) x (v2 - v0).
_C_TEX, _C_DENSITY, _C_LIGHTMAP, _C_NORMAL = 6, 7, 8, 12


class RenderedFrame(NamedTuple):
    rgb: np.ndarray  # H x W x 3 uint8
    depth: np.ndarray  # H x W float32, metres along the optical axis (z), NaN where nothing is hit
    agent_mask: np.ndarray  # H x W bool, pixels showing the agent


class _RayGrid(NamedTuple):
    height: int
    width: int
    dirs_cam_t: np.ndarray  # (3, N) float32 bearings scaled to z = 1 (so t_hit is the z-depth), one row per axis
    ray_len: np.ndarray  # (N,) float32 length of each bearing
    focal: float  # mean focal length (pixels), for the pixel footprint
    rays: np.ndarray  # (N, 6) float32 buffer reused for every frame


def _light_falloff(d2: np.ndarray) -> np.ndarray:
    window = np.clip(1.0 - (d2 / LIGHT_RANGE**2) ** 2, 0.0, 1.0)
    return _R0_SQ / (_R0_SQ + d2) * window


def _direct_light(points: np.ndarray, normals: np.ndarray, position: np.ndarray, intensity: float):
    """Lambertian irradiance from one point light on the +normal and -normal side."""
    delta = position - points
    d2 = np.einsum("ij,ij->i", delta, delta)
    cos = np.einsum("ij,ij->i", normals, delta) / np.sqrt(np.maximum(d2, 1e-12))
    w = intensity * _light_falloff(d2)
    return np.maximum(cos, 0.0) * w, np.maximum(-cos, 0.0) * w


class _Atlas(NamedTuple):
    image: np.ndarray  # one RGB canvas holding every texture at every mip level
    levels: np.ndarray  # (4, L * n_textures) float32: x offset, y offset, width, height


def _shelf_pack(sizes: np.ndarray) -> tuple[np.ndarray, int]:
    """Top-left corners for (w, h) rectangles on shelves _ATLAS_WIDTH wide; returns
    the corners and the canvas height."""
    if len(sizes) and sizes[:, 0].max() > _ATLAS_WIDTH:
        raise ValueError(f"a texture is {sizes[:, 0].max()} texels wide; the atlas holds at most {_ATLAS_WIDTH}")
    corners = np.zeros((len(sizes), 2), np.int64)
    x = y = shelf_h = 0
    for i in np.argsort(-sizes[:, 1], kind="stable"):
        w, h = sizes[i]
        if x + w > _ATLAS_WIDTH:
            x, y, shelf_h = 0, y + shelf_h, 0
        corners[i] = (x, y)
        x += w
        shelf_h = max(shelf_h, h)
    height = max(1, y + shelf_h)
    if height >= 32767:
        raise ValueError(f"atlas of {height} rows exceeds cv2.remap's limit; use fewer or smaller textures")
    return corners, height


def _build_atlas(textures: list[np.ndarray]) -> _Atlas:
    """Every mip level of every texture in one canvas, each with a 1-texel
    wrap-around border so bilinear filtering tiles seamlessly."""
    n = len(textures)
    images = []  # padded images, in (texture, level) order
    for tex in textures:
        img = np.ascontiguousarray(tex[..., :3], dtype=np.uint8)
        for _ in range(_MIP_LEVELS):
            images.append(np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="wrap"))
            h, w = img.shape[:2]
            if min(h, w) >= 2:  # tiny textures keep their last size for the remaining levels
                img = cv2.resize(img, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    corners, height = _shelf_pack(np.array([img.shape[1::-1] for img in images]).reshape(-1, 2))
    canvas = np.zeros((height, _ATLAS_WIDTH, 3), np.uint8)
    levels = np.zeros((_MIP_LEVELS * n, 4), np.float32)
    for k, ((x, y), img) in enumerate(zip(corners, images)):
        ti, level = divmod(k, _MIP_LEVELS)
        canvas[y : y + img.shape[0], x : x + img.shape[1]] = img
        # Texel (0, 0) of the unpadded texture sits at (x + 1, y + 1); cv2.remap
        # samples texel centres at integer coordinates, hence the -0.5.
        levels[level * n + ti] = (x + 0.5, y + 0.5, img.shape[1] - 2, img.shape[0] - 2)
    return _Atlas(canvas, np.ascontiguousarray(levels.T))


def _bake_lightmap(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Ambient + direct light of every triangle, sampled on a grid over the
    parallelogram v0 + b1 e1 + b2 e2 (b in [0, 1], plus a border texel), for both
    sides of the surface. Returns the (h, W, 2) float32 map and, per triangle,
    (x, y, n1, n2) such that texel coordinates are (x + b1 n1, y + b2 n2)."""
    v = scene.vertices[scene.triangles].astype(np.float64)
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    n1 = np.clip(np.ceil(np.linalg.norm(e1, axis=1) / LIGHTMAP_TEXEL), 1, _LIGHTMAP_MAX).astype(np.int64)
    n2 = np.clip(np.ceil(np.linalg.norm(e2, axis=1) / LIGHTMAP_TEXEL), 1, _LIGHTMAP_MAX).astype(np.int64)
    w, h = n1 + 2, n2 + 2
    corners, height = _shelf_pack(np.column_stack([w, h]))
    lightmap = np.full((height, _ATLAS_WIDTH, 2), scene.ambient, np.float32)
    # One row per texel: which triangle, and where in its rectangle.
    tri_of = np.repeat(np.arange(len(v)), w * h)
    k = np.arange(len(tri_of)) - np.repeat(np.cumsum(w * h) - w * h, w * h)
    row, col = np.divmod(k, w[tri_of])
    b1 = (col - 0.5) / n1[tri_of]
    b2 = (row - 0.5) / n2[tri_of]
    points = v[tri_of, 0] + b1[:, None] * e1[tri_of] + b2[:, None] * e2[tri_of]
    normals = _triangle_normals(scene)[tri_of]
    texel_y, texel_x = corners[tri_of, 1] + row, corners[tri_of, 0] + col
    texel_room = scene.triangle_room[tri_of]
    for room in np.unique(texel_room):
        sel = np.flatnonzero(texel_room == room)
        front = np.zeros(len(sel))
        back = np.zeros(len(sel))
        for light in scene.lights:
            if room >= 0 and light.room == room:  # walls block other rooms' lights
                f, b = _direct_light(points[sel], normals[sel], light.position, light.intensity)
                front += f
                back += b
        lightmap[texel_y[sel], texel_x[sel]] += np.column_stack([front, back]).astype(np.float32)
    return lightmap, np.column_stack([corners + 0.5, n1, n2]).astype(np.float32)


def _triangle_normals(scene: Scene) -> np.ndarray:
    v = scene.vertices[scene.triangles].astype(np.float64)
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def _triangle_table(scene: Scene, lightmap_rects: np.ndarray) -> np.ndarray:
    """Per-triangle rendering data, plus one all-zero row for 'no hit'."""
    T = len(scene.triangles)
    table = np.zeros((T + 1, _C_NORMAL + 3), np.float32)
    if T == 0:
        return table
    uv = scene.triangle_uvs.astype(np.float64)
    table[:T, 0:2] = uv[:, 0]
    table[:T, 2:4] = uv[:, 1] - uv[:, 0]
    table[:T, 4:6] = uv[:, 2] - uv[:, 0]
    table[:T, _C_TEX] = scene.triangle_texture
    # Texels per metre at mip level 0: sqrt(texel area / surface area).
    sizes = np.array([t.shape[1::-1] for t in scene.textures], dtype=np.float64)[scene.triangle_texture]  # (w, h)
    e_uv1 = (uv[:, 1] - uv[:, 0]) * sizes
    e_uv2 = (uv[:, 2] - uv[:, 0]) * sizes
    area_uv = 0.5 * np.abs(e_uv1[:, 0] * e_uv2[:, 1] - e_uv1[:, 1] * e_uv2[:, 0])
    v = scene.vertices[scene.triangles].astype(np.float64)
    area_3d = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    table[:T, _C_DENSITY] = np.sqrt(area_uv / np.maximum(area_3d, 1e-12))
    table[:T, _C_LIGHTMAP : _C_LIGHTMAP + 4] = lightmap_rects
    table[:T, _C_NORMAL : _C_NORMAL + 3] = _triangle_normals(scene)
    return table


class Renderer:
    """Renders one static scene (prepared once) from any camera, optionally with the agent."""

    def __init__(self, scene: Scene):
        if len(scene.triangles) and not 0 <= scene.triangle_texture.min() <= scene.triangle_texture.max() < len(
            scene.textures
        ):
            raise ValueError(f"triangle_texture indexes textures outside the {len(scene.textures)} given")
        self.scene = scene
        self._raycaster = o3d.t.geometry.RaycastingScene()
        if len(scene.triangles):
            self._raycaster.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(scene.vertices, dtype=np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(scene.triangles, dtype=np.uint32)),
            )
        self._no_hit = len(scene.triangles)  # index of the table's all-zero row
        self._lightmap, lightmap_rects = _bake_lightmap(scene)
        # Column-major so each per-pixel quantity gathered from it is contiguous.
        self._table = np.ascontiguousarray(_triangle_table(scene, lightmap_rects).T)
        self._n_textures = len(scene.textures)
        self._atlas = _build_atlas(scene.textures)
        self._grids: dict[tuple, _RayGrid] = {}

    def _grid(self, camera: CameraModel) -> _RayGrid:
        key = (camera.width, camera.height, camera.K.tobytes(), camera.D.tobytes(), camera.distortion_model)
        grid = self._grids.get(key)
        if grid is None:
            u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
            bearings = camera.bearings(np.column_stack([u.ravel(), v.ravel()]))
            if (bearings[:, 2] < 1e-6).any():
                raise ValueError("camera has pixels looking 90 degrees or more off-axis; not supported")
            dirs = (bearings / bearings[:, 2:3]).astype(np.float32)
            grid = _RayGrid(
                camera.height,
                camera.width,
                np.ascontiguousarray(dirs.T),
                np.linalg.norm(dirs, axis=1).astype(np.float32),
                float(0.5 * (camera.K[0, 0] + camera.K[1, 1])),
                np.empty((len(dirs), 6), np.float32),
            )
            self._grids[key] = grid
        return grid

    def render(
        self, camera: CameraModel, T_world_cam: np.ndarray, agent: AgentMesh | Sequence[AgentMesh] | None = None
    ) -> RenderedFrame:
        """Colour, z-depth and agent mask of ``camera`` at pose ``T_world_cam`` (4x4).
        ``agent``: one person's mesh or several (the agent and bystanders), each in
        front of or behind the scene and the others pixel by pixel; the mask shows them all."""
        grid = self._grid(camera)
        shape = (grid.height, grid.width)
        T_world_cam = np.asarray(T_world_cam, dtype=np.float64)
        # Element-wise products, not matmul: OpenBLAS threads keep spinning after a
        # BLAS call and slow Open3D's ray casting on the same cores.
        R = T_world_cam[:3, :3].astype(np.float32)
        d = grid.dirs_cam_t
        rays = grid.rays
        rays[:, 0:3] = T_world_cam[:3, 3]
        for i in range(3):
            rays[:, 3 + i] = R[i, 0] * d[0] + R[i, 1] * d[1] + R[i, 2] * d[2]
        hits = self._raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        depth = hits["t_hit"].numpy().copy()  # rays have unit z, so t_hit is the z-depth
        tri = np.minimum(hits["primitive_ids"].numpy(), self._no_hit).astype(np.intp)
        b1, b2 = np.ascontiguousarray(hits["primitive_uvs"].numpy().T)
        cols = self._table.take(tri, axis=1)
        miss = tri == self._no_hit

        # n . d in the camera frame, where the ray directions are cached per axis.
        n = cols[_C_NORMAL : _C_NORMAL + 3]
        n_dot_d = sum((R[0, j] * n[0] + R[1, j] * n[1] + R[2, j] * n[2]) * d[j] for j in range(3))
        albedo = self._albedo(cols, b1, b2, n_dot_d, depth, grid, miss)
        # Light map: texel (x + b1 n1, y + b2 n2); channel 0 lights the +normal side.
        lm_x = cols[_C_LIGHTMAP] + b1 * cols[_C_LIGHTMAP + 2]
        lm_x[miss] = -10.0
        lm_y = cols[_C_LIGHTMAP + 1] + b2 * cols[_C_LIGHTMAP + 3]
        both_sides = cv2.remap(
            self._lightmap,
            lm_x.reshape(shape),
            lm_y.reshape(shape),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        ).reshape(-1, 2)
        shade = np.where(n_dot_d < 0, both_sides[:, 0], both_sides[:, 1])
        rgb = albedo * shade[:, None]
        agent_mask = np.zeros(len(depth), bool)
        # One person at a time: each keeps the nearer of itself and what is drawn so far.
        for person in [agent] if isinstance(agent, AgentMesh) else agent or ():
            self._compose_agent(person, T_world_cam, grid, depth, rgb, agent_mask)
        depth[miss & ~agent_mask] = np.nan
        rgb = np.clip(rgb + 0.5, 0.0, 255.0).astype(np.uint8)  # +0.5: round, not truncate
        return RenderedFrame(rgb.reshape(*shape, 3), depth.reshape(shape), agent_mask.reshape(shape))

    def _albedo(self, cols, b1, b2, n_dot_d, depth, grid: _RayGrid, miss) -> np.ndarray:
        """(N, 3) float32 texture colour at the hits, black where nothing is hit."""
        u = cols[0] + b1 * cols[2] + b2 * cols[4]
        v = cols[1] + b1 * cols[3] + b2 * cols[5]
        # Mip level from the pixel's footprint in texels; the sqrt of the slant is
        # the geometric mean of the footprint's two axes (between blur and aliasing).
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            cos = np.maximum(np.abs(n_dot_d) / grid.ray_len, 0.05)
            footprint = depth * grid.ray_len * (cols[_C_DENSITY] / grid.focal) / np.sqrt(cos)
            # fmin also maps the NaN of misses (inf * 0) to a valid level.
            level = np.fmin(np.floor(np.log2(np.maximum(footprint, 1.0)) + 0.5), _MIP_LEVELS - 1).astype(np.intp)
        info = self._atlas.levels.take(level * self._n_textures + cols[_C_TEX].astype(np.intp), axis=1)
        map_x = info[0] + (u - np.floor(u)) * info[2]
        map_x[miss] = -10.0  # outside the atlas: black
        map_y = info[1] + (v - np.floor(v)) * info[3]
        shape = (grid.height, grid.width)
        out = cv2.remap(
            self._atlas.image,
            map_x.reshape(shape),
            map_y.reshape(shape),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
        return out.reshape(-1, 3).astype(np.float32)

    def _compose_agent(self, agent: AgentMesh, T_world_cam, grid: _RayGrid, depth, rgb, agent_mask) -> None:
        """Cast the rays that can see the agent against its mesh and keep the
        nearer of agent and scene (in place)."""
        R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
        v_cam = np.einsum("ij,ik->jk", R, (np.asarray(agent.vertices, dtype=np.float64) - t).T).T  # no BLAS
        if (v_cam[:, 2] <= 1e-3).all():  # behind the camera (a bystander behind the ego camera)
            return
        if (v_cam[:, 2] > 1e-3).all():
            # The agent's image lies in the bounding box of its vertices' normalised
            # coordinates (a central projection keeps convex hulls), and the ray
            # grid holds each pixel's normalised coordinates.
            xy = v_cam[:, :2] / v_cam[:, 2:3]
            (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
            d = grid.dirs_cam_t
            candidates = np.flatnonzero((d[0] >= x0) & (d[0] <= x1) & (d[1] >= y0) & (d[1] <= y1))
        else:
            candidates = np.arange(grid.height * grid.width)
        if len(candidates) == 0:
            return
        caster = o3d.t.geometry.RaycastingScene()
        caster.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(agent.vertices, dtype=np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(agent.triangles, dtype=np.uint32)),
        )
        rays = np.ascontiguousarray(grid.rays[candidates])
        hits = caster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        t_agent = hits["t_hit"].numpy()
        closer = t_agent < depth[candidates]  # misses are +inf on both sides
        pix = candidates[closer]
        if len(pix) == 0:
            return
        tri = hits["primitive_ids"].numpy()[closer].astype(np.intp)
        normals = hits["primitive_normals"].numpy()[closer].astype(np.float64)
        dirs = rays[closer, 3:6]
        # Two-sided surfaces: light the side the camera sees.
        normals *= np.where(np.einsum("ij,ij->i", normals, dirs) > 0, -1.0, 1.0)[:, None]
        points = rays[closer, 0:3] + t_agent[closer, None] * dirs
        centre = points.mean(axis=0)
        reach = LIGHT_RANGE + np.linalg.norm(points - centre, axis=1).max()  # lights beyond add nothing
        room = self.scene.room_at(centre[:2])
        shade = np.full(len(pix), self.scene.ambient)
        for light in self.scene.lights:
            if light.room == room and np.linalg.norm(light.position - centre) < reach:
                shade += _direct_light(points, normals, light.position, light.intensity)[0]
        depth[pix] = t_agent[closer]
        rgb[pix] = agent.colors[tri].astype(np.float32) * shade[:, None].astype(np.float32)
        agent_mask[pix] = True
