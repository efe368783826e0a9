import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import Sim3, look_at, se3
from yowo_common.trajectory import Trajectory, read_tum, write_tum
from yowo_eval.metrics import (
    ErrorSummary,
    PoseError,
    ate,
    layout_iou,
    mean_baseline_m,
    registration_errors,
    relative_errors_of_baseline,
    relative_pose_errors,
)


def rig(n=4):
    return {f"c{i}": look_at([2.0 * i, (i % 2) * 3.0, 3.0], [2.0 * i + 1, 1.5, 0.0]) for i in range(n)}


def test_registration_errors_known_perturbation():
    gt = rig()
    est = {n: T.copy() for n, T in gt.items()}
    est["c1"][:3, 3] += [0.03, 0.04, 0.0]  # 5 cm
    est["c2"] = se3(Rotation.from_rotvec([0, 0, np.radians(0.5)]).as_matrix() @ gt["c2"][:3, :3], gt["c2"][:3, 3])
    errs = {e.name: e for e in registration_errors(est, gt)}
    assert errs["c1"].eps_pos_m == pytest.approx(0.05)
    assert errs["c2"].eps_rot_deg == pytest.approx(0.5)
    assert errs["c0"].eps_pos_m == 0 and errs["c0"].eps_rot_deg == pytest.approx(0, abs=1e-6)
    s = ErrorSummary.of(list(errs.values()))
    assert (s.count, s.pos_max, s.pos_avg) == (4, pytest.approx(0.05), pytest.approx(0.0125))


@pytest.mark.parametrize("n", [2, 4])
def test_relative_errors_ignore_a_similarity(n):
    gt = rig(n)
    S = Sim3(0.37, Rotation.random(random_state=1).as_matrix(), np.array([5.0, -1.0, 2.0]))
    est = {k: S.transform_pose(T) for k, T in gt.items()}
    errs, align = relative_pose_errors(est, gt, {"g0": list(gt)})
    assert max(e.eps_pos_m for e in errs) < 1e-9
    assert max(e.eps_rot_deg for e in errs) < 1e-5
    assert align["g0"].s == pytest.approx(1 / 0.37)
    if n == 2:
        return
    # A real relative error survives the alignment.
    est["c1"][:3, 3] += S.s * np.array([0.0, 0.0, 0.1])
    errs, _ = relative_pose_errors(est, gt, {"g0": list(gt)})
    assert max(e.eps_pos_m for e in errs) > 0.02


def make_traj(n=200, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 20, n)
    pos = np.column_stack([np.cos(t / 3) * 3, np.sin(t / 2) * 2, 1.6 + 0.05 * np.sin(t * 4)])
    rots = Rotation.from_euler("zyx", np.column_stack([t / 3, 0.1 * np.sin(t), 0.05 * rng.normal(size=n)]))
    T = np.array([se3(R, p) for R, p in zip(rots.as_matrix(), pos)])
    return Trajectory((1_700_000_000 * 10**9 + (t * 1e9).astype(np.int64)), T)


def test_relative_errors_as_percent_of_each_groups_mean_baseline():
    gt = {
        "a": se3(np.eye(3), [0, 0, 0]),
        "b": se3(np.eye(3), [3, 0, 0]),
        "c": se3(np.eye(3), [0, 4, 0]),
        "d": se3(np.eye(3), [10, 0, 0]),
        "e": se3(np.eye(3), [10, 1, 0]),
    }
    assert mean_baseline_m([gt[n] for n in "abc"]) == pytest.approx(4.0)  # (3 + 4 + 5) / 3
    errs = [PoseError("a", 0.04, 1.0), PoseError("c", 0.08, 2.0), PoseError("e", 0.05, 0.5)]
    pct = {e.name: e for e in relative_errors_of_baseline(errs, gt, {"g0": ["a", "b", "c"], "g1": ["d", "e"]})}
    assert pct["a"].eps_pos_m == pytest.approx(1.0) and pct["c"].eps_pos_m == pytest.approx(2.0)
    assert pct["e"].eps_pos_m == pytest.approx(5.0) and pct["c"].eps_rot_deg == 2.0


def test_ate_zero_under_rigid_motion_and_known_offset(tmp_path):
    ref = make_traj()
    G = se3(Rotation.from_euler("z", 40, degrees=True).as_matrix(), [1, 2, 3])
    moved = Trajectory(ref.stamps_ns, np.array([G @ T for T in ref.T_world_cam]))
    assert ate(moved, ref).rmse_m < 1e-9
    shifted = Trajectory(ref.stamps_ns, ref.T_world_cam.copy())
    shifted.T_world_cam[::2, 2, 3] += 0.1  # +-5 cm about the best fit
    assert ate(shifted, ref).rmse_m == pytest.approx(0.05, abs=1e-6)
    with pytest.raises(ValueError, match="ground-truth stamp"):
        ate(Trajectory(ref.stamps_ns + 50_000_000, ref.T_world_cam), ref, max_diff_s=0.01)


def test_tum_roundtrip(tmp_path):
    ref = make_traj(20)
    write_tum(tmp_path / "t.tum", ref)
    back = read_tum(tmp_path / "t.tum")
    np.testing.assert_array_equal(back.stamps_ns, ref.stamps_ns)
    np.testing.assert_allclose(back.T_world_cam, ref.T_world_cam, atol=1e-8)


def test_ate_agrees_with_evo(tmp_path):
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref = make_traj(300, seed=1)
    rng = np.random.default_rng(2)
    G = se3(Rotation.from_euler("xyz", [3, -2, 50], degrees=True).as_matrix(), [0.5, -1, 0.2])
    est_T = np.array([G @ T for T in ref.T_world_cam])
    est_T[:, :3, 3] += rng.normal(scale=0.03, size=(300, 3))
    est = Trajectory(ref.stamps_ns[5:-7] + 3_000_000, est_T[5:-7])  # partial overlap, 3 ms offset
    write_tum(tmp_path / "ref.tum", ref)
    write_tum(tmp_path / "est.tum", est)
    traj_ref = file_interface.read_tum_trajectory_file(str(tmp_path / "ref.tum"))
    traj_est = file_interface.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    traj_ref, traj_est = sync.associate_trajectories(traj_ref, traj_est, max_diff=0.01)
    traj_est.align(traj_ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((traj_ref, traj_est))
    ours = ate(read_tum(tmp_path / "est.tum"), read_tum(tmp_path / "ref.tum"))
    assert ours.matched == len(traj_est.positions_xyz)
    assert ours.rmse_m == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), abs=1e-6)


def test_layout_iou():
    square = np.array([[0, 0], [4, 0], [4, 4], [0, 4]], float)
    assert layout_iou([square], [square]) == pytest.approx(1.0)
    assert layout_iou([square + [2, 0]], [square]) == pytest.approx(8 / 24)
    two = [square, square + [4, 0]]
    assert layout_iou([np.array([[0, 0], [8, 0], [8, 4], [0, 4]], float)], two) == pytest.approx(1.0)
    assert layout_iou([], [square]) == 0.0


def test_map_frame_from_first_pose():
    from yowo_common.geometry import look_at
    from yowo_eval.metrics import map_frame_from_first_pose

    first = look_at([3.0, 4.0, 1.6], [5.0, 4.0, 0.5])  # looking along +x, down
    T = map_frame_from_first_pose(first)
    moved = T @ first
    np.testing.assert_allclose(moved[:3, 3], [0, 0, 1.6], atol=1e-12)
    assert moved[1, 2] == pytest.approx(0.0, abs=1e-12) and moved[0, 2] > 0  # optical axis in the x-z plane
    turned = look_at([3.0, 4.0, 1.6], [3.0, 6.0, 0.5])  # looking along +y
    np.testing.assert_allclose((map_frame_from_first_pose(turned) @ turned)[:3, 3], [0, 0, 1.6], atol=1e-12)
