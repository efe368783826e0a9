"""Bystanders (issue #46): other people walking through the same rooms as the agent, in
the CMCs' and the ego camera's views, so the pipeline meets frames with more than one
person. Each walks its own path for the whole recording, with its own height, speed,
pauses and clothes; some are sent to pass close by the agent.

They come from a random generator of their own ([seed, 46]): the agent's walk, the
cameras and the clocks of a seed are the same with and without bystanders.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import yaml

from .body import GROUND, HEAD_TOP, AgentMesh, Clothing, agent_keypoints_3d, agent_mesh
from .walk import SAMPLE_HZ, FloorRoutes, Walk, WalkSpec

RNG_STREAM = 46  # default_rng([seed, RNG_STREAM]): the bystanders' own generator
# People keep their centres this far apart (bodies about 0.4 m wide): a bystander's plan
# that walks into someone is drawn again, up to PLAN_TRIES times (then the least close one:
# on a long walk people may brush past each other; there is no collision avoidance).
PERSONAL_SPACE_M = 0.5
PLAN_TRIES = 6
GT_KEYPOINT_IDS = (HEAD_TOP, GROUND)  # per bystander on /gt/bystanders/keypoints, in this order

# Clothes far from the agent's orange shirt and blue trousers (RGB distance), so a
# detector that follows the agent's look is not fooled by the colours alone.
SHIRTS = (
    (235, 235, 230),
    (60, 130, 70),
    (120, 50, 130),
    (40, 150, 170),
    (150, 30, 45),
    (110, 110, 115),
    (30, 30, 35),
    (215, 205, 70),
)
BYSTANDER_TROUSERS = ((40, 40, 45), (130, 110, 80), (180, 170, 140), (70, 50, 35), (95, 95, 100))
HAIRS = ((60, 40, 25), (20, 18, 18), (150, 110, 60), (125, 125, 125))
SKINS = ((224, 172, 140), (175, 125, 90), (120, 80, 55), (240, 200, 170))


@dataclass(frozen=True, kw_only=True)
class BystanderSpec:
    count: int = 0  # people walking about besides the agent (0: the agent alone)
    height_m: tuple[float, float] = (1.55, 1.90)  # each one's height, drawn uniformly
    speed_mps: tuple[float, float] = (0.7, 1.3)  # each one's walking speed, drawn uniformly
    pause_s: tuple[float, float] = (0.0, 5.0)  # standing time at each of its targets, drawn per target
    crossing_share: float = 0.5  # share of them (rounded up) sent to pass within a metre of the agent
    target_jitter_m: float = 0.6  # targets scattered this far around CMC targets and room centres


@dataclass(kw_only=True)
class Bystander:
    walk: Walk  # its timeline; walk.height_m is its height
    clothing: Clothing
    crosses_at_s: float | None = None  # when it passes the agent (None: not sent to)

    @property
    def height_m(self) -> float:
        return self.walk.height_m

    def mesh(self, t: float) -> AgentMesh:
        xy, heading, phase = self.walk.state_at(t)
        return agent_mesh(xy, heading, self.walk.height_m, phase, self.clothing)

    def keypoints(self, t: float) -> dict[int, np.ndarray]:
        xy, heading, phase = self.walk.state_at(t)
        return agent_keypoints_3d(xy, heading, self.walk.height_m, phase)


def _clothes(count: int, rng: np.random.Generator) -> list[Clothing]:
    shirts = [SHIRTS[i] for i in rng.permutation(len(SHIRTS))]
    trousers = [BYSTANDER_TROUSERS[i] for i in rng.permutation(len(BYSTANDER_TROUSERS))]
    out = []
    for i in range(count):
        skin = SKINS[int(rng.integers(len(SKINS)))]
        out.append(
            Clothing(
                shirt=shirts[i % len(shirts)],
                trousers=trousers[i % len(trousers)],
                skin=skin,
                skin_shade=tuple(int(round(0.89 * c)) for c in skin),
                hair=HAIRS[int(rng.integers(len(HAIRS)))],
            )
        )
    return out


def _travel_s(routes: FloorRoutes, a, b, spec: WalkSpec) -> float:
    """Time to walk from a to b and stop there (walk._leg_profile: the ramps cost ramp_s)."""
    path = routes.path(a, b)
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) / spec.speed_mps + spec.ramp_s


def _meeting_point(routes: FloorRoutes, agent: Walk, t: float, rng: np.random.Generator) -> np.ndarray:
    """A free spot beside the agent's position at time t (within a metre, never on it)."""
    xy, heading, _ = agent.state_at(t)
    left = np.array([-np.sin(heading), np.cos(heading)])
    side = 1.0 if rng.random() < 0.5 else -1.0
    for offset in (0.6, -0.6, 0.45, -0.45, 0.8, -0.8):
        q = routes.nearest_free(xy + side * offset * left)
        if PERSONAL_SPACE_M < np.linalg.norm(q - xy) < 0.9:
            return q
    return routes.nearest_free(xy + side * 0.6 * left)


def plan_bystanders(spec: BystanderSpec, routes: FloorRoutes, places: list, agent: Walk, seed: int) -> list[Bystander]:
    """``spec.count`` bystanders walking between ``places`` (CMC targets, room centres),
    each scattered by the spec's jitter, in a random order, for at least the agent's
    whole walk; the crossing ones first walk to a spot beside the agent's path and
    stand there from a second before the agent passes until a second after."""
    if spec.count <= 0:
        return []
    rng = np.random.default_rng([seed, RNG_STREAM])
    n_cross = int(np.ceil(spec.crossing_share * spec.count - 1e-9))
    crossing = rng.permutation(spec.count) < n_cross
    clothes = _clothes(spec.count, rng)
    places = [np.asarray(p, dtype=float) for p in places]

    def place(away_from=None):
        """A scattered place, if it can be, half a metre or more from ``away_from``."""
        for _ in range(20):
            p = places[int(rng.integers(len(places)))] + rng.uniform(-1.0, 1.0, 2) * spec.target_jitter_m
            p = routes.nearest_free(p)
            if away_from is None or np.linalg.norm(p - away_from) >= 0.5:
                break
        return p

    def plan(wspec: WalkSpec, crosses: bool) -> tuple[Walk, float | None]:
        start = place()
        waypoints, pauses, elapsed, crosses_at = [start], [float(rng.uniform(*spec.pause_s))], 0.0, None
        if crosses:
            crosses_at = float(rng.uniform(0.2, 0.8) * agent.duration_s)
            meet = _meeting_point(routes, agent, crosses_at, rng)
            # A start it can leave in time to arrive a second early; else it waits at the spot.
            candidates = [start] + [place() for _ in range(5)]
            travel = [_travel_s(routes, c, meet, wspec) for c in candidates]
            fits = [k for k, s in enumerate(travel) if s <= crosses_at - 1.0]
            if fits:
                k = fits[0]
                waypoints = [candidates[k], meet]
                pauses = [crosses_at - 1.0 - travel[k], 2.0]
            else:
                waypoints, pauses = [meet], [crosses_at + 1.0]
            elapsed = crosses_at + 1.0
        # Walk on until past the agent's end (an estimate; after its end it stands still).
        while elapsed < agent.duration_s + 2.0:
            nxt = place(away_from=waypoints[-1])
            pause = float(rng.uniform(*spec.pause_s))
            elapsed += _travel_s(routes, waypoints[-1], nxt, wspec) + pause
            waypoints.append(nxt)
            pauses.append(pause)
        return routes.walk_through(waypoints, pauses, wspec, rng), crosses_at

    out: list[Bystander] = []
    for i in range(spec.count):
        wspec = WalkSpec(
            speed_mps=float(rng.uniform(*spec.speed_mps)),
            agent_height_m=float(rng.uniform(*spec.height_m)),
            pause_s=0.0,
        )
        best, best_gap = None, -1.0
        for _ in range(PLAN_TRIES):
            walk, crosses_at = plan(wspec, bool(crossing[i]))
            gap = _closest_approach(walk, [agent] + [b.walk for b in out], agent.duration_s)
            if gap > best_gap:
                best, best_gap = (walk, crosses_at), gap
            if gap >= PERSONAL_SPACE_M:
                break
        out.append(Bystander(walk=best[0], clothing=clothes[i], crosses_at_s=best[1]))
    return out


def _closest_approach(walk: Walk, others: list[Walk], duration_s: float) -> float:
    """The least distance [m] between ``walk`` and any of ``others`` at the same time,
    every 0.1 s over the duration (a finished walk stands at its end)."""
    t = np.arange(0.0, duration_s, 0.1)

    def xy(w: Walk) -> np.ndarray:
        return w.xy[np.minimum(np.round(t * SAMPLE_HZ).astype(int), len(w.xy) - 1)]

    mine = xy(walk)
    return min(float(np.linalg.norm(mine - xy(o), axis=1).min()) for o in others)


def info_yaml(bystanders: list[Bystander]) -> str:
    """What evaluation needs to tell the people apart (/gt/bystanders/info)."""
    doc = {
        "keypoints": "/gt/bystanders/keypoints: poses[2 i] head top, poses[2 i + 1] ground point of bystander i",
        "bystanders": [
            {
                "index": i,
                "height_m": float(b.height_m),
                "shirt_rgb": list(b.clothing.shirt),
                "trousers_rgb": list(b.clothing.trousers),
                "crosses_agent_at_s": b.crosses_at_s,
            }
            for i, b in enumerate(bystanders)
        ],
    }
    return yaml.safe_dump(doc, sort_keys=False)
