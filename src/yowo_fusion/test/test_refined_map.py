"""The refined cloud and layout follow the refined ego poses."""

import numpy as np
from scipy.spatial.transform import Rotation
from shapely.geometry import Polygon

from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at, se3, transform_points
from yowo_fusion.refined_map import move_cloud, rebuild_layout

ROOM = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])


def room_cloud(rng, spacing=0.04, height=2.6):
    """Floor and four walls of a 6 x 4 m room (surface samples, as a TSDF cloud)."""
    xs, ys, zs = np.arange(0, 6, spacing), np.arange(0, 4, spacing), np.arange(0, height, spacing)
    floor = np.array([[x, y, 0.0] for x in xs for y in ys])
    walls = [np.array([[x, y0, z] for x in xs for z in zs]) for y0 in (0.0, 4.0)]
    walls += [np.array([[x0, y, z] for y in ys for z in zs]) for x0 in (0.0, 6.0)]
    return np.vstack([floor, *walls]) + rng.normal(size=(1, 3)) * 0.002


def views():
    centres = [(1.5, 1.0), (4.5, 1.0), (4.5, 3.0), (1.5, 3.0), (3.0, 2.0)]
    return np.array(
        [
            look_at([x, y, 1.6], [x + dx, y + dy, 0.8])
            for x, y in centres
            for dx, dy in ((2, 0), (0, 2), (-2, 0), (0, -2))
        ]
    )


def test_cloud_and_layout_follow_a_known_pose_correction():
    rng = np.random.default_rng(0)
    points, T_old = room_cloud(rng), views()
    camera = CameraModel.from_fov(640, 480, 70)
    C = se3(Rotation.from_euler("z", 4, degrees=True).as_matrix(), [0.15, -0.10, 0.0])
    moved = move_cloud(points, camera, T_old, np.array([C @ T for T in T_old]), 5.0)
    np.testing.assert_allclose(moved, transform_points(C, points), atol=1e-9)

    # Two halves of the walk corrected differently: each point takes its viewers' mean.
    T_new = np.array([se3(np.eye(3), [0.0, 0.0, 0.02 * (i >= 10)]) @ T for i, T in enumerate(T_old)])
    dz = move_cloud(points, camera, T_old, T_new, 5.0)[:, 2] - points[:, 2]
    assert dz.min() >= -1e-12 and dz.max() <= 0.02 + 1e-12 and 0.0 < dz.mean() < 0.02

    layout = rebuild_layout(transform_points(C, points), transform_points(C, T_old[:, :3, 3]))
    floor = Polygon(np.vstack(layout.floor_polygons))
    truth_moved, truth_before = Polygon(transform_points(C, np.column_stack([ROOM, np.zeros(4)]))[:, :2]), Polygon(ROOM)

    def iou(a, b):
        return a.intersection(b).area / a.union(b).area

    assert iou(floor, truth_moved) > 0.95 and iou(floor, truth_moved) > iou(floor, truth_before) + 0.05
