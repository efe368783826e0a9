"""Planar scene layout in the rectified world frame (z up, floor z = 0): walls
as vertical planar patches, the ceiling as the largest horizontal patch above
the cameras, and the floor outline in top view.

Floor outline: every cloud point between the floor and just below the ceiling
(floor, furniture and walls alike) marks its top-view cell as inside the scene;
a morphological closing bridges unobserved gaps, enclosed holes (e.g. under
furniture) are filled, an opening removes thin spurs, and each remaining region
becomes a polygon (OpenCV contours through the boundary cells' centres, which
is where the wall points lie on average)."""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from shapely.geometry import Polygon
from shapely.geometry.polygon import orient

from .scene import PlanarPatch

KIND_OTHER, KIND_FLOOR, KIND_WALL, KIND_CEILING = 0, 1, 2, 3   # yowo_msgs/Plane kinds


@dataclass(frozen=True)
class LayoutParams:
    cell_m: float = 0.05
    floor_band_m: float = 0.15           # points from this far below the floor count
    below_ceiling_m: float = 0.25        # ceiling points (and lamps) do not
    default_top_m: float = 2.3           # upper bound when no ceiling was found
    close_m: float = 0.35
    open_m: float = 0.2
    min_area_m2: float = 1.0
    simplify_m: float = 0.05
    wall_max_tilt_deg: float = 10.0
    wall_min_height_m: float = 0.6
    horizontal_max_tilt_deg: float = 10.0
    ceiling_above_camera_m: float = 0.3


@dataclass
class LayoutPlane:
    kind: int
    coefficients: np.ndarray             # (a, b, c, d), unit normal, n . p + d = 0
    boundary: np.ndarray                 # (N, 3)
    num_points: int


@dataclass
class Layout:
    floor_polygons: list[np.ndarray]     # (N, 2) counter-clockwise, metres
    floor_height: float
    ceiling_height: float                # NaN when no ceiling was seen
    planes: list[LayoutPlane] = field(default_factory=list)


def _disk(diameter_m: float, cell_m: float) -> np.ndarray:
    n = max(1, int(round(diameter_m / cell_m))) | 1
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (n, n))


def floor_polygons(points: np.ndarray, top_m: float, params: LayoutParams = LayoutParams()) -> list[np.ndarray]:
    """Top-view outline(s) of the space the points occupy between the floor
    (z = 0) and top_m."""
    sel = (points[:, 2] > -params.floor_band_m) & (points[:, 2] < top_m)
    xy = points[sel, :2]
    if len(xy) < 10:
        return []
    cell = params.cell_m
    pad = int(np.ceil(params.close_m / cell)) + 2
    origin = xy.min(axis=0) - pad * cell
    ij = np.floor((xy - origin) / cell).astype(int)
    shape = ij.max(axis=0) + pad + 1
    occ = np.zeros((shape[1], shape[0]), np.uint8)
    occ[ij[:, 1], ij[:, 0]] = 255
    occ = cv2.morphologyEx(occ, cv2.MORPH_CLOSE, _disk(params.close_m, cell))
    # Fill enclosed holes: everything the outside cannot reach.
    outside = occ.copy()
    mask = np.zeros((occ.shape[0] + 2, occ.shape[1] + 2), np.uint8)
    cv2.floodFill(outside, mask, (0, 0), 128)
    occ[outside == 0] = 255
    occ = cv2.morphologyEx(occ, cv2.MORPH_OPEN, _disk(params.open_m, cell))
    contours, _ = cv2.findContours(occ, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = []
    for c in contours:
        c = cv2.approxPolyDP(c, params.simplify_m / cell, True).reshape(-1, 2)
        if len(c) < 3:
            continue
        poly = Polygon(origin + (c + 0.5) * cell).buffer(0)
        if poly.geom_type != "Polygon" or poly.area < params.min_area_m2:
            continue
        out.append(np.asarray(orient(poly, 1.0).exterior.coords)[:-1])
    return out


def build_layout(points: np.ndarray, patches: list[PlanarPatch], cameras: np.ndarray,
                 params: LayoutParams = LayoutParams()) -> Layout:
    """Layout from the rectified cloud, its planar patches and the camera centres."""
    sin_wall = np.sin(np.radians(params.wall_max_tilt_deg))
    cos_h = np.cos(np.radians(params.horizontal_max_tilt_deg))
    top_camera = float(np.max(cameras[:, 2])) if len(cameras) else 0.0
    planes, ceilings = [], []
    for p in patches:
        n = p.normal
        if abs(n[2]) <= sin_wall and np.ptp(p.corners[:, 2]) >= params.wall_min_height_m:
            n = np.array([n[0], n[1], 0.0]) / np.hypot(n[0], n[1])   # walls are vertical by definition
            planes.append(LayoutPlane(KIND_WALL, np.append(n, -n @ p.center), p.corners, p.num_points))
        elif n[2] <= -cos_h and p.center[2] > top_camera + params.ceiling_above_camera_m:
            ceilings.append(p)
    ceiling = max(ceilings, key=lambda p: p.num_points, default=None)
    ceiling_height = float(ceiling.center[2]) if ceiling is not None else float("nan")
    if ceiling is not None:
        planes.append(LayoutPlane(KIND_CEILING, np.array([0.0, 0.0, -1.0, ceiling_height]), ceiling.corners,
                                  ceiling.num_points))
    top = ceiling_height - params.below_ceiling_m if ceiling is not None else params.default_top_m
    polygons = floor_polygons(points, top, params)
    for poly in polygons:
        boundary = np.column_stack([poly, np.zeros(len(poly))])
        floor_support = int(np.sum(np.abs(points[:, 2]) < 0.05))
        planes.append(LayoutPlane(KIND_FLOOR, np.array([0.0, 0.0, 1.0, 0.0]), boundary, floor_support))
    return Layout(polygons, 0.0, ceiling_height, planes)
