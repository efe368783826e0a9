"""Above `loops.max_optimised_keyframes` the ego stage does not run Open3D's global
optimisation (its dense 6N x 6N system took a 25-minute floor's walk to 22 GB): the
keyframes keep their checked odometry poses, loop edges are left out, a warning says so,
and the map is still made (the bundle adjustment refines it)."""
from dataclasses import replace

import numpy as np

from yowo_common.trajectory import Trajectory
from yowo_ego.pipeline import EgoParams
from yowo_ego.recording import map_bag
from yowo_eval.evaluation import ate
from yowo_eval.ground_truth import read_ground_truth


def test_too_many_keyframes_for_the_dense_pose_graph_give_a_warned_unoptimised_map(tiny_bag):
    defaults = EgoParams()
    full, _ = map_bag(tiny_bag, defaults)
    assert full.stats["pose_graph_optimised"] == 1 and not any("not optimised" in w for w in full.warnings)
    limited = replace(defaults, loops=replace(defaults.loops, max_optimised_keyframes=5))
    r, _ = map_bag(tiny_bag, limited)
    n = int(r.stats["keyframes"])
    assert n > 5 and r.stats["pose_graph_optimised"] == 0 and r.stats["loops_kept"] == 0
    (warning,) = [w for w in r.warnings if "not optimised" in w]
    assert f"{n} keyframes" in warning and "ego.loops.max_optimised_keyframes = 5" in warning
    # The multiway poses are the chain of checked edges (none corrected on this walk: the
    # odometry itself), and the map still fits.
    np.testing.assert_allclose(r.trajectories["multiway"], r.trajectories["odometry"], atol=1e-9)
    gt = read_ground_truth(tiny_bag).ego
    err = [ate(Trajectory(m.stamps_ns, m.T_world_cam), gt).rmse_m for m in (full, r)]
    assert err[1] < 2.0 * err[0] + 0.01, err
