import itertools
from dataclasses import replace

import networkx as nx
import numpy as np
from scipy.spatial.transform import Rotation
from test_group_sfm import three_camera_rig

from cmc_synthetic import HEIGHT, ceiling_camera, loop_walk, observe
from yowo_cmc.group_sfm import SfmParams
from yowo_cmc.keypoint_tracks import TrackParams
from yowo_common.geometry import inv_se3
from yowo_eval.metrics import relative_pose_errors
from yowo_eval.omecc_style import OmeccParams, calibrate_groups_omecc, consistent_poses

EXACT = OmeccParams(sfm=SfmParams(tracks=TrackParams(window_s=0.0, gate_px=1e9)))


def relative_errors(group, cams):
    gt = {n: cams[n][1] for n in group.T_local_cam}
    errs, align = relative_pose_errors(group.T_local_cam, gt, {"g": list(gt)})
    return max(e.eps_pos_m for e in errs), max(e.eps_rot_deg for e in errs), align["g"].s


def test_noise_free_rig_exact_up_to_scale_and_metric_from_height():
    cams = three_camera_rig()
    tracks = observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 20.0)
    result = calibrate_groups_omecc(tracks, replace(EXACT, person_height_m=HEIGHT))
    assert result.ungrouped == {}
    (group,) = result.groups
    assert sorted(group.names) == ["a", "b", "c"]
    assert group.T_local_cam[group.reference] is not None
    pos, rot, scale = relative_errors(group, cams)
    assert pos < 1e-4 and rot < 1e-3
    assert abs(scale - 1.0) < 1e-3  # the right height gives the right metric scale
    assert max(group.rmse_px.values()) < 1e-3


def test_scale_follows_the_height_prior():
    """The method knows an average height (1.70 m), the agent is 1.75 m: the map comes
    out 1.70 / 1.75 the true size, which is the only source of scale."""
    cams = three_camera_rig()
    tracks = observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 20.0)
    (group,) = calibrate_groups_omecc(tracks, EXACT).groups
    pos, rot, scale = relative_errors(group, cams)
    assert pos < 1e-4 and rot < 1e-3
    assert abs(1.0 / scale - 1.70 / HEIGHT) < 2e-3


def test_noisy_distorted_unequal_rates():
    cams = three_camera_rig(D=[-0.2, 0.04, 0, 0, 0])
    tracks = observe(
        cams,
        loop_walk((3.0, 2.5), (2.0, 1.5)),
        40.0,
        rate_hz={"a": 10.0, "b": 15.0, "c": 7.5},
        offsets_s=[0.0, 0.031, 0.057],
        sigma_px=1.0,
        seed=3,
    )
    (group,) = calibrate_groups_omecc(tracks, OmeccParams(person_height_m=HEIGHT)).groups
    pos, rot, scale = relative_errors(group, cams)
    assert pos < 0.01 and rot < 0.2
    assert abs(scale - 1.0) < 0.01
    assert max(group.rmse_px.values()) < 2.0


def test_isolated_camera_reported():
    cams = three_camera_rig()
    cams["blind"] = ceiling_camera(30.0, 30.0, (35.0, 35.0))
    result = calibrate_groups_omecc(observe(cams, loop_walk((3.0, 2.5), (2.0, 1.5)), 20.0, sigma_px=0.5))
    assert sorted(result.groups[0].names) == ["a", "b", "c"]
    assert result.ungrouped["blind"].startswith("seen in 0 frames")


def test_inconsistent_pairs_are_dropped_from_the_initialisation():
    """Four cameras, every pair's relative pose exact (baselines of arbitrary length)
    except a weak pair with a 40 deg rotation error and one with a 70 deg wrong baseline
    direction: both are dropped and the rest gives the rig exactly up to scale."""
    rig = three_camera_rig()
    rig["d"] = ceiling_camera(5.5, 4.6, (2.5, 2.0), z=3.1)
    T = [rig[n][1] for n in sorted(rig)]
    G, relative = nx.Graph(), {}
    rng = np.random.default_rng(0)
    for a, b in itertools.combinations(range(4), 2):
        rel = inv_se3(T[a]) @ T[b]
        rel[:3, 3] *= rng.uniform(0.2, 5.0)
        G.add_edge(a, b, weight=100)
        relative[(a, b)] = rel
    relative[(0, 3)][:3, :3] = relative[(0, 3)][:3, :3] @ Rotation.from_rotvec([0.0, np.radians(40), 0.0]).as_matrix()
    relative[(1, 2)][:3, 3] = Rotation.from_rotvec([np.radians(70), 0.0, 0.0]).as_matrix() @ relative[(1, 2)][:3, 3]
    G[0][3]["weight"] = G[1][2]["weight"] = 10
    for (a, b), rel in list(relative.items()):
        relative[(b, a)] = inv_se3(rel)
    root, poses = consistent_poses(G, relative, OmeccParams())
    assert sorted(poses) == [0, 1, 2, 3]
    est = {str(c): T for c, T in poses.items()}
    errs, _ = relative_pose_errors(est, {str(c): T[c] for c in poses}, {"g": list(est)})
    assert max(e.eps_pos_m for e in errs) < 1e-9 and max(e.eps_rot_deg for e in errs) < 1e-7
