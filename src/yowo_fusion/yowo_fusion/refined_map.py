"""The ego map's cloud and planar layout after joint optimisation (paper "Collaborative
Processing": "refined point cloud and planar layout"). The TSDF cloud has no record of
which keyframes fused each point, so each point takes the mean correction
(T_new T_old^-1) of the refined views that see it (inside the image, in depth range):
what re-fusing the keyframes at their refined poses would give for corrections this
small, without the RGB-D images. The layout is rebuilt from the moved cloud with the ego
stage's own functions; the world frame (floor z = 0) stays the ego map's."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, transform_points
from yowo_ego.layout import Layout, LayoutParams, build_layout
from yowo_ego.scene import CloudParams, planar_patches


def move_cloud(
    points: np.ndarray,
    camera: CameraModel,
    T_old: np.ndarray,
    T_new: np.ndarray,
    depth_max_m: float,
    cell_m: float = 0.2,
) -> np.ndarray:
    """points (N, 3) moved by the mean correction of the views (T_old -> T_new, (V, 4, 4))
    that see them; a point no view sees takes its nearest view's correction. Visibility is
    decided per cell of cell_m (at the centroid of its points): the corrections vary over
    metres, and a cloud of 10^5-10^6 points times hundreds of views would take a minute."""
    cells, index = np.unique(np.floor(points / cell_m).astype(np.int64), axis=0, return_inverse=True)
    index = index.reshape(-1)
    centres = np.column_stack([np.bincount(index, points[:, k]) for k in range(3)]) / np.bincount(index)[:, None]
    total = np.zeros((len(cells), 3, 4))
    count = np.zeros(len(cells))
    for To, Tn in zip(T_old, T_new):
        P = transform_points(inv_se3(To), centres)
        z = P[:, 2]
        ok = (z > 0) & (z <= depth_max_m)
        uv = P[ok, :2] / z[ok, None] @ camera.K[:2, :2].T + camera.K[:2, 2]
        seen = np.flatnonzero(ok)[camera.in_image(uv)]
        total[seen] += (Tn @ inv_se3(To))[:3]
        count[seen] += 1
    unseen = np.flatnonzero(count == 0)
    if len(unseen):
        nearest = cKDTree(T_old[:, :3, 3]).query(centres[unseen])[1]
        total[unseen] = np.einsum("nij,njk->nik", T_new[nearest], np.linalg.inv(T_old[nearest]))[:, :3]
        count[unseen] = 1
    mean = total / count[:, None, None]  # the mean of C_k p is the mean C_k applied to p
    return np.einsum("nij,nj->ni", mean[index, :, :3], points) + mean[index, :, 3]


def rebuild_layout(
    points: np.ndarray,
    camera_centres: np.ndarray,
    cloud: CloudParams = CloudParams(),
    layout: LayoutParams = LayoutParams(),
) -> Layout:
    """The ego stage's layout steps (planar patches, walls, ceiling, floor outline) on a cloud
    already in the world frame."""
    patches, sampled, normals = planar_patches(points, camera_centres, cloud)
    return build_layout(points, sampled, normals, patches, camera_centres, layout)
