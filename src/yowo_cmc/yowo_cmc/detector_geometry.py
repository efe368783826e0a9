"""The model-free detector's geometry (image_detector): the world-down direction d and
the height ratio rho (agent height / camera height above the floor) from many of the
agent's silhouettes and the background's straight edges, and the head top of one
outline. Geometry is done on viewing rays (unit bearings).

Vertical: the world-down direction d in the camera frame (the vertical vanishing point
is K d); "up" is never assumed to be the image's -y axis. A standing or walking person
is elongated along the vertical, so each silhouette's principal plane (through the
camera centre and its long axis) nearly contains d. Their robust common direction is
good to a few degrees where the agent was seen all over the image, but is loose along
the planes when the agent's axes are nearly parallel. The background's straight edges
(LSD) decide: among the intersections of edges that the agent's planes allow, d is the
one through which the most edges pass and whose horizon orders the other edges into
two orthogonal directions (a room's Manhattan layout; this rejects clusters of leaning
edges such as books on a shelf), refined by least squares to a fraction of a degree.
Without such edges the agent's estimate stands if the agent was seen in enough places.
The camera is taken to look down and not to be mounted upside down (this picks the
sign of d)."""

from __future__ import annotations

import cv2
import numpy as np

from yowo_common.camera import CameraModel

from .params import DetectorParams

AXIS_SIGMA_DEG = 2.5  # scatter of a silhouette's principal plane around the vertical
SCENE_MIN_SIGMA_DEG = 0.2  # long edges are not perfectly straight
SCENE_CANDIDATE_LINES = 100  # the most precise lines propose vanishing points
SCENE_CANDIDATES = 200  # the best supported of them are checked for a Manhattan horizon
MANHATTAN_BIN_DEG = 0.5  # horizontal vanishing directions are binned this finely
LEVEL_TOLERANCE = 0.05  # |d_z| of a camera looking level
MIN_AXIS_SPREAD_DEG = 5.0  # agent axes alike within this fix only a band of verticals


def _robust_null(
    normals: np.ndarray, sigma_deg: np.ndarray, init: np.ndarray | None = None, iterations: int = 10
) -> np.ndarray:
    """Unit vector most orthogonal to the planes with these normals: iteratively
    reweighted least squares on the angle between the vector and each plane, with
    inverse-variance weights and Tukey's loss (planes beyond 3 sigma drop out)."""
    v = init
    w = sigma_deg**-2.0
    for _ in range(iterations):
        if v is not None:
            r = np.degrees(np.arcsin(np.clip(np.abs(normals @ v), 0.0, 1.0))) / sigma_deg
            w = sigma_deg**-2.0 * np.clip(1.0 - (r / 3.0) ** 2, 0.0, None) ** 2
        v = np.linalg.eigh((normals * w[:, None]).T @ normals)[1][:, 0]
    return v


def _scene_line_normals(camera: CameraModel, background: np.ndarray, min_length_px: float = 20.0):
    """Planes (through the camera centre) of the background's straight edges
    (LSD), and each one's direction uncertainty in degrees."""
    lines = cv2.createLineSegmentDetector().detect(cv2.cvtColor(background, cv2.COLOR_RGB2GRAY))[0]
    if lines is None:
        return np.zeros((0, 3)), np.zeros(0)
    lines = lines.reshape(-1, 4).astype(float)
    length = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1])
    lines, length = lines[length >= min_length_px], length[length >= min_length_px]
    n = np.cross(camera.bearings(lines[:, :2]), camera.bearings(lines[:, 2:]))
    # Endpoints are good to about half a pixel.
    return n / np.linalg.norm(n, axis=1, keepdims=True), np.maximum(np.degrees(1.0 / length), SCENE_MIN_SIGMA_DEG)


def _scene_vertical(
    normals: np.ndarray, sigma_deg: np.ndarray, offset_deg, cone_deg: float, at: np.ndarray, min_lines: int = 4
) -> np.ndarray | None:
    """The vertical vanishing direction that best explains the scene's straight
    edges (normals: their planes through the camera centre; sigma_deg: their
    precision) as a room's: vertical edges pass through it, and the others (most
    of them) run along two orthogonal horizontal directions (a Manhattan world).
    Candidates are the intersections of pairs of the most precise lines that can
    be a ceiling camera's nadir (below the agent at `at`, in front of the camera)
    and that are at most cone_deg from the agent's estimate by `offset_deg`;
    scores have a Gaussian prior (sigma cone_deg / 2) on that offset. None
    without enough support. (Shelves and leaning objects make clusters of
    near-vertical edges; only the true vertical also orders the horizontal ones.)"""
    if len(normals) < min_lines:
        return None
    best = np.argsort(sigma_deg)[:SCENE_CANDIDATE_LINES]
    i, j = np.triu_indices(len(best), 1)
    cand = np.cross(normals[best[i]], normals[best[j]])
    norm = np.linalg.norm(cand, axis=1)
    cand = _orient_down(cand[norm > 1e-3] / norm[norm > 1e-3, None], at)
    offset = offset_deg(cand)
    keep = (offset < cone_deg) & (cand[:, 2] > -LEVEL_TOLERANCE)
    cand, prior = cand[keep], np.exp(-2.0 * (offset[keep] / cone_deg) ** 2)
    if len(cand) == 0:
        return None
    weight = 1.0 / sigma_deg  # the line's length
    vertical = np.degrees(np.arcsin(np.clip(np.abs(cand @ normals.T), 0.0, 1.0))) < 3.0 * sigma_deg  # (cand, lines)
    # The best candidate per 0.5 degree cell (a strong cluster yields many near-copies), best cells first.
    order = np.argsort(-(vertical @ weight) * prior)
    cell = np.round(cand[order] / np.radians(MANHATTAN_BIN_DEG)).astype(np.int64)
    _, first = np.unique(cell, axis=0, return_index=True)
    top = order[np.sort(first)[:SCENE_CANDIDATES]]
    cand, prior, vertical = cand[top], prior[top], vertical[top]
    # Each other line's vanishing point on the candidate's horizon, as an azimuth modulo 90 degrees.
    e1 = np.cross(cand, np.where(np.abs(cand[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(cand, e1)
    v = np.cross(normals[None, :, :], cand[:, None, :])  # (cand, lines, 3)
    azimuth = np.degrees(np.arctan2(np.einsum("clk,ck->cl", v, e2), np.einsum("clk,ck->cl", v, e1))) % 90.0
    bins = int(90.0 / MANHATTAN_BIN_DEG)
    index = np.arange(len(cand))[:, None] * bins + np.floor(azimuth / MANHATTAN_BIN_DEG).astype(int) % bins
    hist = np.bincount(index.ravel(), weights=(~vertical * weight).ravel(), minlength=len(cand) * bins)
    hist = hist.reshape(len(cand), bins)
    hist = hist + np.roll(hist, 1, axis=1) + np.roll(hist, -1, axis=1)
    k = int(np.argmax((vertical @ weight + hist.max(axis=1)) * prior))
    return cand[k] if vertical[k].sum() >= min_lines else None


def _spread_deg(normals: np.ndarray, d: np.ndarray) -> float:
    """RMS angle between the agent's axis planes around d (their normals' spread
    orthogonal to d): small when the agent was only seen in one place."""
    m = np.linalg.eigh(normals.T @ normals)[1][:, 2]  # the mean normal
    side = np.cross(d, m)
    side /= np.linalg.norm(side)
    return float(np.degrees(np.sqrt(np.mean(np.arcsin(np.clip(normals @ side, -1.0, 1.0)) ** 2))))


def _orient_down(d: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Down directions (rows of d, sign free) signed to point down the image at the
    bearing `at` (the camera is not mounted upside down): moving along d from the
    normalised point p goes along (d_x - d_z p_x, d_y - d_z p_y) in the image."""
    s = np.sign(d[..., 1] - d[..., 2] * at[1] / at[2])
    return d * np.where(s == 0, 1.0, s)[..., None]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def outline_top(b: np.ndarray, d: np.ndarray, rho: float, p: DetectorParams, f: float):
    """Head-top bearing of an outline (bearings b), its sideways unit direction u
    (orthogonal to d) and every outline point's angle from the nadir. Sideways, the
    top is the middle between the head's left and right edges down to one head
    radius below the top, which survives hair blending into the background on one
    side."""
    theta = np.arccos(np.clip(b @ d, -1.0, 1.0))
    t_max = theta.max()
    m = b[theta > t_max - p.top_band_px / f].mean(axis=0)
    u = m - (m @ d) * d
    u /= np.linalg.norm(u)
    r = max(_head_radius_angle(t_max, rho, p.head_radius), p.top_band_px / f)
    side = np.arctan2(b @ np.cross(d, u), b @ u)
    side = side[(theta > t_max - r) & (np.abs(side) < 1.5 * r)]  # the head, not the shoulders
    middle = 0.5 * (side.min() + side.max())
    u = np.cos(middle) * u + np.sin(middle) * np.cross(d, u)
    t = t_max - _head_bias(t_max, rho, p.head_radius)
    return np.cos(t) * d + np.sin(t) * u, u, theta


def _head_radius_angle(theta: float, rho: float, head_radius: float) -> float:
    """Angular radius of the head seen at angle theta from the nadir; lengths in
    camera heights (head radius r = k rho, distance to the head centre
    D = (1 - rho + r) / cos(theta))."""
    r = head_radius * rho
    return r * np.cos(theta) / (1.0 - rho + r)


def _head_bias(theta: float, rho: float, head_radius: float) -> float:
    """Angle by which a spherical head's outline top lies above its top point, seen
    at angle theta from the nadir."""
    return _head_radius_angle(theta, rho, head_radius) * (1.0 - np.sin(theta))


def rho_from_feet(cos_top: float, theta_low: float, foot_reach: float) -> float:
    """Height ratio from the head top (its cosine to the nadir) and the lowest sole
    point, which lies foot_reach * rho closer to the camera than the ground point:
    (1 - rho) tan(theta_top) = tan(theta_low) + foot_reach * rho."""
    tan_top = np.sqrt(max(1.0 - cos_top**2, 0.0)) / max(cos_top, 1e-9)
    return float((tan_top - np.tan(theta_low)) / (tan_top + foot_reach))


class SceneGeometry:
    """Down direction d and height ratio rho, estimated from many silhouettes."""

    def __init__(self, params: DetectorParams, camera: CameraModel, focal_px: float):
        self.p, self.camera, self.f = params, camera, focal_px
        self.silhouettes: list[np.ndarray] = []  # float32 outline bearings of distinct, uncut silhouettes
        self._last_centre: np.ndarray | None = None
        self.d: np.ndarray | None = None
        self.rho: float | None = None
        self.settled = False
        self._estimated_at = 0

    def add(self, bearings: np.ndarray) -> None:
        """Keep a silhouette unless it repeats the last one kept (a standing agent
        would otherwise dominate the fit)."""
        centre = bearings.mean(axis=0)
        centre /= np.linalg.norm(centre)
        if (
            self._last_centre is not None
            and np.radians(_angle_deg(centre, self._last_centre)) * self.f < self.p.distinct_px
        ):
            return
        self._last_centre = centre
        self.silhouettes.append(bearings.astype(np.float32))
        if len(self.silhouettes) > self.p.max_geometry_frames:
            self.silhouettes = self.silhouettes[::2]  # thin evenly over time

    @property
    def count(self) -> int:
        return len(self.silhouettes)

    def update(self, minimum: int, background: np.ndarray, final: bool = False) -> None:
        """Re-estimate from `minimum` silhouettes on, whenever their number grew by a
        quarter (at least 10), or changed at all when `final`."""
        n, last = self.count, self._estimated_at
        due = n != last if final else (n >= last + max(10, last // 4) or n < last)
        if n < minimum or not due:
            return
        d, rho = self.d, self.rho
        self._estimated_at = n
        if (
            self._estimate(background)
            and d is not None
            and _angle_deg(d, self.d) < self.p.settle_deg
            and abs(rho - self.rho) < self.p.settle_rho
        ):
            self.settled = True

    def _estimate(self, background: np.ndarray) -> bool:
        """Sets d and rho; False (and no change) when the data leave d undetermined."""
        sils = [s.astype(np.float64) for s in self.silhouettes]
        normals = np.array([np.linalg.eigh(b.T @ b)[1][:, 0] for b in sils])
        sigma = np.full(len(normals), AXIS_SIGMA_DEG)
        d_agent = _robust_null(normals, sigma, init=_robust_null(normals, 4.0 * sigma))
        scene_n, scene_sigma = _scene_line_normals(self.camera, background)
        at = np.mean([b.mean(axis=0) for b in sils], axis=0)

        def agent_misfit(c):  # median angle to the agent's planes
            return np.median(np.degrees(np.arcsin(np.clip(np.abs(c @ normals.T), 0.0, 1.0))), axis=-1)

        def offset(c):  # small along the directions the agent's planes leave open
            return np.maximum(agent_misfit(c) - agent_misfit(d_agent), 0.0)

        scene_d = _scene_vertical(scene_n, scene_sigma, offset, self.p.scene_cone_deg, at)
        if scene_d is not None:
            d = _robust_null(np.vstack([normals, scene_n]), np.concatenate([sigma, scene_sigma]), init=scene_d)
        elif _spread_deg(normals, d_agent) >= MIN_AXIS_SPREAD_DEG:
            d = d_agent
        else:
            return False  # the agent's axes only fix a band, and no scene edges pick d on it
        d = _orient_down(d, at)
        if d[2] <= -LEVEL_TOLERANCE:
            return False  # a camera looking up: not a ceiling camera, or a wrong vertical
        if np.median(np.degrees(np.arcsin(np.clip(np.abs(normals @ d), 0.0, 1.0)))) > 2.0 * AXIS_SIGMA_DEG:
            return False  # the silhouettes are not upright people (or the background is spoilt)

        def rho_from(b, rho):
            top, _, theta = outline_top(b, d, rho, self.p, self.f)
            return rho_from_feet(top @ d, theta.min(), self.p.foot_reach)

        rho = self.rho if self.rho is not None else 0.6
        for _ in range(2):  # the head-top correction depends on rho
            rho = float(np.median([rho_from(b, rho) for b in sils]))
        self.d, self.rho = d, rho
        return True
