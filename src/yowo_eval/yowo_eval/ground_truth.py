"""The ground truth of a recording (/gt/... topics, written by the simulator), in
YOWO's map frame. Only evaluation reads it; the pipeline never does."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from yowo_common.topics import GT_EGO_POSE, GT_FLOOR, GT_PREFIX, gt_cmc_clock_offset_topic, parse_gt_cmc_pose_topic
from yowo_common.trajectory import Trajectory

from .metrics import map_frame_from_first_pose


@dataclass(kw_only=True)
class GroundTruth:
    cameras: dict[str, np.ndarray]
    ego: Trajectory | None
    floor: list[np.ndarray]
    # The simulator's frame -> YOWO's map frame; other /gt/ data (agent keypoints) need it.
    T_map_sim: np.ndarray = field(default_factory=lambda: np.eye(4))
    # Each CMC's clock minus the ego clock [s] (absent: synchronised); its stamps are true time + this.
    clock_offsets_s: dict[str, float] = field(default_factory=dict)

    def true_time_ns(self, camera: str, stamp_ns: int) -> int:
        """A CMC's stamp on the ego clock (the ground truth's)."""
        return int(stamp_ns) - round(self.clock_offsets_s.get(camera, 0.0) * 1e9)


def read_ground_truth(bag) -> GroundTruth:
    from yowo_common.ros.bag import list_topics, read_messages
    from yowo_common.rosconv import points_to_array, pose_to_matrix, stamp_to_ns

    topics = [t.name for t in list_topics(bag) if t.name.startswith(GT_PREFIX)]
    cams, ego_ns, ego_T, floor = {}, [], [], []
    clocks = {gt_cmc_clock_offset_topic(n): n for n in map(parse_gt_cmc_pose_topic, topics) if n}
    offsets = {}
    for topic, _, msg in read_messages(bag, topics):
        if topic in clocks:
            offsets[clocks[topic]] = float(msg.data)
        elif parse_gt_cmc_pose_topic(topic):
            cams[parse_gt_cmc_pose_topic(topic)] = pose_to_matrix(msg.pose)
        elif topic == GT_EGO_POSE:
            ego_ns.append(stamp_to_ns(msg.header.stamp))
            ego_T.append(pose_to_matrix(msg.pose))
        elif topic == GT_FLOOR:
            floor.append(points_to_array(msg.polygon.points)[:, :2])
    ego = Trajectory(np.array(ego_ns, dtype=np.int64), np.array(ego_T)) if ego_ns else None
    T = np.eye(4)
    if ego is not None:  # into YOWO's map convention (defined by the first ego pose)
        T = map_frame_from_first_pose(ego.T_world_cam[np.argmin(ego.stamps_ns)])
        cams = {n: T @ P for n, P in cams.items()}
        ego = Trajectory(ego.stamps_ns, np.einsum("ij,njk->nik", T, ego.T_world_cam))
        floor = [p @ T[:2, :2].T + T[:2, 3] for p in floor]
    return GroundTruth(cameras=cams, ego=ego, floor=floor, T_map_sim=T, clock_offsets_s=offsets)
