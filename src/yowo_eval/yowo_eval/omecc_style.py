"""OMECC-style baseline (a labelled reimplementation of the idea of Pätzold et al. 2022,
"Online marker-free extrinsic camera calibration using person keypoint detections",
not the authors' code): relative CMC calibration from the agent's keypoints alone by
one factor graph over camera poses and person keypoints, started from a rough
initialisation, with the person's height as the only scale information.

Shares YOWO's primitives: the same time grid and correspondences (``sample_on_grid``),
MAGSAC pair geometry and scene-graph grouping (``pair_geometry``, ``group_cameras``),
so only the calibration of each group differs:

1. Rough initialisation (OMECC itself starts from rough manual poses; we have none, so
   we build what such a system could get without markers): the 5-point essential matrix
   of every camera pair of the group (``IncrementalSfm.initialise``); rotations chained
   along the maximum spanning tree of the pairs (weight = inliers), camera centres by
   linear translation averaging of the pairs' baseline directions, pairs that disagree
   with the rest dropped; the agent triangulated with these poses and everything scaled
   so that the median head-top to ground distance = the prior height.
2. Factor graph (GTSAM built-in factors only): a Pose3 per camera (the root camera
   fixed), a Point3 per (grid time, keypoint id) seen by two or more cameras,
   Huber-robust ``GenericProjectionFactorCal3_S2`` per observation, and a
   ``RangeFactor3`` between the head top (id 0) and ground point (id 1) of each
   instant = the prior person height. Levenberg-Marquardt.

Differences from OMECC: offline batch instead of online sliding window; the agent's
two required keypoints (plus any others present) instead of a full skeleton with limb
length factors; no temporal smoothness factors; the height prior replaces their
scale-by-person-size assumption.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import networkx as nx
import numpy as np
from gtsam.symbol_shorthand import L, X

from yowo_cmc.group_sfm import CameraGroupResult, GroupingResult
from yowo_cmc.incremental_sfm import IncrementalSfm, triangulate
from yowo_cmc.keypoint_tracks import CameraTracks
from yowo_cmc.params import SfmParams
from yowo_cmc.scene_graph import MAX_IDS, GridObservations, PairGeometry, group_cameras, pair_geometry, sample_on_grid
from yowo_common.bundle import (
    FIXED_SIGMA,
    Observations,
    add_projection_factors,
    optimize,
    pose3,
    reprojection_residuals,
    robust_sigma,
)
from yowo_common.geometry import inv_se3, rotation_angle_deg, se3, skew

HEAD_TOP, GROUND = 0, 1


@dataclass(frozen=True)
class OmeccParams:
    # An average adult: the method knows a typical height, not the agent's.
    person_height_m: float = 1.70
    person_height_sigma_m: float = 0.10
    sigma_px: float = 1.5  # projection factor noise (Huber inlier scale)
    huber_k: float = 1.345
    min_height_pairs: int = 5  # head/ground instants a group needs to get a scale
    max_rotation_disagreement_deg: float = 15.0  # pair rotation vs the spanning tree's
    max_direction_disagreement_deg: float = 20.0  # pair baseline direction vs the averaged centres
    max_iterations: int = 200
    sfm: SfmParams = field(default_factory=SfmParams)


def head_ground_pairs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keys of head tops whose ground point at the same grid time is also in ``keys``:
    (head keys, ground keys)."""
    keys = np.asarray(keys, dtype=np.int64)
    heads = keys[keys % MAX_IDS == HEAD_TOP]
    grounds = heads - HEAD_TOP + GROUND
    ok = np.isin(grounds, keys)
    return heads[ok], grounds[ok]


def pair_pose(obs: GridObservations, pair: PairGeometry, params: OmeccParams) -> np.ndarray | None:
    """T_a_b (unit baseline) of a camera pair from its essential matrix; None when the
    decomposition triangulates too little of the agent (a wrong solution)."""
    sfm = IncrementalSfm(obs, [pair.a, pair.b], params.sfm)
    sfm.initialise(pair)
    if len(sfm.points) < params.sfm.min_init_fraction * pair.num_inliers:
        return None
    return sfm.poses[pair.b]


def initial_poses(
    obs: GridObservations, members: list[int], pairs: list[PairGeometry], params: OmeccParams
) -> tuple[int | None, dict[int, np.ndarray], dict[int, str]]:
    """Root camera and T_root_cam (arbitrary scale) of the members reachable over pairs
    with a usable essential matrix: rotations chained along the maximum spanning tree of
    the pairs (weight = inliers), centres by linear translation averaging of every pair's
    baseline direction (each pair's E has its own unknown scale, so the directions are
    averaged, not chained); members left out with a reason."""
    G = nx.Graph()
    G.add_nodes_from(members)
    relative = {}
    for p in pairs:
        if p.a in members and p.b in members and p.F is not None and p.num_inliers >= params.sfm.min_matches:
            T = pair_pose(obs, p, params)
            if T is not None:
                relative[(p.a, p.b)], relative[(p.b, p.a)] = T, inv_se3(T)
                G.add_edge(p.a, p.b, weight=p.num_inliers)
    root, poses = consistent_poses(G, relative, params)
    failed = {
        c: "no usable, consistent essential matrices to two cameras of its group" for c in members if c not in poses
    }
    return root, poses, failed


def consistent_poses(
    G: nx.Graph, relative: dict[tuple[int, int], np.ndarray], params: OmeccParams
) -> tuple[int | None, dict[int, np.ndarray]]:
    """Root and T_root_cam (arbitrary scale) from the pairs of G (edge weight: inliers;
    ``relative[(a, b)]`` = T_a_b with any baseline length). The agent's points lie near
    two planes, where some pairs' E is far off: the pairs that disagree with the rest
    (rotation against the spanning tree's, direction against the averaged centres) are
    dropped, worst first, until every remaining pair agrees."""
    G = G.copy()
    while True:
        root, R, centre, bad = _average(G, relative, params)
        if root is None:
            return None, {}
        if bad is None:
            return root, {c: se3(R[c], centre[c]) for c in centre}
        G.remove_edge(*bad)


def _average(G: nx.Graph, relative: dict, params: OmeccParams):
    """(root, rotations, centres, worst inconsistent pair or None) of the largest part of
    G where every camera has two pairs (one pair leaves its distance along the baseline free)."""
    core = nx.k_core(G, 2) if len(G) > 2 else G
    comps = [c for c in nx.connected_components(core) if len(c) >= 2]
    if not comps:
        return None, {}, {}, None
    core = core.subgraph(max(comps, key=len))
    tree = nx.maximum_spanning_tree(core)
    # Root: the camera with the most inliers to its tree neighbours (the best-anchored).
    root = max(core, key=lambda c: sum(d["weight"] for *_, d in tree.edges(c, data=True)))
    R = {root: np.eye(3)}
    for parent, child in nx.bfs_edges(tree, root):
        R[child] = R[parent] @ relative[(parent, child)][:3, :3]
    rot_err = {(i, j): rotation_angle_deg(R[i].T @ R[j], relative[(i, j)][:3, :3]) for i, j in core.edges}
    worst = max(rot_err, key=rot_err.get)
    if rot_err[worst] > params.max_rotation_disagreement_deg:
        return root, R, {}, worst
    # [d_ij]_x (c_j - c_i) = 0 for every pair, root centre at 0: the null vector of A.
    cams = sorted(c for c in core if c != root)
    col = {c: 3 * i for i, c in enumerate(cams)}
    rows, dirs = [], {}
    for i, j in core.edges:
        d = R[i] @ relative[(i, j)][:3, 3]
        d /= np.linalg.norm(d)
        row = np.zeros((3, 3 * len(cams)))
        for c, sign in ((j, 1.0), (i, -1.0)):
            if c != root:
                row[:, col[c] : col[c] + 3] = sign * skew(d)
        rows.append(row)
        dirs[(i, j)] = d
    x = np.linalg.svd(np.vstack(rows))[2][-1]
    centre = {root: np.zeros(3)} | {c: x[col[c] : col[c] + 3] for c in cams}
    if sum(d @ (centre[j] - centre[i]) for (i, j), d in dirs.items()) < 0:
        centre = {c: -v for c, v in centre.items()}
    dir_err = {
        e: np.degrees(
            np.arccos(
                np.clip(
                    d @ (centre[e[1]] - centre[e[0]]) / max(np.linalg.norm(centre[e[1]] - centre[e[0]]), 1e-12), -1, 1
                )
            )
        )
        for e, d in dirs.items()
    }
    worst = max(dir_err, key=dir_err.get)
    return root, R, centre, worst if dir_err[worst] > params.max_direction_disagreement_deg else None


def calibrate_group(
    obs: GridObservations, members: list[int], pairs: list[PairGeometry], group_id: str, params: OmeccParams
) -> tuple[CameraGroupResult | None, dict[int, str]]:
    root, init, failed = initial_poses(obs, members, pairs, params)
    if root is None:
        return None, failed
    cams = sorted(init)
    index = {c: i for i, c in enumerate(cams)}
    # Agent points seen by at least two calibrated cameras, triangulated with the rough poses.
    views: dict[int, list[int]] = {}
    for c in cams:
        for k in obs.per_camera[c]:
            views.setdefault(k, []).append(c)
    keys, points = [], []
    for k, cs in sorted(views.items()):
        if len(cs) < 2:
            continue
        X_ = triangulate([obs.cameras[c] for c in cs], [init[c] for c in cs], [obs.per_camera[c][k] for c in cs])
        if np.isfinite(X_).all():
            keys.append(k)
            points.append(X_)
    keys = np.array(keys, dtype=np.int64)
    points = np.array(points).reshape(-1, 3)
    kidx = {int(k): i for i, k in enumerate(keys)}
    heads, grounds = head_ground_pairs(keys)
    if len(heads) < params.min_height_pairs:
        return None, {
            c: (
                f"its group's cameras see the agent's head top and ground point together at only "
                f"{len(heads)} instants (needs {params.min_height_pairs} for the height scale)"
            )
            for c in members
        }
    # Metric initialisation: the median head-top to ground distance = the prior height.
    scale = params.person_height_m / np.median(
        np.linalg.norm(points[[kidx[int(h)] for h in heads]] - points[[kidx[int(g)] for g in grounds]], axis=1)
    )
    points *= scale
    for T in init.values():
        T[:3, 3] *= scale
    cam_i, pt_i, uv = [], [], []
    for c in cams:
        for k, p in obs.per_camera[c].items():
            if k in kidx:
                cam_i.append(index[c])
                pt_i.append(kidx[k])
                uv.append(p)
    o = Observations(
        np.array(cam_i, dtype=int),
        np.array(pt_i, dtype=int),
        np.array(uv).reshape(-1, 2),
        np.full(len(cam_i), params.sigma_px),
    )

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for c in cams:
        values.insert(X(index[c]), pose3(init[c]))
    graph.add(
        gtsam.PriorFactorPose3(X(index[root]), pose3(np.eye(4)), gtsam.noiseModel.Isotropic.Sigma(6, FIXED_SIGMA))
    )
    for j, P in enumerate(points):
        values.insert(L(j), gtsam.Point3(*P))
    add_projection_factors(graph, o, [obs.cameras[c] for c in cams], X, L, params.huber_k)
    height = gtsam.noiseModel.Isotropic.Sigma(1, params.person_height_sigma_m)
    for h, g in zip(heads, grounds):
        graph.add(gtsam.RangeFactor3(L(kidx[int(h)]), L(kidx[int(g)]), params.person_height_m, height))
    result, *_ = optimize(graph, values, params.max_iterations)

    T = [result.atPose3(X(i)).matrix() for i in range(len(cams))]
    points = np.array([result.atPoint3(L(j)) for j in range(len(keys))]).reshape(-1, 3)
    res = reprojection_residuals([obs.cameras[c] for c in cams], T, points, o)
    rmse, counts = {}, {}
    for i, c in enumerate(cams):
        r = res[o.camera == i]
        r = r[np.isfinite(r).all(axis=1)]
        rmse[obs.names[c]] = float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")
        counts[obs.names[c]] = int(len(r))
    kp_ids = keys[o.point] % MAX_IDS
    sigma_by_id = {int(i): robust_sigma(res[kp_ids == i]) for i in np.unique(kp_ids) if np.sum(kp_ids == i) >= 10}
    stamps, ids = obs.stamp_and_id(keys)
    neighbour = max(
        (p for p in pairs if root in (p.a, p.b) and (p.b if p.a == root else p.a) in init), key=lambda p: p.num_inliers
    )
    other = neighbour.b if neighbour.a == root else neighbour.a
    names = [obs.names[c] for c in cams]
    return (
        CameraGroupResult(
            group_id=group_id,
            reference=obs.names[root],
            names=names,
            T_local_cam={obs.names[c]: T[index[c]] for c in cams},
            point_stamps_ns=stamps,
            point_ids=ids,
            points=points,
            rmse_px=rmse,
            num_observations=counts,
            sigma_px_by_id=sigma_by_id,
            initial_pair=(obs.names[root], obs.names[other]),
        ),
        failed,
    )


def calibrate_groups_omecc(cams: list[CameraTracks], params: OmeccParams = OmeccParams()) -> GroupingResult:
    """Drop-in for ``group_sfm.calibrate_groups``: the same grouping, each group calibrated
    OMECC-style. Group frames are metric (height prior), with the root camera at identity."""
    obs = sample_on_grid(cams, params.sfm.tracks)
    pairs = [pair_geometry(obs, a, b, params.sfm) for a in range(len(cams)) for b in range(a + 1, len(cams))]
    groups, reasons = group_cameras(obs, pairs, params.sfm)
    results = []
    for members in groups:
        result, failed = calibrate_group(obs, members, pairs, f"g{len(results)}", params)
        reasons.update(failed)
        if result is not None:
            results.append(result)
    return GroupingResult(results, {obs.names[c]: r for c, r in sorted(reasons.items())}, pairs)
