"""Without an IMU, the floor each keyframe sees sets its tilt in the bundle adjustment:
the floor's normal is found in one rendered depth image, and two halves of a walk joined
by a tilted step (bare walls, no shared features) come out level."""
import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, look_at, rotation_angle_deg, se3, transform_points
from yowo_ego.features import KeyframeFeatures
from yowo_ego.frames import make_frame
from yowo_ego.odometry import OdometryEdge, downsample, scaled_K
from yowo_ego.refine import bundle_adjust
from yowo_ego.scene import FloorAttitudes, floor_normal_in_view
from yowo_ego.tracks import Tracks

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
        features.append(KeyframeFeatures(uv[seen] + rng.normal(0, 0.5, (len(seen), 2)),
                                         np.zeros((len(seen), 128), np.float32), local[seen, 2]))
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
    edge = OdometryEdge(4, 3, T_3_4, np.diag([1e4] * 3 + [1e4] * 3), "odometry")
    plain = bundle_adjust(tracks, features, init, CAM, edges=[edge])
    floor = FloorAttitudes(UP, {k: T[:3, :3].T @ UP for k, T in enumerate(poses)})   # each view's true floor
    levelled = bundle_adjust(tracks, features, init, CAM, edges=[edge], floor=floor)
    worst = [max(rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(out.T_world_kf, poses))
             for out in (plain, levelled)]
    assert worst[0] > 4.0          # the features cannot see the tilt between the halves
    assert worst[1] < 1.0          # from 5: the floor outweighs the one tracked step
