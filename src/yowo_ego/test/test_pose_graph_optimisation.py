"""The global pose-graph optimisation (``posegraph.optimize``, GTSAM) on synthesised
graphs with a known answer: it is Open3D's ``global_optimization`` (same poses, same
loops pruned) without the dense system, it removes the odometry's drift, drops a
wrong loop closure, and leaves a part of the graph without edges to keyframe 0
where it is."""

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import inv_se3, rotation_angle_deg, se3
from yowo_ego.odometry import Keyframe, OdometryEdge
from yowo_ego.posegraph import LoopParams, optimize

reg = o3d.pipelines.registration


def _information(rng, n_points: int = 3000) -> np.ndarray:
    """What Open3D's point-to-point information matrix holds (rotation first): the sum of
    [-[p]x | I]^T [-[p]x | I] over the points a keyframe pair shares."""
    info = np.zeros((6, 6))
    for p in rng.uniform([-2, -1.5, 0.5], [2, 1.5, 4.0], size=(n_points, 3)):
        J = np.hstack([-np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]]), np.eye(3)])
        info += J.T @ J
    return info


def _perturb(T: np.ndarray, rng, sigma_m: float, sigma_deg: float) -> np.ndarray:
    noise = se3(Rotation.from_rotvec(np.deg2rad(rng.normal(0, sigma_deg, 3))).as_matrix(), rng.normal(0, sigma_m, 3))
    return T @ noise


def _ring(rng, n: int = 60):
    """Keyframes on a 3 m circle looking along it; noisy odometry, two loop closures
    where the walk returns and one wrong one (0.6 m and 20 deg off)."""
    truth = []
    for k in range(n):
        a = 2 * np.pi * k / n
        R = Rotation.from_euler("y", -a).as_matrix()
        truth.append(se3(R, [3 * np.cos(a), 0.0, 3 * np.sin(a)]))
    info = _information(rng)

    def edge(s, t, kind, sigma_m, sigma_deg):
        T = _perturb(inv_se3(truth[t]) @ truth[s], rng, sigma_m, sigma_deg)
        return OdometryEdge(source=s, target=t, T_target_source=T, information=info, kind=kind)

    edges = [edge(k, k - 1, "odometry", 0.01, 0.3) for k in range(1, n)]
    edges += [edge(n - 1, 0, "loop", 0.002, 0.05), edge(n - 2, 1, "loop", 0.002, 0.05)]
    T_wrong = _perturb(inv_se3(truth[5]) @ truth[n // 2], rng, 0.6, 20.0)
    wrong = OdometryEdge(source=n // 2, target=5, T_target_source=T_wrong, information=info, kind="loop")
    edges.append(wrong)
    # Nodes start on the odometry chain, as the ego stage starts them.
    chain = [truth[0]]
    for e in edges[: n - 1]:
        chain.append(chain[-1] @ e.T_target_source)
    return truth, chain, edges


def _keyframes(T_odom_cam):
    return [Keyframe(i, i, i, T, None, None, 0) for i, T in enumerate(T_odom_cam)]


def _open3d(T_init, edges, params: LoopParams):
    graph = reg.PoseGraph()
    for T in T_init:
        graph.nodes.append(reg.PoseGraphNode(T))
    for e in edges:
        graph.edges.append(
            reg.PoseGraphEdge(e.source, e.target, e.T_target_source, e.information, uncertain=e.kind == "loop")
        )
    option = reg.GlobalOptimizationOption(
        max_correspondence_distance=params.max_correspondence_distance_m,
        edge_prune_threshold=params.edge_prune_threshold,
        preference_loop_closure=params.preference_loop_closure,
        reference_node=0,
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(
            graph, reg.GlobalOptimizationLevenbergMarquardt(), reg.GlobalOptimizationConvergenceCriteria(), option
        )
    return [np.asarray(n.pose) for n in graph.nodes], {(g.source_node_id, g.target_node_id) for g in graph.edges}


def _errors(T, truth):
    return (
        max(np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(T, truth)),
        max(rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(T, truth)),
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_the_ring_closes_like_open3d_and_the_wrong_loop_is_pruned(seed):
    rng = np.random.default_rng(seed)
    truth, chain, edges = _ring(rng)
    params = LoopParams()
    T, kept = optimize(_keyframes(chain), edges, params)
    kept_pairs = {(e.source, e.target) for e in kept}
    wrong = edges[-1]
    assert (wrong.source, wrong.target) not in kept_pairs
    assert len(kept) == len(edges) - 1
    np.testing.assert_allclose(T[0], chain[0], atol=1e-9)  # keyframe 0 is the reference
    # The walk closes: its last keyframe is where the loops put it, not where the odometry drifted.
    n = len(truth)
    closure = [_errors([inv_se3(T_[0]) @ T_[n - 1]], [inv_se3(truth[0]) @ truth[n - 1]]) for T_ in (chain, T)]
    assert closure[0][0] > 0.1 and closure[1][0] < 0.1 * closure[0][0] and closure[1][1] < 0.1 * closure[0][1], closure
    # In between, the drift is spread along the ring (a bridge: about half of it remains).
    drift_m, drift_deg = _errors(chain, truth)
    err_m, err_deg = _errors(T, truth)
    assert err_m < 0.75 * drift_m and err_deg < 0.75 * drift_deg, (drift_m, err_m, drift_deg, err_deg)
    T_o3d, kept_o3d = _open3d(chain, edges, params)
    assert kept_pairs == kept_o3d
    dp, dr = _errors(T, T_o3d)
    assert dp < 1e-3 and dr < 0.02, (dp, dr)


def test_a_part_without_edges_to_keyframe_0_stays_where_it_is():
    rng = np.random.default_rng(2)
    truth, chain, edges = _ring(rng, 20)
    # Keyframes 10-19 lose their link to 0-9 (and the loops): two separate chains.
    edges = [e for e in edges if e.kind == "odometry" and (e.source, e.target) != (10, 9)]
    moved = [T @ se3(np.eye(3), [0.5, 0, 0]) if i >= 10 else T for i, T in enumerate(chain)]
    T, kept = optimize(_keyframes(moved), edges, LoopParams())
    assert len(kept) == len(edges)
    for i in (0, 10):
        np.testing.assert_allclose(T[i], moved[i], atol=1e-9)
    # Within each part the (only) odometry edges hold exactly.
    for e in edges:
        np.testing.assert_allclose(inv_se3(T[e.target]) @ T[e.source], e.T_target_source, atol=1e-6)
