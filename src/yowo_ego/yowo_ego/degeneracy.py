"""How much a dense RGB-D odometry result is constrained, direction by direction, and
what to do where it is not (degeneracy-aware tracking).

``motion_information`` is the Gauss-Newton information of the two terms Open3D's
hybrid odometry minimises, at the result: point-to-plane (depth) and photometric
(intensity), each whitened by its noise. Its eigenvectors with little information
are the directions the images cannot see: sliding along one wall or down a corridor
(depth), motion in front of a bare wall or in the dark (intensity). The optimiser
still returns some value along them, drifting by centimetres per frame (small
texture_poor: 5-19 cm per frame along bare walls with fitness and RMSE that pass
every check). ``remap_degenerate`` keeps the result where the information is and
takes the motion prediction (constant velocity, with the gyro when recorded) along
the unobserved directions: the solution remapping of Zhang, Kaess & Singh, "On
degeneracy of optimization-based state estimation problems" (ICRA 2016).

Perturbations are on the left, in the target (keyframe) frame: T' = exp(d) T, with
d = (rotation, translation) as Open3D's and GTSAM's tangent order; rotations are
compared with translations at ``length_m`` (1 rad ~ length_m metres)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import gtsam
import numpy as np


@dataclass(frozen=True)
class DegeneracyParams:
    enabled: bool = True  # remap accepted results along the directions their images do not constrain
    depth_sigma_m: float = 0.005  # noise of the point-to-plane residual (sensor noise plus normal errors)
    # Noise of a grey level in [0, 1] (sensor noise, shading between views) [grey level].
    intensity_sigma: float = 0.02
    correspondence_m: float = 0.07  # depth difference beyond which a pixel has no correspondence
    stride: int = 4  # every stride-th pixel (each way) of the odometry images enters the information [px]
    length_m: float = 1.0  # the length a radian of rotation counts as against translation
    # Sigma per tracked step above which a direction is degenerate. A step is ~7 cm of walking.
    # The pixels' errors are taken as independent, so the sigmas are optimistic: rooms, bare-walled
    # ones too, stay well below it in every direction; one bare plane leaves three directions free.
    max_sigma_m: float = 0.003


def depth_points(depth_mm: np.ndarray, K: np.ndarray, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (h, w, 3) camera frame, valid (h, w)) of every stride-th pixel."""
    z = depth_mm[::stride, ::stride].astype(float) / 1000.0
    v, u = np.mgrid[0 : depth_mm.shape[0] : stride, 0 : depth_mm.shape[1] : stride].astype(float)
    P = np.dstack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    return P, z > 0


def _gray(color: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(color, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0


def motion_information(
    source_color: np.ndarray,
    source_depth_mm: np.ndarray,
    target_color: np.ndarray,
    target_depth_mm: np.ndarray,
    K: np.ndarray,
    T_target_source: np.ndarray,
    params: DegeneracyParams = DegeneracyParams(),
) -> np.ndarray:
    """6x6 information (rotation scaled by ``length_m``, then translation) of the
    depth and intensity terms at T_target_source, odometry-resolution images with
    intrinsics K."""
    s = params.stride
    Ps, valid_s = depth_points(source_depth_mm, K, s)
    Ps = Ps[valid_s]
    P = Ps @ T_target_source[:3, :3].T + T_target_source[:3, 3]
    h, w = target_depth_mm.shape
    front = P[:, 2] > 1e-3
    P = P[front]
    u = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2]
    v = K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]
    ui, vi = np.round(u).astype(int), np.round(v).astype(int)
    inside = (ui >= 1) & (ui < w - 1) & (vi >= 1) & (vi < h - 1)
    P, u, v, ui, vi = P[inside], u[inside], v[inside], ui[inside], vi[inside]
    zt = target_depth_mm.astype(float) / 1000.0
    z = zt[vi, ui]
    ok = (z > 0) & (np.abs(z - P[:, 2]) < params.correspondence_m)
    P, u, v, ui, vi = P[ok], u[ok], v[ok], ui[ok], vi[ok]
    if len(P) < 6:
        return np.zeros((6, 6))

    # Target normals from the neighbouring pixels' points.
    def at(du, dv):
        zz = zt[vi + dv, ui + du]
        return np.column_stack([(ui + du - K[0, 2]) / K[0, 0] * zz, (vi + dv - K[1, 2]) / K[1, 1] * zz, zz])

    right, left, down, up = at(1, 0), at(-1, 0), at(0, 1), at(0, -1)
    n = np.cross(right - left, down - up)
    norm = np.linalg.norm(n, axis=1)
    has_n = (right[:, 2] > 0) & (left[:, 2] > 0) & (down[:, 2] > 0) & (up[:, 2] > 0) & (norm > 1e-12)
    n = n[has_n] / norm[has_n, None]
    Pn = P[has_n]
    J_depth = np.hstack([np.cross(Pn, n) / params.length_m, n]) / params.depth_sigma_m
    # Intensity: target gradient (per pixel) through the projection's Jacobian.
    gray = _gray(target_color)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)[vi, ui] / 8.0
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)[vi, ui] / 8.0
    x, y, zz = P[:, 0], P[:, 1], P[:, 2]
    # d(intensity)/dP = g_u * du/dP + g_v * dv/dP
    dI = np.column_stack([gx * K[0, 0] / zz, gy * K[1, 1] / zz, -(gx * K[0, 0] * x + gy * K[1, 1] * y) / zz**2])
    # dP/d(rotation) = -[P]x : dI . (w x P) = w . (P x dI)
    J_int = np.hstack([np.cross(P, dI) / params.length_m, dI]) / params.intensity_sigma
    return J_depth.T @ J_depth + J_int.T @ J_int


def degenerate_directions(information: np.ndarray, params: DegeneracyParams = DegeneracyParams()) -> np.ndarray:
    """(6, k) orthonormal directions (scaled tangent) with less information than
    ``max_sigma_m`` allows."""
    values, vectors = np.linalg.eigh(information)
    return vectors[:, values < params.max_sigma_m**-2]


def remap_degenerate(
    T_est: np.ndarray, T_pred: np.ndarray, information: np.ndarray, params: DegeneracyParams = DegeneracyParams()
) -> tuple[np.ndarray, int]:
    """T_est with its component along the degenerate directions replaced by the
    prediction's; (pose, number of degenerate directions)."""
    D = degenerate_directions(information, params)
    if D.shape[1] == 0:
        return T_est, 0
    scale = np.array([params.length_m] * 3 + [1.0] * 3)
    delta = gtsam.Pose3.Logmap(gtsam.Pose3(T_pred) * gtsam.Pose3(T_est).inverse()) * scale
    step = (D @ (D.T @ delta)) / scale
    return (gtsam.Pose3.Expmap(step) * gtsam.Pose3(T_est)).matrix(), D.shape[1]
