import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import Sim3
from yowo_fusion.alignment import AlignParams, align_group, rebalanced_weights, spatiotemporal_clusters

S_TRUE = Sim3(2.3, Rotation.from_euler("xyz", [10, -5, 70], degrees=True).as_matrix(), np.array([4.0, -2.0, 1.6]))


def walk_with_stop(stop_s=60.0, walk_s=20.0, rate=15.0):
    """World head positions: a stop at one spot, then a walk (stamps in ns)."""
    t = np.arange(0, stop_s + walk_s, 1 / rate)
    xy = np.where(
        (t < stop_s)[:, None],
        [[1.0, 1.0]],
        np.column_stack([1 + 3 * np.sin((t - stop_s) / 4), 1 + 2 * (1 - np.cos((t - stop_s) / 3))]),
    )
    return (t * 1e9).astype(np.int64), np.column_stack([xy, np.full(len(t), 1.7)])


def test_weighted_umeyama_recovers_known_sim3_exactly():
    stamps, world = walk_with_stop()
    local = S_TRUE.inverse().apply(world)
    al = align_group(stamps, local, stamps, world)
    assert al.sim3_world_local.s == pytest.approx(S_TRUE.s, rel=1e-10)
    np.testing.assert_allclose(al.sim3_world_local.R, S_TRUE.R, atol=1e-10)
    np.testing.assert_allclose(al.sim3_world_local.t, S_TRUE.t, atol=1e-9)
    assert al.weights.sum() == pytest.approx(1.0)


def test_clusters_and_weights():
    stamps, world = walk_with_stop(stop_s=10, walk_s=10)
    labels = spatiotemporal_clusters(world, stamps, AlignParams())
    stop = stamps < 10e9
    assert len(np.unique(labels[stop])) == 1  # the stop is one cluster
    assert len(np.unique(labels[~stop])) > 5  # the walk splits into many
    w = rebalanced_weights(labels)
    assert w[labels == labels[0]].sum() == pytest.approx(1 / len(np.unique(labels)))
    # Revisiting a place much later is a different cluster (temporal condition).
    same_place = np.array([[0, 0, 0]] * 4, float)
    t = np.array([0, 0.5, 100, 100.5]) * 1e9
    assert len(np.unique(spatiotemporal_clusters(same_place, t.astype(np.int64), AlignParams()))) == 2


def test_long_stationary_segment_biases_plain_ku_but_not_rebalanced():
    stamps, world = walk_with_stop(stop_s=120.0, walk_s=15.0)
    rng = np.random.default_rng(0)
    local = S_TRUE.inverse().apply(world)
    stop = stamps < 120e9
    # While standing, the looking-around head puts the ego camera ~12 cm off the head top, in one direction.
    world_obs = world + rng.normal(scale=0.01, size=world.shape)
    world_obs[stop] += [0.12, 0.0, -0.05]
    test_points = S_TRUE.inverse().apply(np.array([[0, 0, 3.0], [6, 4, 3.0], [6, 0, 2.5]]))  # e.g. CMC centres
    truth = S_TRUE.apply(test_points)
    err = {}
    for rebalance in (False, True):
        al = align_group(stamps, local, stamps, world_obs, AlignParams(rebalance=rebalance))
        err[rebalance] = np.abs(al.sim3_world_local.apply(test_points) - truth).max()
    assert err[False] > 0.08  # plain KU is dragged by the stop
    assert err[True] < 0.5 * err[False]  # the rebalanced version is not


def test_too_few_overlapping_stamps_is_an_error():
    stamps, world = walk_with_stop(stop_s=1, walk_s=1)
    with pytest.raises(ValueError, match="needs at least 3"):
        align_group(stamps + 10**12, world, stamps, world)


def test_ground_points_fix_the_roll_of_a_straight_walk():
    """Head tops along a straight line leave the roll about that line free: 5 mm of
    noise tilts the head-only fit by degrees; with the ground points matched to the
    floor under the ego positions the rotation is recovered to a fraction of a degree."""
    rng = np.random.default_rng(3)
    stamps = np.arange(150) * 66_666_667
    heads = np.column_stack([np.linspace(0, 4, 150), np.full(150, 1.0), np.full(150, 1.75)])
    grounds = heads * [1, 1, 0]
    S = Sim3(0.5, Rotation.from_rotvec([0.2, -0.1, 0.7]).as_matrix(), np.array([1.0, -2.0, 0.3]))
    inv = S.inverse()
    local_heads = inv.apply(heads + rng.normal(0, 0.005, heads.shape))
    local_grounds = inv.apply(grounds + rng.normal(0, 0.005, grounds.shape))

    def roll_error(fit):
        return np.degrees(Rotation.from_matrix(fit.sim3_world_local.R @ S.R.T).magnitude())

    head_only = align_group(stamps, local_heads, stamps, heads)
    both = align_group(stamps, local_heads, stamps, heads, AlignParams(), stamps, local_grounds)
    assert roll_error(both) < 0.3 < 2.0 < roll_error(head_only)
    assert abs(both.sim3_world_local.s - S.s) < 0.01 * S.s
