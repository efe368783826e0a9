"""Degeneracy of the dense odometry's terms: a bare plane leaves the motion along it
unobserved (depth has no gradient along it, intensity none at all), a textured plane
observes it; the remapped pose keeps the observed part and takes the prediction's
along the rest."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import se3
from yowo_ego.degeneracy import DegeneracyParams, degenerate_directions, motion_information, remap_degenerate
from yowo_ego.rgbd_odometry import scaled_K

K = scaled_K(np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]]), 2)
H, W = 240, 320


def _wall(textured: bool):
    """A fronto-parallel wall 2 m ahead (depth mm), bare or with a random texture."""
    depth = np.full((H, W), 2000, np.uint16)
    rng = np.random.default_rng(0)
    if textured:
        noise = rng.integers(0, 255, (H // 4, W // 4), dtype=np.uint8)
        gray = np.kron(noise, np.ones((4, 4), np.uint8))
    else:
        gray = np.full((H, W), 128, np.uint8)
    return np.dstack([gray] * 3), depth


def test_bare_wall_leaves_three_directions_unobserved():
    """One plane: depth fixes the distance and the two tilts; a bare wall nothing else
    (sliding along it in x, y and turning about its normal)."""
    color, depth = _wall(False)
    info = motion_information(color, depth, color, depth, K, np.eye(4))
    D = degenerate_directions(info)
    assert D.shape[1] == 3
    # The unobserved subspace: translation x, y and rotation about z (scaled tangent order).
    basis = np.zeros((6, 3))
    basis[2, 0] = basis[3, 1] = basis[4, 2] = 1.0
    assert np.linalg.svd(basis.T @ D, compute_uv=False).min() > 0.99
    color, depth = _wall(True)
    assert degenerate_directions(motion_information(color, depth, color, depth, K, np.eye(4))).shape[1] == 0


def test_remap_takes_the_prediction_along_the_wall_only():
    color, depth = _wall(False)
    info = motion_information(color, depth, color, depth, K, np.eye(4))
    T_est = se3(Rotation.from_rotvec([0.01, 0.0, 0.02]).as_matrix(), [0.10, -0.05, 0.02])  # slid along the wall
    T_pred = se3(np.eye(3), [0.03, 0.0, 0.0])
    T, k = remap_degenerate(T_est, T_pred, info)
    assert k == 3
    # Along the wall (x, y, yaw about z) the prediction's, across it (z, tilts) the estimate's.
    assert T[:3, 3] == pytest.approx([0.03, 0.0, 0.02], abs=2e-3)
    rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    assert rotvec[2] == pytest.approx(0.0, abs=1e-3) and rotvec[0] == pytest.approx(0.01, abs=1e-3)
    # A textured wall observes everything: the estimate stands; a bound no image meets takes the prediction alone.
    color, depth = _wall(True)
    textured = motion_information(color, depth, color, depth, K, np.eye(4))
    T2, k2 = remap_degenerate(T_est, T_pred, textured)
    assert k2 == 0 and np.array_equal(T2, T_est)
    assert remap_degenerate(T_est, T_pred, textured, DegeneracyParams(max_sigma_m=1e-9))[1] == 6
