"""EgoMap -> EgoMapData: how each pose was tracked reaches the fusion, and a producer that
does not say leaves the fusion to judge by landmarks."""

import numpy as np
from geometry_msgs.msg import Pose
from sensor_msgs.msg import CameraInfo

from yowo_ego.ego_messages import TRACKING_CODES
from yowo_ego.odometry import IMU_BRIDGED, INTERPOLATED, LOST, MAP_RELOCALISED, MEASURED, RECOVERED, TRACKED
from yowo_fusion.messages import ego_map_from_msg
from yowo_msgs.msg import EgoMap


def _msg(tracking, fitness, n: int = 5) -> EgoMap:
    info = CameraInfo(
        width=640, height=480, k=[500.0, 0, 320, 0, 500, 240, 0, 0, 1], distortion_model="plumb_bob", d=[0.0] * 5
    )
    poses = [Pose() for _ in range(n)]
    for p in poses:
        p.orientation.w = 1.0
    return EgoMap(
        camera_info=info,
        stamps=[],
        poses=poses,
        descriptor_type="SIFT",
        descriptor_size=128,
        tracking=tracking,
        tracking_fitness=fitness,
    )


def test_tracking_reaches_the_fusion_and_its_absence_is_none():
    statuses = [TRACKED, MAP_RELOCALISED, INTERPOLATED, IMU_BRIDGED, LOST]
    ego = ego_map_from_msg(_msg([TRACKING_CODES[s] for s in statuses], [0.8, 0.9, 0.7, 0.0, 0.0]))
    assert ego.tracking_measured.tolist() == [s in MEASURED for s in statuses] == [True, True, True, False, False]
    assert np.allclose(ego.tracking_fitness, [0.8, 0.9, 0.7, 0.0, 0.0])
    silent = ego_map_from_msg(_msg([], []))
    assert silent.tracking_measured is None and silent.tracking_fitness is None
    assert not ego.imu
    with_imu = _msg([TRACKING_CODES[s] for s in statuses], [0.8, 0.9, 0.7, 0.0, 0.0])
    with_imu.imu = True
    assert ego_map_from_msg(with_imu).imu


def test_held_attitudes_reach_the_fusion_and_their_absence_is_none():
    held = _msg([], [])
    held.attitude_held = [True, False, True, True, False]
    assert ego_map_from_msg(held).attitude_held.tolist() == [True, False, True, True, False]
    assert ego_map_from_msg(_msg([], [])).attitude_held is None
    held.attitude_held = [True, False]  # not one per pose: not said
    assert ego_map_from_msg(held).attitude_held is None


def test_every_tracking_status_has_a_code():
    assert set(TRACKING_CODES) == {TRACKED, RECOVERED, MAP_RELOCALISED, IMU_BRIDGED, LOST, INTERPOLATED}
    measured = (EgoMap.TRACKING_DENSE, EgoMap.TRACKING_MAP, EgoMap.TRACKING_INTERPOLATED)
    assert all((TRACKING_CODES[s] in measured) == (s in MEASURED) for s in TRACKING_CODES)
    assert TRACKING_CODES[INTERPOLATED] not in (TRACKING_CODES[TRACKED], TRACKING_CODES[IMU_BRIDGED])
