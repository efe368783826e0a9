"""Dense RGB-D odometry of one image pair (Open3D's tensor ``rgbd_odometry_multi_scale``)
and the images it takes: downsampled to the odometry resolution, padded, as Open3D's RGBD
image."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from yowo_common.geometry import rotation_angle_deg

from .frames import RgbdFrame
from .odometry import OdometryParams

_odo = o3d.t.pipelines.odometry


def orthonormalize(T: np.ndarray) -> np.ndarray:
    """Project the rotation block onto SO(3): Open3D returns float32-accurate
    rotations whose errors otherwise grow without bound when chained."""
    T = np.array(T, dtype=float)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    T[:3, :3] = R
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return T


def scaled_K(K: np.ndarray, scale: int) -> np.ndarray:
    """K of an image downsampled by ``scale`` (pixel centres at integer coordinates)."""
    Ks = np.array(K, dtype=float)
    Ks[0, 0] /= scale
    Ks[1, 1] /= scale
    Ks[0, 1] /= scale
    Ks[:2, 2] = (Ks[:2, 2] + 0.5) / scale - 0.5
    return Ks


def downsample(frame: RgbdFrame, scale: int, edge_ratio: float = 0.03) -> tuple[np.ndarray, np.ndarray]:
    """(colour uint8, depth uint16 mm) at 1/scale resolution: block means, so both
    stay centred where ``scaled_K`` puts the pixel. Depth averages the valid
    pixels of a block (isolated dropouts must not spread: Open3D's normals need
    valid neighbours) and drops blocks spanning a depth edge rather than blending
    two surfaces."""
    if scale == 1:
        depth, color = frame.depth, frame.color
    else:
        h, w = (s // scale * scale for s in frame.depth.shape)
        parts = [frame.depth[dy:h:scale, dx:w:scale] for dy in range(scale) for dx in range(scale)]
        valid = [np.isfinite(q) for q in parts]
        count = np.add.reduce(valid, dtype=np.float32)
        with np.errstate(invalid="ignore", divide="ignore"):
            depth = np.add.reduce([np.where(v, q, 0.0) for q, v in zip(parts, valid)]) / count
            spread = np.fmax.reduce(parts) - np.fmin.reduce(parts)
            depth[(count == 0) | ~(spread <= edge_ratio * depth)] = np.nan
        color = cv2.resize(frame.color[:h, :w], (w // scale, h // scale), interpolation=cv2.INTER_AREA)
    mm = np.nan_to_num(depth * 1000.0, nan=0.0, posinf=0.0)
    return np.ascontiguousarray(color), np.clip(np.round(mm), 0, 65535).astype(np.uint16)


# Open3D 0.20's Gaussian filter (its image pyramid's) differs by 1 ulp within 2 px of the
# image border from one process to the next (measured: two outcomes, chosen at random per
# process). The dense odometry sees the images inside a border of invalid depth, 2 px at
# its coarsest level, so those pixels never count and a recording gives the same poses in
# every run. `RgbdOdometry` shifts K's principal point to match.
ODOMETRY_PAD_PX = 8


def o3d_rgbd(color: np.ndarray, depth_mm: np.ndarray) -> o3d.t.geometry.RGBDImage:
    """Tensor RGBD image (float colour in [0, 1], float depth in mm) inside a border of
    ODOMETRY_PAD_PX (replicated colour, no depth); copies the arrays."""
    pad = ODOMETRY_PAD_PX
    color = np.pad(np.asarray(color, dtype=np.float32) / 255.0, ((pad, pad), (pad, pad), (0, 0)), mode="edge")
    depth = np.pad(np.asarray(depth_mm, dtype=np.float32), pad)
    return o3d.t.geometry.RGBDImage(
        o3d.t.geometry.Image(o3d.core.Tensor(color)), o3d.t.geometry.Image(o3d.core.Tensor(depth))
    )


@dataclass
class OdometryImages:
    """A frame's images as the tracker takes them: at the odometry resolution (also as
    Open3D's RGBD image) and the full-resolution grey image the feature fall-back matches.
    Made by ``of`` on any thread (the ego mapper node makes the next frame's while the last
    is tracked)."""

    color: np.ndarray
    depth_mm: np.ndarray
    rgbd: o3d.t.geometry.RGBDImage
    full_gray: np.ndarray

    @classmethod
    def of(cls, frame: RgbdFrame, scale: int) -> "OdometryImages":
        color, depth_mm = downsample(frame, scale)
        return cls(color, depth_mm, o3d_rgbd(color, depth_mm), cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY))


@dataclass(kw_only=True)
class OdometryFrame:
    """One frame as the tracker holds it: its OdometryImages with its index, stamp and
    full-resolution depth (the feature fall-back's)."""

    frame_index: int
    stamp_ns: int
    color: np.ndarray
    depth_mm: np.ndarray
    rgbd: o3d.t.geometry.RGBDImage
    full_gray: np.ndarray
    full_depth: np.ndarray


class RgbdOdometry:
    """Dense RGB-D odometry between pairs of images at one resolution."""

    def __init__(self, K: np.ndarray, params: OdometryParams = OdometryParams()):
        self.params = params
        self.K_full = np.asarray(K, dtype=float)
        self.K = scaled_K(self.K_full, params.scale)
        K_padded = self.K.copy()
        K_padded[:2, 2] += ODOMETRY_PAD_PX
        self._K = o3d.core.Tensor(K_padded)  # of the images o3d_rgbd makes
        self._K_depth = o3d.core.Tensor(self.K)  # of the plain depth images `information` takes
        self._criteria = [
            _odo.OdometryConvergenceCriteria(n, params.relative_tolerance, params.relative_tolerance)
            for n in params.iterations
        ]
        self._polish_criteria = [_odo.OdometryConvergenceCriteria(params.polish_iterations)]

    def register(
        self,
        source: o3d.t.geometry.RGBDImage,
        target: o3d.t.geometry.RGBDImage,
        init_target_source: np.ndarray,
        cascade: tuple[str, ...] = ("Hybrid",),
    ) -> tuple[np.ndarray, float, float]:
        """(T_target_source, fitness, inlier RMSE) after running the methods of
        ``cascade`` in turn (fitness scaled for a source with little depth, full_depth_fraction);
        fitness 0 when Open3D gives up."""
        T, r = init_target_source, None
        for method in cascade:
            run = self._run(source, target, T, self._criteria, getattr(_odo.Method, method))
            if run is None:
                return init_target_source, 0.0, np.inf
            T, r = run
        return T, float(r.fitness) * self._fitness_scale(source), float(r.inlier_rmse)

    def _run(
        self,
        source: o3d.t.geometry.RGBDImage,
        target: o3d.t.geometry.RGBDImage,
        init_target_source: np.ndarray,
        criteria: list,
        method,
    ):
        """(T_target_source orthonormalised, Open3D's result) of one multi-scale odometry run;
        None when Open3D gives up or diverges."""
        try:
            r = _odo.rgbd_odometry_multi_scale(
                source,
                target,
                self._K,
                o3d.core.Tensor(init_target_source),
                1000.0,
                self.params.depth_max_m,
                criteria,
                method,
            )
        except RuntimeError:  # "Singular 6x6 linear system": nothing to track
            return None
        T = r.transformation.numpy()
        return (orthonormalize(T), r) if np.isfinite(T).all() else None

    def _fitness_scale(self, source: o3d.t.geometry.RGBDImage) -> float:
        """full_depth_fraction over the source's share of pixels with depth (inside the padding), at least 1."""
        depth = source.depth.as_tensor().numpy()[ODOMETRY_PAD_PX:-ODOMETRY_PAD_PX, ODOMETRY_PAD_PX:-ODOMETRY_PAD_PX]
        return max(1.0, self.params.full_depth_fraction * depth.size / max(np.count_nonzero(depth), 1))

    def polish(
        self, source: o3d.t.geometry.RGBDImage, target: o3d.t.geometry.RGBDImage, T_target_source: np.ndarray
    ) -> np.ndarray:
        """A few point-to-plane iterations at full odometry resolution from an
        accepted result. The photometric term leaves a bias of 1-3 mm (texture
        filtering differs between views); the depth term alone is unbiased
        where geometry constrains all six degrees of freedom. Where it does not
        (one wall, two walls), point-to-plane slides, so a polish that moves
        further than ``polish_max_m`` / ``polish_max_deg`` is discarded."""
        p = self.params
        run = self._run(source, target, T_target_source, self._polish_criteria, _odo.Method.PointToPlane)
        if run is None:
            return T_target_source
        T = run[0]
        if (
            np.linalg.norm(T[:3, 3] - T_target_source[:3, 3]) > p.polish_max_m
            or rotation_angle_deg(T[:3, :3], T_target_source[:3, :3]) > p.polish_max_deg
        ):
            return T_target_source
        return T

    def information(
        self, source_depth_mm: np.ndarray, target_depth_mm: np.ndarray, T_target_source: np.ndarray
    ) -> np.ndarray:
        info = _odo.compute_odometry_information_matrix(
            o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(source_depth_mm, dtype=np.float32))),
            o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(target_depth_mm, dtype=np.float32))),
            self._K_depth,
            o3d.core.Tensor(T_target_source),
            self.params.info_distance_m,
            1000.0,
            self.params.depth_max_m,
        ).numpy()
        return np.asarray(info, dtype=float)
