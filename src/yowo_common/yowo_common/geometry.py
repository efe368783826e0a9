"""SE(3) / Sim(3) helpers on plain numpy arrays.

Conventions used across YOWO:
- A pose ``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame ``b`` to
  frame ``a`` (so ``T_world_cam[:3, 3]`` is the camera centre in the world).
- Camera frames are optical frames: x right, y down, z forward.
- Quaternions are (x, y, z, w), as in ROS messages.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def se3(R: np.ndarray, t) -> np.ndarray:
    """4x4 pose from a rotation matrix and a translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def inv_se3(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 pose (exact, no general matrix inverse)."""
    R, t = T[:3, :3], T[:3, 3]
    return se3(R.T, -R.T @ t)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 pose to Nx3 points."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    return points @ T[:3, :3].T + T[:3, 3]


def quat_xyzw_from_rotation(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R).as_quat()


def rotation_from_quat_xyzw(q) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
        raise ValueError(f"quaternion {q.tolist()} is not a rotation")
    return Rotation.from_quat(q).as_matrix()


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of R_a^T R_b in degrees: the paper's eps_rot = arccos((tr(R_a^T R_b) - 1) / 2),
    computed via the rotation vector, which stays accurate for tiny angles."""
    return float(np.degrees(Rotation.from_matrix(R_a.T @ R_b).magnitude()))


def skew(v) -> np.ndarray:
    x, y, z = np.asarray(v, dtype=float).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_aligning(v_from, v_to) -> np.ndarray:
    """Smallest rotation R with R @ v_from parallel to v_to.

    This is the paper's eq. rot_gp2w (Rodrigues form with g = v_from x v_to).
    """
    a = np.asarray(v_from, dtype=float)
    b = np.asarray(v_to, dtype=float)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    g = np.cross(a, b)
    c = float(a @ b)
    gg = float(g @ g)
    if gg < 1e-24:
        if c > 0:
            return np.eye(3)
        # Opposite vectors: rotate by pi about any axis orthogonal to a.
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    G = skew(g)
    return np.eye(3) + G + G @ G * ((1.0 - c) / gg)


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_cam of an optical-frame camera at ``eye`` looking at ``target``.

    The image's "up" (-y) is as close to ``up`` as the viewing direction allows.
    """
    eye = np.asarray(eye, dtype=float)
    z = np.asarray(target, dtype=float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=float))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return se3(np.column_stack([x, y, z]), eye)


@dataclass(frozen=True)
class Sim3:
    """Similarity x -> s * R @ x + t."""

    s: float
    R: np.ndarray
    t: np.ndarray

    @staticmethod
    def identity() -> "Sim3":
        return Sim3(1.0, np.eye(3), np.zeros(3))

    def apply(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=float)
        return self.s * points @ self.R.T + self.t

    def inverse(self) -> "Sim3":
        R_inv = self.R.T
        return Sim3(1.0 / self.s, R_inv, -R_inv @ self.t / self.s)

    def compose(self, other: "Sim3") -> "Sim3":
        """self o other."""
        return Sim3(self.s * other.s, self.R @ other.R, self.s * self.R @ other.t + self.t)

    def transform_pose(self, T_a_cam: np.ndarray) -> np.ndarray:
        """Move a camera pose from frame a to frame b = self(a): rotation R R_c,
        centre s R X + t (paper eqs. reblanced_matching_2/3)."""
        return se3(self.R @ T_a_cam[:3, :3], self.apply(T_a_cam[:3, 3]))

    def matrix(self) -> np.ndarray:
        M = np.eye(4)
        M[:3, :3] = self.s * self.R
        M[:3, 3] = self.t
        return M


def umeyama(src: np.ndarray, dst: np.ndarray, weights=None, with_scale: bool = True) -> Sim3:
    """Weighted Kabsch-Umeyama: argmin sum_i w_i ||dst_i - (s R src_i + t)||^2.

    ``weights`` default to uniform; they are normalised to sum to one (paper eq.
    reblanced_matching). The reflection guard keeps R a proper rotation.
    """
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    if len(src) != len(dst):
        raise ValueError(f"umeyama: {len(src)} source vs {len(dst)} target points")
    if len(src) < 3:
        raise ValueError(f"umeyama: needs >= 3 point pairs, got {len(src)}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if (w < 0).any() or w.sum() <= 0:
        raise ValueError("umeyama: weights must be non-negative with a positive sum")
    w = w / w.sum()
    mu_src = w @ src
    mu_dst = w @ dst
    d_src = src - mu_src
    d_dst = dst - mu_dst
    H = (d_dst * w[:, None]).T @ d_src  # weighted cross-covariance, dst x src
    U, sig, Vt = np.linalg.svd(H)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_src = float(w @ np.sum(d_src**2, axis=1))
    if with_scale:
        if var_src <= 1e-18:
            raise ValueError("umeyama: source points are all at one position; scale undefined")
        s = float(np.sum(sig * np.diag(S)) / var_src)
    else:
        s = 1.0
    return Sim3(s, R, mu_dst - s * R @ mu_src)
