"""The agent's walk: a path through the free floor that visits every CMC's view,
with pauses (the paper's "stationary for a long time" case) and head motion."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra
from shapely.geometry import Point, Polygon
from shapely.ops import nearest_points

from yowo_common.geometry import se3

# Optical frame (x right, y down, z forward) expressed in a body frame (x forward, y left, z up).
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
STRIDE_M = 1.4  # one gait cycle (two steps)
SAMPLE_HZ = 100.0  # resolution of the walk timeline
BOB_M = 0.015  # vertical head bob amplitude at walking speed
EYE_BELOW_TOP_M = 0.10  # the ego camera below the head top ...
EYE_FORWARD_M = 0.10  # ... and in front of it (body x)


@dataclass(frozen=True)
class WalkSpec:
    speed_mps: float = 1.0
    agent_height_m: float = 1.75
    pause_s: float = 4.0  # stationary time at each CMC view
    long_pause_s: float = 0.0  # one extra-long stop (stationary-agent scenario)
    look_around_deg: float = 25.0  # head yaw amplitude while walking
    pitch_down_deg: float = 20.0  # mean head pitch, looking slightly down
    # Time to reach walking speed from standing, and to stop (a smooth speed profile:
    # the IMU sees finite accelerations; 0: start and stop at once).
    ramp_s: float = 0.8


@dataclass(kw_only=True)
class Walk:
    """Dense timeline of the agent: position, heading, gait phase and head angles."""

    t_s: np.ndarray  # (N,) seconds from the start
    xy: np.ndarray  # (N, 2)
    heading: np.ndarray  # (N,) rad, walking direction
    phase: np.ndarray  # (N,) rad, gait phase (constant while standing)
    head_yaw: np.ndarray  # (N,) rad relative to heading
    head_pitch: np.ndarray  # (N,) rad, positive = looking down
    head_roll: np.ndarray  # (N,) rad
    height_m: float
    bob_m: np.ndarray | None = None  # (N,) vertical head bob of the gait [m] (None: none)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    @functools.cached_property
    def _spline(self) -> CubicSpline:
        """The timeline between its samples: one C2 cubic spline through every channel, so
        the ego pose has exact velocities and accelerations (what the IMU measures)."""
        bob = np.zeros_like(self.t_s) if self.bob_m is None else self.bob_m
        channels = np.column_stack(
            [self.xy, self.heading, self.phase, self.heading + self.head_yaw, self.head_pitch, self.head_roll, bob]
        )
        return CubicSpline(self.t_s, channels, axis=0)

    def state_at(self, t: float) -> tuple[np.ndarray, float, float]:
        """(xy, heading, phase) at time t (angles unwrapped)."""
        v = self._spline(np.clip(t, 0.0, self.duration_s))
        return v[:2], float(v[2]), float(v[3])

    def ego_pose_at(self, t: float) -> np.ndarray:
        """T_world_ego: the head-mounted camera ~10 cm below the head top and in front of it,
        bobbing with the gait."""
        m = self.ego_motion(np.array([t], dtype=float))
        return se3(m.R[0], m.p[0])

    def ego_motion(self, t_s: np.ndarray) -> EgoMotion:
        """The ego camera's pose and its first and second time derivatives at times t_s,
        analytic from the timeline's spline (ego_pose_at is its zeroth order)."""
        t = np.clip(np.asarray(t_s, dtype=float), 0.0, self.duration_s)
        v, dv, ddv = (self._spline(t, k) for k in range(3))
        R, dR, ddR = _rotation_z(v[:, 4], dv[:, 4], ddv[:, 4])
        for rot, k in ((_rotation_y, 5), (_rotation_x, 6)):  # intrinsic ZYX: yaw, pitch, roll
            R, dR, ddR = _jet_product((R, dR, ddR), rot(v[:, k], dv[:, k], ddv[:, k]))
        eye = np.array([EYE_FORWARD_M, 0.0, 0.0])
        base = np.column_stack([v[:, 0], v[:, 1], self.height_m - EYE_BELOW_TOP_M + v[:, 7]])
        dbase = np.column_stack([dv[:, 0], dv[:, 1], dv[:, 7]])
        ddbase = np.column_stack([ddv[:, 0], ddv[:, 1], ddv[:, 7]])
        return EgoMotion(
            t_s=t,
            R=R @ R_BODY_OPTICAL,
            dR=dR @ R_BODY_OPTICAL,
            ddR=ddR @ R_BODY_OPTICAL,
            p=base + R @ eye,
            dp=dbase + dR @ eye,
            ddp=ddbase + ddR @ eye,
        )


@dataclass(kw_only=True)
class EgoMotion:
    """T_world_ego (R, p) at times t and its time derivatives, in the world frame."""

    t_s: np.ndarray  # (n,)
    R: np.ndarray  # (n, 3, 3) R_world_ego
    dR: np.ndarray  # (n, 3, 3) dR/dt
    ddR: np.ndarray  # (n, 3, 3) d2R/dt2
    p: np.ndarray  # (n, 3) camera centre [m]
    dp: np.ndarray  # (n, 3) velocity [m/s]
    ddp: np.ndarray  # (n, 3) acceleration [m/s^2]

    @property
    def omega_ego(self) -> np.ndarray:
        """(n, 3) angular velocity in the ego frame [rad/s]: vee(R^T dR/dt)."""
        W = np.einsum("nji,njk->nik", self.R, self.dR)
        return np.column_stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]])


def _elementary(axis: int, a: np.ndarray, da: np.ndarray, dda: np.ndarray):
    """Rotation by angle a(t) about a coordinate axis and its first two time derivatives:
    R = exp(a K), dR = R K da, ddR = R (K K da^2 + K dda)."""
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.zeros((len(a), 3, 3))
    R[:, axis, axis] = 1.0
    R[:, i, i], R[:, i, j], R[:, j, i], R[:, j, j] = c, -s, s, c
    K = np.zeros((3, 3))
    K[i, j], K[j, i] = -1.0, 1.0
    RK = R @ K
    return R, RK * da[:, None, None], RK @ K * (da**2)[:, None, None] + RK * dda[:, None, None]


def _rotation_x(a, da, dda):
    return _elementary(0, a, da, dda)


def _rotation_y(a, da, dda):
    return _elementary(1, a, da, dda)


def _rotation_z(a, da, dda):
    return _elementary(2, a, da, dda)


def _jet_product(A, B):
    """(AB, (AB)', (AB)'') from the jets (A, A', A'') and (B, B', B'')."""
    return A[0] @ B[0], A[1] @ B[0] + A[0] @ B[1], A[2] @ B[0] + 2.0 * A[1] @ B[1] + A[0] @ B[2]


class _VisibilityGraph:
    """Shortest paths inside `free` over the polygon's vertices. The node-to-node
    visibility is tested once per walk, on the prepared polygon: per leg, only the
    legs' ends are new (the large preset's floor has ~1000 vertices and 42 targets;
    testing every pair per leg took hours)."""

    def __init__(self, free: Polygon, nodes: np.ndarray):
        shapely.prepare(free)
        self.free, self.nodes = free, nodes
        ii, jj = np.triu_indices(len(nodes), 1)
        ok = shapely.covers(free, shapely.linestrings(np.stack([nodes[ii], nodes[jj]], axis=1)))
        self.ii, self.jj = ii[ok] + 2, jj[ok] + 2  # indices among [a, b, *nodes]

    def path(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        pts = np.vstack([a, b, self.nodes])
        n = len(pts)
        ends_i = np.concatenate([[0], np.zeros(n - 2, int), np.ones(n - 2, int)])
        ends_j = np.concatenate([[1], np.arange(2, n), np.arange(2, n)])
        ok = shapely.covers(self.free, shapely.linestrings(np.stack([pts[ends_i], pts[ends_j]], axis=1)))
        ii, jj = np.concatenate([ends_i[ok], self.ii]), np.concatenate([ends_j[ok], self.jj])
        w = np.linalg.norm(pts[ii] - pts[jj], axis=1)
        graph = csr_matrix((w, (ii, jj)), shape=(n, n))
        dist, pred = dijkstra(graph, directed=False, indices=0, return_predecessors=True)
        if not np.isfinite(dist[1]):
            raise ValueError(f"no walkable path from {a.round(2).tolist()} to {b.round(2).tolist()}")
        path, k = [1], 1
        while k != 0:
            k = pred[k]
            path.append(k)
        return pts[path[::-1]]


CORNER_CLEARANCE_M = 0.3  # paths keep this far from reflex corners, so rounding stays inside


def _corner_nodes(free: Polygon) -> np.ndarray:
    """Visibility-graph nodes: vertices of the free space shrunk by the corner clearance."""
    inner = free.buffer(-CORNER_CLEARANCE_M, join_style="mitre")
    parts = [g for g in getattr(inner, "geoms", [inner]) if not g.is_empty] or [free]
    return np.vstack([np.asarray(r.coords)[:-1] for g in parts for r in [g.exterior, *g.interiors]])


def _nearest_free(free: Polygon, p) -> np.ndarray:
    if free.contains(Point(p)):
        return np.asarray(p, dtype=float)
    q = nearest_points(free.buffer(-0.05), Point(p))[0]
    return np.array([q.x, q.y])


class FloorRoutes:
    """Shortest paths through the walkable floor (already shrunk by the body's clearance):
    one visibility graph shared by every walk planned on it (the agent's, the bystanders')."""

    def __init__(self, free):
        self.free = free if isinstance(free, Polygon) else max(free.geoms, key=lambda g: g.area)
        self.graph = _VisibilityGraph(self.free, _corner_nodes(self.free))

    def nearest_free(self, p) -> np.ndarray:
        return _nearest_free(self.free, p)

    def path(self, a, b) -> np.ndarray:
        """Corner points of the shortest path from a to b (both in the free floor)."""
        return self.graph.path(np.asarray(a, dtype=float), np.asarray(b, dtype=float))

    def walk_through(self, waypoints: list, pauses: list, spec: WalkSpec, rng: np.random.Generator) -> Walk:
        """Walk the waypoints in their order (the first is the start), standing pauses[i]
        seconds at waypoints[i] (pauses[0]: before setting off)."""
        points = [self.nearest_free(w) for w in waypoints]
        legs, stops = [points[0][None]], [float(pauses[0])]
        for a, b, pause in zip(points[:-1], points[1:], pauses[1:]):
            leg = self.path(a, b)
            legs.append(leg[1:])
            stops += [0.0] * (len(leg) - 2) + [float(pause)]
        return _timeline(np.vstack(legs), np.array(stops), spec, rng)


def plan_walk(
    free: Polygon | FloorRoutes, start_xy, targets_xy: list, spec: WalkSpec, rng: np.random.Generator
) -> Walk:
    """Walk from start through every target (nearest-first order), pausing at each;
    `free` is the walkable floor already shrunk by the body's clearance (or its routes)."""
    routes = free if isinstance(free, FloorRoutes) else FloorRoutes(free)
    current = routes.nearest_free(start_xy)
    remaining = [routes.nearest_free(t) for t in targets_xy]
    order, pauses = [current], [0.0]
    long_pause_at = int(rng.integers(len(remaining))) if remaining and spec.long_pause_s > 0 else -1
    visit = 0
    while remaining:
        k = int(np.argmin([np.linalg.norm(r - current) for r in remaining]))
        current = remaining.pop(k)
        order.append(current)
        pauses.append(spec.pause_s + (spec.long_pause_s if visit == long_pause_at else 0.0))
        visit += 1
    return routes.walk_through(order, pauses, spec, rng)


def _resample(polyline: np.ndarray, spacing: float) -> np.ndarray:
    """Points every `spacing` metres along a polyline (both ends kept)."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(int(np.ceil(s[-1] / spacing)), 1)
    q = np.linspace(0.0, s[-1], n + 1)
    return np.column_stack([np.interp(q, s, polyline[:, k]) for k in range(2)])


def _rounded(leg: np.ndarray, radius_m: float = 0.35) -> np.ndarray:
    """Round a leg's corners (a person does not turn on the spot while walking),
    keeping its end points where they are."""
    dense = _resample(leg, 0.01)
    if len(dense) < 3:
        return dense
    smooth = np.column_stack([gaussian_filter1d(dense[:, k], radius_m / 0.01, mode="nearest") for k in range(2)])
    u = np.linspace(0.0, 1.0, len(dense))[:, None]
    return smooth - (1 - u) * (smooth[0] - dense[0]) - u * (smooth[-1] - dense[-1])


def _speed_ramp(u: np.ndarray) -> np.ndarray:
    """Speed shape 0 -> 1 over u in [0, 1] (smootherstep: zero acceleration and jerk at both ends)."""
    u = np.clip(u, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u**2)


def _ramp_distance(u: np.ndarray) -> np.ndarray:
    """Integral of _speed_ramp from 0 to u (1/2 at u = 1)."""
    u = np.clip(u, 0.0, 1.0)
    return u**4 * (2.5 - 3.0 * u + u**2)


def _leg_profile(length_m: float, spec: WalkSpec, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(distance, speed) along a leg at the samples dt, 2 dt, ..., n dt: from standing to
    walking speed in spec.ramp_s, cruise, and to standing again, ending exactly at the leg's
    end; the cruise speed is never above spec.speed_mps."""
    n = max(int(np.ceil((length_m / spec.speed_mps + spec.ramp_s) / dt - 1e-9)), 1)
    tau = np.arange(1, n + 1) * dt
    total = n * dt
    ramp = min(spec.ramp_s, total / 2.0)
    v = length_m / (total - ramp)
    if ramp <= 0.0:
        return v * tau, np.full(n, v)
    up, down = tau / ramp, (total - tau) / ramp
    s = np.where(
        tau <= ramp,
        v * ramp * _ramp_distance(up),
        np.where(tau >= total - ramp, length_m - v * ramp * _ramp_distance(down), v * (tau - ramp / 2.0)),
    )
    return s, v * np.minimum(_speed_ramp(up), _speed_ramp(down))


def _timeline(corners: np.ndarray, pauses: np.ndarray, spec: WalkSpec, rng: np.random.Generator) -> Walk:
    """Walk the corner path with rounded corners, speeding up from and slowing down to a
    stand, standing still for pauses[i] seconds at corners[i] (pauses[0]: before setting
    off); sampled at SAMPLE_HZ."""
    dt = 1.0 / SAMPLE_HZ
    n_wait = 1 + int(round(pauses[0] * SAMPLE_HZ))
    xy, moving, speed_frac = [np.repeat(corners[:1], n_wait, axis=0)], [np.zeros(n_wait, bool)], [np.zeros(n_wait)]
    stops = [0] + [i for i in range(1, len(corners)) if pauses[i] > 0 or i == len(corners) - 1]
    for a, b in zip(stops[:-1], stops[1:]):
        path = _rounded(corners[a : b + 1])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        s, v = _leg_profile(float(arc[-1]), spec, dt)
        walked = np.column_stack([np.interp(s, arc, path[:, k]) for k in range(2)])
        n_pause = int(round(pauses[b] * SAMPLE_HZ))
        xy += [walked, np.repeat(walked[-1:], n_pause, axis=0)]
        moving += [np.ones(len(walked), bool), np.zeros(n_pause, bool)]
        speed_frac += [v / spec.speed_mps, np.zeros(n_pause)]
    xy = np.vstack(xy)
    moving = np.concatenate(moving)
    speed_frac = np.concatenate(speed_frac)
    vel = np.gradient(xy, dt, axis=0)
    speed = np.linalg.norm(vel, axis=1)
    heading = np.arctan2(vel[:, 1], vel[:, 0])
    # Keep the last walking heading while standing still.
    for i in range(1, len(heading)):
        if speed[i] < 0.05:
            heading[i] = heading[i - 1]
    heading = np.unwrap(gaussian_filter1d(np.unwrap(heading), sigma=0.1 * SAMPLE_HZ, mode="nearest"))
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    phase = 2.0 * np.pi * dist / STRIDE_M
    t = np.arange(len(xy)) * dt
    # Head: slow look-around while walking, wide scans while standing, slight pitch/roll sway.
    f1, f2 = rng.uniform(0.1, 0.2), rng.uniform(0.05, 0.1)
    standing = gaussian_filter1d((~moving).astype(float), sigma=0.5 * SAMPLE_HZ)
    yaw_amp = np.radians(spec.look_around_deg) * (1 + 1.5 * standing)
    head_yaw = yaw_amp * np.sin(2 * np.pi * f1 * t + rng.uniform(0, 2 * np.pi))
    head_pitch = np.radians(spec.pitch_down_deg) + np.radians(8.0) * np.sin(2 * np.pi * f2 * t)
    head_roll = np.radians(2.0) * np.sin(phase / 2.0) * (1 - standing)
    # The bob grows with the speed (no jump of the head when the agent stops or starts).
    bob = BOB_M * np.cos(2.0 * phase) * speed_frac
    return Walk(
        t_s=t,
        xy=xy,
        heading=heading,
        phase=phase,
        head_yaw=head_yaw,
        head_pitch=head_pitch,
        head_roll=head_roll,
        height_m=spec.agent_height_m,
        bob_m=bob,
    )
