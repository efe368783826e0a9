"""Pinhole camera model with the distortion models of sensor_msgs/CameraInfo."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .geometry import inv_se3, transform_points

# CameraInfo distortion_model names (sensor_msgs/distortion_models.hpp).
PLUMB_BOB = "plumb_bob"
RATIONAL_POLYNOMIAL = "rational_polynomial"
EQUIDISTANT = "equidistant"
# Coefficient counts OpenCV's models take for each (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]).
DISTORTION_LENGTHS = {PLUMB_BOB: (4, 5), RATIONAL_POLYNOMIAL: (8, 12, 14), EQUIDISTANT: (4,)}
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass
class CameraModel:
    """Intrinsics of one camera. ``K`` is 3x3, ``D`` the distortion coefficients
    in OpenCV order for ``distortion_model`` (empty or all-zero: no distortion).
    ``R`` (3x3) and ``P`` (3x4) are CameraInfo's rectification and projection, kept so
    that exports give a camera's CameraInfo back as it came (None: identity, [K | 0]);
    no geometry here uses them."""

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray = field(default_factory=lambda: np.zeros(5))
    distortion_model: str = PLUMB_BOB
    R: np.ndarray | None = None
    P: np.ndarray | None = None

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=float).reshape(3, 3)
        self.D = np.asarray(self.D, dtype=float).reshape(-1)
        if self.R is None:
            self.R = np.eye(3)
        if self.P is None:
            self.P = np.column_stack([self.K, np.zeros(3)])
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        self.P = np.asarray(self.P, dtype=float).reshape(3, 4)

    @staticmethod
    def from_fov(width: int, height: int, hfov_deg: float) -> "CameraModel":
        """Square-pixel camera with the principal point at the image centre."""
        f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        return CameraModel(width, height, K)

    def problems(self) -> list[str]:
        """What makes these intrinsics unusable (empty list: usable)."""
        out = []
        if self.width <= 0 or self.height <= 0:
            out.append(f"image size {self.width}x{self.height} is empty")
        if not np.isfinite(self.K).all():
            out.append("K has non-finite entries")
        else:
            if self.K[0, 0] <= 0 or self.K[1, 1] <= 0:
                out.append(f"K has focal lengths fx={self.K[0, 0]:g}, fy={self.K[1, 1]:g} (must be > 0)")
            if not np.allclose(self.K[2], (0.0, 0.0, 1.0)) or self.K[1, 0] != 0.0:
                out.append(
                    f"K is not an upper-triangular camera matrix with last row 0 0 1 "
                    f"(rows {self.K[1].tolist()}, {self.K[2].tolist()}; transposed?)"
                )
        if not np.isfinite(self.D).all():
            out.append(f"D has non-finite entries ({self.D.tolist()})")
        elif self.has_distortion:
            lengths = DISTORTION_LENGTHS.get(self.distortion_model)
            if lengths is None:
                out.append(f"distortion model '{self.distortion_model}' is not supported")
            elif len(self.D) not in lengths:
                out.append(
                    f"D has {len(self.D)} coefficients; {self.distortion_model} takes {' or '.join(map(str, lengths))}"
                )
        return out

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.D != 0.0))

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nx3 points in the optical frame -> (Nx2 raw pixels, mask of points in front)."""
        P = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        in_front = P[:, 2] > 1e-9
        if not self.has_distortion:
            return self._ideal(P, in_front), in_front
        if len(P) == 0:  # OpenCV returns None for no points
            return np.zeros((0, 2)), in_front
        zero = np.zeros(3)
        if self.distortion_model == EQUIDISTANT:
            uv = cv2.fisheye.projectPoints(P[None], zero, zero, self.K, self.D[:4])[0]
        else:
            uv = cv2.projectPoints(P, zero, zero, self.K, self.D)[0]
        return uv.reshape(-1, 2), in_front

    def within_model(self, points_cam: np.ndarray, tol_px: float = 1.0) -> np.ndarray:
        """Mask of points in front whose projection the model inverts: a polynomial
        distortion turns back beyond some field angle and folds rays from far outside the
        lens's view into the image, which no real lens does. Round trip test:
        undistort(project(P)) is P's ideal (distortion-free) projection."""
        uv, in_front = self.project(points_cam)
        if not self.has_distortion or len(uv) == 0:
            return in_front
        ideal = self._ideal(np.asarray(points_cam, dtype=float).reshape(-1, 3), in_front)
        return in_front & (np.linalg.norm(self.undistort_pixels(uv) - ideal, axis=1) <= tol_px)

    def _ideal(self, P: np.ndarray, in_front: np.ndarray) -> np.ndarray:
        """Pinhole (distortion-free) pixels of points in the optical frame."""
        z = np.where(in_front, P[:, 2], 1.0)
        return (P[:, :2] / z[:, None]) @ self.K[:2, :2].T + self.K[:2, 2]

    def project_world(self, T_world_cam: np.ndarray, points_world: np.ndarray):
        return self.project(transform_points(inv_se3(T_world_cam), points_world))

    def distort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Pixels of the ideal pinhole camera (same K) -> raw pixels: undistort_pixels' inverse."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        rays = np.column_stack([(uv - self.K[:2, 2]) @ np.linalg.inv(self.K[:2, :2]).T, np.ones(len(uv))])
        return self.project(rays)[0]

    def undistort_pixels(self, uv: np.ndarray) -> np.ndarray:
        """Raw pixels -> pixels of the ideal (distortion-free) pinhole camera with the same K."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if not self.has_distortion or len(uv) == 0:
            return uv.copy()
        src = uv[:, None, :]
        if self.distortion_model == EQUIDISTANT:
            out = cv2.fisheye.undistortPoints(src, self.K, self.D[:4], P=self.K)
        else:
            # The default 5 iterations leave mm-level errors at strongly distorted corners.
            out = cv2.undistortPoints(src, self.K, self.D, R=None, P=self.K, criteria=_UNDISTORT_CRITERIA)
        return out.reshape(-1, 2)

    def bearings(self, uv: np.ndarray) -> np.ndarray:
        """Raw pixels -> unit viewing rays in the optical frame."""
        ideal = self.undistort_pixels(uv)
        rays = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(self.K).T
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        return (
            (uv[:, 0] >= -0.5 + margin)
            & (uv[:, 1] >= -0.5 + margin)
            & (uv[:, 0] < self.width - 0.5 - margin)
            & (uv[:, 1] < self.height - 0.5 - margin)
        )
