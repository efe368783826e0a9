"""Without an IMU, the floor each keyframe sees sets its tilt in the bundle adjustment and
its largest wall its heading: the floor's normal and the wall's are found in one rendered
depth image, and two halves of a walk joined by a tilted or turned step (bare walls, no
shared features) come out level and square."""

import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, look_at, rotation_angle_deg, se3, transform_points
from yowo_ego.feature_tracks import Tracks
from yowo_ego.features import KeyframeFeatures
from yowo_ego.frames import make_frame
from yowo_ego.odometry import Keyframe, OdometryEdge
from yowo_ego.refine import bundle_adjust
from yowo_ego.rgbd_odometry import downsample, scaled_K
from yowo_ego.scene import FloorAttitudes, WallAttitudes, floor_normal_in_view, wall_attitudes, wall_normals_in_view

CAM = CameraModel.from_fov(640, 480, 70.0)
UP = np.array([0.0, 0.0, 1.0])


def test_the_floor_normal_of_one_view(renderer, ego_camera):
    """The room's floor (z = 0, z up) from a head-height view: its normal in the camera
    frame within 0.5 deg, whatever the up direction guessed (within 15 deg)."""
    T = look_at((0.8, 0.9, 1.6), (3.5, 3.2, 0.7))
    view = renderer.render(ego_camera, T)
    _, depth_mm = downsample(make_frame(0, view.rgb, view.depth, ego_camera), 2)
    truth = T[:3, :3].T @ UP
    guess = Rotation.from_rotvec([0.0, np.radians(15.0), 0.0]).as_matrix() @ truth
    n = floor_normal_in_view(depth_mm, scaled_K(ego_camera.K, 2), guess)
    assert n is not None and np.degrees(np.arccos(np.clip(n @ truth, -1, 1))) < 0.5
    # Looking at the ceiling: no floor below.
    up_view = renderer.render(ego_camera, look_at((2.0, 2.0, 1.6), (2.1, 2.0, 3.0)))
    _, up_depth = downsample(make_frame(0, up_view.rgb, up_view.depth, ego_camera), 2)
    assert floor_normal_in_view(up_depth, scaled_K(ego_camera.K, 2), UP) is None


def test_the_largest_wall_of_one_view(renderer, ego_camera):
    """The room's walls are x or y = const: each wall a view finds is one of them, its normal
    within 0.5 deg, whatever the up direction guessed (within 5 deg)."""
    T = look_at((1.0, 1.2, 1.6), (2.6, 4.0, 1.3))
    view = renderer.render(ego_camera, T)
    _, depth_mm = downsample(make_frame(0, view.rgb, view.depth, ego_camera), 2)
    guess = Rotation.from_rotvec([np.radians(5.0), 0.0, 0.0]).as_matrix() @ T[:3, :3].T @ UP
    walls = wall_normals_in_view(depth_mm, scaled_K(ego_camera.K, 2), guess)
    assert len(walls) >= 1
    for n in walls:
        world = T[:3, :3] @ n
        assert min(np.degrees(np.arccos(np.clip(abs(world @ axis), -1, 1))) for axis in np.eye(3)[:2]) < 0.5


def _turned(T, deg):
    """T turned by ``deg`` about the vertical through its centre."""
    R = Rotation.from_rotvec(np.radians(deg) * UP).as_matrix()
    return se3(R @ T[:3, :3], T[:3, 3])


def _turn_from_truth(walls, poses):
    """The turn [deg] about the vertical from each keyframe's true wall direction (its true
    pose) to the axis direction its wall was given."""
    out = []
    for k, (n, axis) in walls.walls.items():
        true = poses[k][:3, :3] @ n
        out.append(np.degrees(np.arctan2(np.cross(true, axis) @ UP, true @ axis)))
    return np.array(out)


def test_walls_agree_on_the_room_s_axes_and_a_turned_keyframe_gets_its_own(renderer, ego_camera):
    """Six views around the room, four into corners; two of them tracked 8 deg turned, then
    all of them +-15 deg: every keyframe's wall belongs to its true axis, up to one turn of
    the whole map (the axes: the majority's, within a third of the turned ones' turn)."""
    targets = [(3.8, 2.2, 1.2), (2.0, 3.8, 1.1), (3.6, 3.5, 1.2), (0.4, 3.6, 1.1), (0.1, 0.1, 1.2), (3.9, 0.1, 1.2)]
    poses = [look_at((2.0, 2.0, 1.6), t) for t in targets]
    keyframes = []
    for k, T in enumerate(poses):
        view = renderer.render(ego_camera, T)
        _, depth_mm = downsample(make_frame(0, view.rgb, view.depth, ego_camera), 2)
        keyframes.append(Keyframe(k, k, k, T, None, depth_mm, 0))
    K = scaled_K(ego_camera.K, 2)
    for tracked in (
        poses[:4] + [_turned(T, 8.0) for T in poses[4:]],
        [_turned(T, 15.0 * (-1) ** k) for k, T in enumerate(poses)],
    ):
        walls = wall_attitudes(keyframes, tracked, K, UP)
        assert walls is not None and len(walls.walls) == 6
        turns = _turn_from_truth(walls, poses)
        assert np.ptp(turns) < 0.5 and abs(turns[0]) < 8.0 / 3


def _corner_depth(K, angle_deg, width=320, height=240):
    """Depth [mm] of a camera (looking along z, y down) facing a corner of two vertical walls
    3 m ahead whose normals make ``angle_deg``."""
    v, u = np.mgrid[0:height, 0:width].astype(float)
    rays = np.dstack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)])
    corner = np.array([0.0, 0.0, 3.0])
    t = np.full((height, width), np.inf)
    for sign in (1, -1):
        half = np.radians(angle_deg / 2) * sign
        n = np.array([np.sin(half), 0.0, -np.cos(half)])  # facing the camera
        along = rays @ n
        hit = (corner @ n) / np.where(along < 0, along, -1e-12)
        t = np.minimum(t, np.where(hit > 0, hit, np.inf))  # the ray leaves the room at the nearer wall
    depth = np.where(t < 8.0, t * 1000.0, 0.0)
    return depth.astype(np.uint16)


def test_a_building_whose_corners_are_not_square_gets_no_walls():
    """Views whose two walls meet at 120 deg: not a Manhattan world, so no keyframe's
    heading is held to an axis; the same views of a square corner are."""
    K = scaled_K(CAM.K, 2)
    up = np.array([0.0, -1.0, 0.0])  # camera y points down
    poses = [se3(Rotation.from_rotvec(np.radians(d) * up).as_matrix(), np.zeros(3)) for d in (-10, 0, 10)]
    for angle, square in ((60.0, False), (90.0, True)):
        keyframes = [Keyframe(k, k, k, T, None, _corner_depth(K, angle), 0) for k, T in enumerate(poses)]
        assert len(wall_normals_in_view(keyframes[0].depth_mm, K, up)) == 2
        walls = wall_attitudes(keyframes, poses, K, up)
        assert (walls is not None) == square


def _two_rooms(seed=0):
    """8 keyframes along a wall; keyframes 0-3 and 4-7 see disjoint stretches of it (no
    track joins the halves: a bare stretch between them)."""
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-1, 6, 900), rng.uniform(3.0, 3.5, 900), rng.uniform(0, 2.5, 900)])
    poses = [look_at((x, 0.0, 1.6), (x + 0.5, 3.0, 1.0)) for x in np.linspace(0, 3.0, 8)]
    features, kf, feat, trk = [], [], [], []
    for k, T in enumerate(poses):
        local = transform_points(inv_se3(T), points)
        uv, front = CAM.project(local)
        half = points[:, 0] < 1.6 if k < 4 else points[:, 0] >= 1.6
        seen = np.flatnonzero(front & CAM.in_image(uv, margin=5) & half)
        features.append(
            KeyframeFeatures(
                uv[seen] + rng.normal(0, 0.5, (len(seen), 2)), np.zeros((len(seen), 128), np.float32), local[seen, 2]
            )
        )
        kf += [k] * len(seen)
        feat += list(range(len(seen)))
        trk += list(seen)
    return poses, Tracks(np.array(kf), np.array(feat), np.array(trk)), features


def test_a_tilted_step_between_two_halves_is_levelled_by_the_floor():
    poses, tracks, features = _two_rooms()
    tilt = se3(Rotation.from_rotvec([np.radians(5.0), 0.0, 0.0]).as_matrix(), np.zeros(3))
    # The step from keyframe 3 to 4 was tracked 5 deg off; the second half inherits it.
    T_3_4 = inv_se3(poses[3]) @ poses[4] @ tilt
    init = poses[:4] + [poses[3] @ T_3_4 @ inv_se3(poses[4]) @ T for T in poses[4:]]
    edge = OdometryEdge(
        source=4, target=3, T_target_source=T_3_4, information=np.diag([1e4] * 3 + [1e4] * 3), kind="odometry"
    )
    plain = bundle_adjust(tracks, features, init, CAM, edges=[edge])
    floor = FloorAttitudes(UP, {k: T[:3, :3].T @ UP for k, T in enumerate(poses)})  # each view's true floor
    levelled = bundle_adjust(tracks, features, init, CAM, edges=[edge], floor=floor)
    worst = [
        max(rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(out.T_world_kf, poses))
        for out in (plain, levelled)
    ]
    assert worst[0] > 4.0  # the features cannot see the tilt between the halves
    assert worst[1] < 1.0  # from 5: the floor outweighs the one tracked step


def test_a_turned_step_between_two_halves_is_squared_by_the_walls():
    poses, tracks, features = _two_rooms()
    # The step from keyframe 3 to 4 was tracked turned by 5 deg about the vertical.
    turn = se3(Rotation.from_rotvec(np.radians(5.0) * (poses[4][:3, :3].T @ UP)).as_matrix(), np.zeros(3))
    T_3_4 = inv_se3(poses[3]) @ poses[4] @ turn
    init = poses[:4] + [poses[3] @ T_3_4 @ inv_se3(poses[4]) @ T for T in poses[4:]]
    edge = OdometryEdge(
        source=4, target=3, T_target_source=T_3_4, information=np.diag([1e4] * 3 + [1e4] * 3), kind="odometry"
    )
    plain = bundle_adjust(tracks, features, init, CAM, edges=[edge])
    wall = np.array([0.0, -1.0, 0.0])  # the wall at y = 3-3.5 faces the cameras
    walls = WallAttitudes(UP, np.array([1.0, 0.0, 0.0]), {k: (T[:3, :3].T @ wall, wall) for k, T in enumerate(poses)})
    squared = bundle_adjust(tracks, features, init, CAM, edges=[edge], walls=walls)
    worst = [
        max(rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(out.T_world_kf, poses)) for out in (plain, squared)
    ]
    assert worst[0] > 4.0  # the features cannot see the turn between the halves
    assert worst[1] < 1.0  # from 5: the wall outweighs the one tracked step
