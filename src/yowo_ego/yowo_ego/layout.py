"""Planar scene layout in the rectified world frame (z up, floor z = 0): walls
as vertical planes, the ceiling as the largest downward-facing planar patch
above the cameras, and the floor outline in top view.

Floor outline (top-view grid aligned with the dominant wall direction): every
cloud point between the floor and just below the ceiling (floor, furniture and
walls alike) marks its cell as inside the scene; so does an unobserved cell
with walls or furniture seen beyond it in three of the four directions (the
one left may be a wall the camera never looked at). A morphological
closing bridges gaps, enclosed holes (e.g. under furniture) are filled, an
opening removes thin spurs, and each remaining region becomes a polygon
(OpenCV contours through the boundary cells' centres, which is where the wall
points lie on average). Rooms are assumed rectangular (Manhattan layout): the
walls cut the region into rooms and a room observed over a good part of its
bounding box (``room_fill_min``) is completed to that box."""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np
import open3d as o3d
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from .scene import PlanarPatch

KIND_OTHER, KIND_FLOOR, KIND_WALL, KIND_CEILING = 0, 1, 2, 3  # yowo_msgs/Plane kinds


@dataclass(frozen=True)
class LayoutParams:
    cell_m: float = 0.05  # cell size of the floor outline's top-view grid
    floor_band_m: float = 0.15  # points from this far below the floor count
    below_ceiling_m: float = 0.25  # points this close below the ceiling (and lamps) do not count
    default_top_m: float = 2.3  # upper bound when no ceiling was found
    wall_from_m: float = 0.3  # points above this height block the inside test
    wall_min_points: int = 2  # points above wall_from_m a cell needs to block the inside test [count]
    enclosing_sides: int = 3  # blocked directions (of four) an unobserved cell needs to count as inside [count]
    door_gap_m: float = 1.2  # wall pieces this far apart count as one wall (a door)
    room_fill_min: float = 0.3  # observed share of a room's box for rectangle completion [share]
    close_m: float = 0.35  # radius of the morphological closing that bridges gaps in the outline
    open_m: float = 0.2  # radius of the morphological opening that removes thin spurs
    min_area_m2: float = 1.0  # outline regions and rooms smaller than this are dropped
    simplify_m: float = 0.05  # tolerance of the outline polygons' simplification
    wall_max_tilt_deg: float = 10.0  # points whose normal is this close to horizontal may lie on walls
    wall_min_height_m: float = 0.6  # a wall piece spans this height at least
    wall_ransac_m: float = 0.04  # RANSAC inlier distance of the wall planes
    # Points a wall plane needs at least, a wall piece half as many [count]. At the cloud's 6 cm
    # sampling, about 0.5 m².
    wall_min_points_plane: int = 150
    wall_gap_m: float = 0.5  # gaps along a wall plane longer than this split it into pieces
    max_walls: int = 60  # wall planes extracted at most [count]
    horizontal_max_tilt_deg: float = 10.0  # a ceiling patch's normal is this close to straight down
    ceiling_above_camera_m: float = 0.3  # a ceiling patch lies this far above the highest camera at least


@dataclass
class LayoutPlane:
    kind: int
    coefficients: np.ndarray  # (a, b, c, d), unit normal, n . p + d = 0
    boundary: np.ndarray  # (N, 3)
    num_points: int


@dataclass
class Layout:
    floor_polygons: list[np.ndarray]  # (N, 2) counter-clockwise, metres
    floor_height: float
    ceiling_height: float  # NaN when no ceiling was seen
    planes: list[LayoutPlane] = field(default_factory=list)


def _disk(diameter_m: float, cell_m: float) -> np.ndarray:
    n = max(1, int(round(diameter_m / cell_m))) | 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (n, n))


def wall_orientation(walls: list[LayoutPlane]) -> float:
    """Dominant wall direction (rad, modulo 90 deg): the circular mean of 4x the
    wall normals' angles, weighted by their support (rooms are mostly rectilinear)."""
    if not walls:
        return 0.0
    a = np.array([np.arctan2(w.coefficients[1], w.coefficients[0]) for w in walls])
    w = np.array([max(w.num_points, 1) for w in walls], dtype=float)
    return float(np.arctan2((w * np.sin(4 * a)).sum(), (w * np.cos(4 * a)).sum()) / 4)


def floor_polygons(
    points: np.ndarray,
    top_m: float,
    params: LayoutParams = LayoutParams(),
    orientation_rad: float = 0.0,
    walls: list[LayoutPlane] = (),
) -> list[np.ndarray]:
    """Top-view outline(s) of the space the points occupy between the floor
    (z = 0) and top_m, on a grid aligned with ``orientation_rad``. Unobserved
    floor (a head-worn camera rarely sees every corner) counts as inside when
    walls or furniture were seen beyond it in ``enclosing_sides`` of the four
    wall directions, and rooms are completed to rectangles (below)."""
    sel = (points[:, 2] > -params.floor_band_m) & (points[:, 2] < top_m)
    c, s = np.cos(orientation_rad), np.sin(orientation_rad)
    R = np.array([[c, s], [-s, c]])  # world -> grid axes
    xy = points[sel, :2] @ R.T
    if len(xy) < 10:
        return []
    cell = params.cell_m
    pad = int(np.ceil(params.close_m / cell)) + 2
    origin = xy.min(axis=0) - pad * cell
    ij = np.floor((xy - origin) / cell).astype(int)
    shape = ij.max(axis=0) + pad + 1
    occ = np.zeros((shape[1], shape[0]), np.uint8)
    occ[ij[:, 1], ij[:, 0]] = 255
    tall = points[sel, 2] > params.wall_from_m
    blocking = np.zeros(occ.shape, np.int32)
    np.add.at(blocking, (ij[tall, 1], ij[tall, 0]), 1)
    blocking = blocking >= params.wall_min_points
    hits = np.zeros(occ.shape, np.uint8)
    for axis in (0, 1):
        hits += np.maximum.accumulate(blocking, axis=axis)
        hits += np.flip(np.maximum.accumulate(np.flip(blocking, axis), axis=axis), axis)
    occ[hits >= params.enclosing_sides] = 255
    occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, _disk(params.close_m, cell))
    # Fill enclosed holes: everything the outside cannot reach.
    outside = occ.copy()
    mask = np.zeros((occ.shape[0] + 2, occ.shape[1] + 2), np.uint8)
    cv2.floodFill(outside, mask, (0, 0), 128)
    occ[outside == 0] = 255
    occ = cv2.morphologyEx(occ, cv2.MORPH_OPEN, _disk(params.open_m, cell))
    if walls:
        occ = _complete_rooms(occ, [(w.boundary[:2, :2] @ R.T - origin) / cell for w in walls], params)
    contours, _ = cv2.findContours(occ, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for contour in contours:
        contour = cv2.approxPolyDP(contour, params.simplify_m / cell, True).reshape(-1, 2)
        if len(contour) < 3:
            continue
        poly = Polygon((origin + (contour + 0.5) * cell) @ R).buffer(0)
        if poly.geom_type != "Polygon" or poly.area < params.min_area_m2:
            continue
        out.append(np.asarray(orient(poly, 1.0).exterior.coords)[:-1])
    return out


def _complete_rooms(occ: np.ndarray, wall_segments: list[np.ndarray], params: LayoutParams) -> np.ndarray:
    """Rectangular-room completion (a Manhattan-layout assumption): the walls,
    lengthened across door-sized gaps, cut the inside region into rooms; a room
    that fills at least ``room_fill_min`` of its axis-aligned bounding box is
    taken to be that whole box (the parts of it the camera never saw)."""
    barrier = np.zeros(occ.shape, np.uint8)
    reach = params.door_gap_m / 2 / params.cell_m
    for seg in wall_segments:
        a, b = seg
        d = (b - a) / max(np.linalg.norm(b - a), 1e-9)
        p0, p1 = np.round(a - reach * d).astype(int), np.round(b + reach * d).astype(int)
        cv2.line(barrier, tuple(int(v) for v in p0), tuple(int(v) for v in p1), 255, 2)
    rooms = np.where(barrier > 0, 0, occ)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(rooms, connectivity=4)
    out = occ.copy()
    min_cells = params.min_area_m2 / params.cell_m**2
    for k in range(1, n):
        x, y, w, h, area = stats[k]
        if area >= min_cells and area >= params.room_fill_min * w * h:
            out[y : y + h, x : x + w] = 255
    return out


@contextmanager
def _one_open3d_thread():
    """Open3D's RANSAC draws its samples in the threads' order even with a seed: one
    thread, whoever calls (the fusion rebuilds the layout on all cores: the same cloud
    gave walls a point apart from call to call). The caller's setting is restored."""
    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)


def extract_walls(points: np.ndarray, normals: np.ndarray, params: LayoutParams = LayoutParams()) -> list[LayoutPlane]:
    """Vertical planes by sequential RANSAC (Open3D ``segment_plane``) on the
    points whose normal is horizontal; each plane is split into wall pieces at
    gaps along it (collinear walls of neighbouring rooms share a plane).
    The planar patch detector misses or fragments walls behind furniture and
    posters too often to be the layout's walls."""
    sin_tilt = np.sin(np.radians(params.wall_max_tilt_deg))
    idx = np.flatnonzero(np.abs(normals[:, 2]) <= sin_tilt)
    walls = []
    o3d.utility.random.seed(0)  # the same recording gives the same layout
    while len(idx) >= params.wall_min_points_plane and len(walls) < params.max_walls:
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[idx]))
        with _one_open3d_thread():
            plane, inliers = cloud.segment_plane(params.wall_ransac_m, 3, 200)
        inliers = np.asarray(inliers, dtype=int)
        if len(inliers) < params.wall_min_points_plane:
            break
        n = np.asarray(plane[:3], dtype=float)
        members = idx[inliers]
        idx = np.delete(idx, inliers)
        if abs(n[2]) > sin_tilt:
            continue  # a slanted surface (furniture, a stair), not a wall
        n = np.array([n[0], n[1], 0.0]) / np.hypot(n[0], n[1])
        # Orient the normal like the points' own normals (towards the room side seen).
        if np.mean(normals[members] @ n) < 0:
            n = -n
        along = np.array([-n[1], n[0], 0.0])
        u = points[members] @ along
        order = np.argsort(u)
        cuts = np.flatnonzero(np.diff(u[order]) > params.wall_gap_m) + 1
        for piece in np.split(order, cuts):
            pts = points[members[piece]]
            z = pts[:, 2]
            if len(piece) < params.wall_min_points_plane / 2 or np.ptp(z) < params.wall_min_height_m:
                continue
            d = -float(np.median(pts @ n))
            u0, u1 = u[piece].min(), u[piece].max()
            base = -d * n
            corners = np.array(
                [
                    base + u0 * along + z.min() * np.array([0, 0, 1.0]),
                    base + u1 * along + z.min() * np.array([0, 0, 1.0]),
                    base + u1 * along + z.max() * np.array([0, 0, 1.0]),
                    base + u0 * along + z.max() * np.array([0, 0, 1.0]),
                ]
            )
            walls.append(LayoutPlane(KIND_WALL, np.append(n, d), corners, len(piece)))
    return walls


def build_layout(
    points: np.ndarray,
    sampled: np.ndarray,
    normals: np.ndarray,
    patches: list[PlanarPatch],
    cameras: np.ndarray,
    params: LayoutParams = LayoutParams(),
) -> Layout:
    """Layout from the rectified cloud (all points, and a downsampled copy with
    normals), its planar patches (for the ceiling) and the camera centres."""
    cos_h = np.cos(np.radians(params.horizontal_max_tilt_deg))
    top_camera = float(np.max(cameras[:, 2])) if len(cameras) else 0.0
    planes = extract_walls(sampled, normals, params)
    ceilings = [
        p for p in patches if p.normal[2] <= -cos_h and p.center[2] > top_camera + params.ceiling_above_camera_m
    ]
    ceiling = max(ceilings, key=lambda p: p.num_points, default=None)
    ceiling_height = float(ceiling.center[2]) if ceiling is not None else float("nan")
    if ceiling is not None:
        planes.append(
            LayoutPlane(KIND_CEILING, np.array([0.0, 0.0, -1.0, ceiling_height]), ceiling.corners, ceiling.num_points)
        )
    top = ceiling_height - params.below_ceiling_m if ceiling is not None else params.default_top_m
    walls = [q for q in planes if q.kind == KIND_WALL]
    polygons = floor_polygons(points, top, params, wall_orientation(walls), walls)
    floor_support = int(np.sum((np.abs(sampled[:, 2]) < 0.05) & (normals[:, 2] > cos_h)))
    for poly in polygons:
        planes.append(
            LayoutPlane(
                KIND_FLOOR, np.array([0.0, 0.0, 1.0, 0.0]), np.column_stack([poly, np.zeros(len(poly))]), floor_support
            )
        )
    return Layout(polygons, 0.0, ceiling_height, planes)
