"""Ground plane, vertical rectification (eq. rot_gp2w) and layout on a rendered room
whose reconstruction starts tilted, as an ego map does before rectification."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import look_at, se3, transform_points
from yowo_ego.frames import make_frame
from yowo_ego.layout import KIND_CEILING, KIND_WALL, build_layout
from yowo_ego.odometry import Keyframe
from yowo_ego.rgbd_odometry import downsample, scaled_K
from yowo_ego.scene import CloudParams, find_floor, fuse_cloud, planar_patches, rectify, up_from_cameras
from yowo_eval.metrics import layout_iou

# The odometry frame of the reconstruction: tilted by 12 deg and shifted.
T_ODOM_TRUE = se3(Rotation.from_euler("xyz", [12.0, -5.0, 30.0], degrees=True).as_matrix(), [0.3, -1.0, 0.5])


@pytest.fixture(scope="module")
def reconstruction(renderer, ego_camera):
    """Keyframes looking all around from two spots, 20 deg down like a walking
    head, and a few glances up at the ceiling."""
    keyframes = []
    views = [(x, y, yaw, -20) for x, y in ((1.3, 1.4), (2.7, 2.4)) for yaw in np.arange(0, 360, 45) + 10]
    views += [(2.0, 2.0, yaw, 25) for yaw in range(0, 360, 60)]
    for x, y, yaw_deg, pitch_deg in views:
        yaw = np.radians(yaw_deg)
        eye = np.array([x, y, 1.62])
        T_true = look_at(eye, eye + np.array([np.cos(yaw), np.sin(yaw), np.tan(np.radians(pitch_deg))]))
        f = renderer.render(ego_camera, T_true)
        color, depth_mm = downsample(make_frame(0, f.rgb, f.depth, ego_camera), 2)
        keyframes.append(Keyframe(len(keyframes), len(keyframes), 0, T_ODOM_TRUE @ T_true, color, depth_mm, 0))
    T_odom = [k.T_odom_cam for k in keyframes]
    # Few, barely overlapping views: keep surfaces seen once (a walk sees them many times).
    points, _ = fuse_cloud(keyframes, T_odom, scaled_K(ego_camera.K, 2), CloudParams(min_weight=1.0))
    cams = np.array([T[:3, 3] for T in T_odom])
    patches, small, normals = planar_patches(points, cams)
    return T_odom, points, cams, patches, small, normals


def test_rectification_brings_floor_normal_to_z(reconstruction):
    T_odom, points, cams, patches, small, normals = reconstruction
    n, c, support = find_floor(patches, small, normals, cams, up_from_cameras(T_odom))
    rect = rectify(n, c, T_odom[0], support)
    true_up_in_odom = T_ODOM_TRUE[:3, :3] @ np.array([0.0, 0.0, 1.0])
    up_after = rect.T_world_odom[:3, :3] @ true_up_in_odom
    assert np.degrees(np.arccos(np.clip(up_after[2], -1, 1))) < 0.2
    # World frame convention: floor at z = 0 under the first camera, x along its heading.
    first = rect.T_world_odom @ T_odom[0]
    assert abs(first[2, 3] - 1.62) < 0.01 and np.hypot(first[0, 3], first[1, 3]) < 1e-9
    assert abs(first[1, 2]) < 1e-9 and first[0, 2] > 0
    assert support > 500


def test_layout_of_the_room(reconstruction, room):
    T_odom, points, cams, patches, small, normals = reconstruction
    n, c, support = find_floor(patches, small, normals, cams, up_from_cameras(T_odom))
    W = rectify(n, c, T_odom[0], support).T_world_odom
    layout = build_layout(
        transform_points(W, points),
        transform_points(W, small),
        normals @ W[:3, :3].T,
        [p.transformed(W) for p in patches],
        transform_points(W, cams),
    )
    assert abs(layout.ceiling_height - room.spec.ceiling_height) < 0.05
    walls = [p for p in layout.planes if p.kind == KIND_WALL]
    assert len(walls) >= 4 and sum(p.kind == KIND_CEILING for p in layout.planes) == 1
    to_map = W @ T_ODOM_TRUE
    gt = [transform_points(to_map, np.column_stack([p, np.zeros(len(p))]))[:, :2] for p in room.floor_polygons]
    assert layout_iou(layout.floor_polygons, gt) > 0.93
    # In the room's own frame every wall normal lies along x or y.
    for w in walls:
        nx, ny, nz = to_map[:3, :3].T @ w.coefficients[:3]
        assert min(abs(nx), abs(ny)) < np.sin(np.radians(2.0)) and abs(nz) < 1e-9 + np.sin(np.radians(0.5))


def test_the_floor_is_the_plane_most_points_lie_on_not_the_largest_patch():
    """The patch detector splits a floor into pieces; a slanted surface (a ramp, a sofa's
    back) can be the largest single patch. The floor is the plane the most cloud points
    below the cameras lie on."""
    from yowo_ego.scene import PlanarPatch

    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(0, 10, 4000), rng.uniform(0, 6, 4000), np.zeros(4000)])
    tilt = Rotation.from_euler("x", 7.0, degrees=True).as_matrix()
    slab_n = tilt @ [0.0, 0.0, 1.0]
    slab = (tilt @ np.column_stack([rng.uniform(-1, 1, 800), rng.uniform(-1, 1, 800), np.zeros(800)]).T).T
    slab += [5.0, 3.0, 0.4]
    points = np.vstack([floor, slab])
    normals = np.vstack([np.tile([0.0, 0.0, 1.0], (len(floor), 1)), np.tile(slab_n, (len(slab), 1))])
    cams = np.column_stack([rng.uniform(1, 9, 50), rng.uniform(1, 5, 50), np.full(50, 1.6)])

    def patch(n, c, count):
        n, c = np.asarray(n, float), np.asarray(c, float)
        return PlanarPatch(normal=n, center=c, d=float(-np.dot(n, c)), corners=np.tile(c, (4, 1)), num_points=count)

    patches = [patch(slab_n, [5.0, 3.0, 0.4], 800), patch([0.0, 0.0, 1.0], [2.0, 2.0, 0.0], 300)]
    n, c, support = find_floor(patches, points, normals, cams, np.array([0.05, 0.0, 1.0]))
    assert np.degrees(np.arccos(min(1.0, n[2]))) < 0.5 and abs(c @ n) < 0.01, (n, c)
    assert support >= 3900
