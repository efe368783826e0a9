"""fusion_node: registers every CMC in the ego map's world frame once the ego map,
the CMC groups and every camera's keypoints are complete; publishes
/yowo/cmc_poses (RegisteredCameraArray), /tf_static (one TFMessage, map -> every
camera), the ego map's cloud and layout at the jointly optimised ego poses
(/yowo/fusion/map/points, /yowo/fusion/layout), the trajectory at those poses
(/yowo/fusion/path) and /yowo/layout/markers (that layout's floor), all latched for
late joiners."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from nav_msgs.msg import Path
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from yowo_cmc.keypoint_input import TrackAccumulator, frame_from_msg
from yowo_cmc.messages import groups_from_msg
from yowo_common import topics
from yowo_common.ros.context import spin_node
from yowo_common.ros.stage import LATCHED, StageNode
from yowo_common.rosconv import decode_color
from yowo_ego.ego_messages import path_msg, points_msg, scene_layout_msg
from yowo_msgs.msg import (
    AgentKeypoints,
    CameraAgentFitArray,
    CameraGroupArray,
    EgoMap,
    RegisteredCameraArray,
    SceneLayout,
)

from .config import UPSTREAM_HOMES, FusionParams, UpstreamParams
from .messages import (
    agent_fits_to_msg,
    ego_map_from_msg,
    layout_markers,
    registered_to_msg,
    tf_static,
    weak_places_msg,
)
from .pipeline import fuse
from .records import CmcInput


class FusionNode(StageNode):
    def __init__(self):
        super().__init__(topics.FUSION_STAGE)
        cameras = [c for c in self.declare_parameter("cameras", [""]).value if c]
        # Cameras without intrinsics: their trackers' models are nominal (registered only in a group).
        self.estimated = {c for c in self.declare_parameter("estimate_intrinsics", [""]).value if c}
        # Where recordings read as one meet (0: none), for the ego map's breaks.
        self.joins_ns = np.array(
            [j for j in self.declare_parameter("recording_joins_ns", [0]).value if j > 0], np.int64
        )
        self.params = self.section(FusionParams, "fusion")
        defaults = UpstreamParams()
        self.upstream = UpstreamParams(
            **{
                field: self.section(type(getattr(defaults, field)), home, field)
                for field, home in UPSTREAM_HOMES.items()
            }
        )
        self.acc = {c: TrackAccumulator(c) for c in cameras}
        self.backgrounds = {}
        self.ego_map = self.groups = self.layout = self.cloud = None
        self.pub_poses = self.output(RegisteredCameraArray, topics.CMC_POSES, LATCHED)
        self.pub_tf = self.output(TFMessage, topics.TF_STATIC, LATCHED)
        self.pub_markers = self.output(MarkerArray, topics.LAYOUT_MARKERS, LATCHED)
        self.pub_cloud = self.output(PointCloud2, topics.REFINED_MAP_POINTS, LATCHED)
        self.pub_layout = self.output(SceneLayout, topics.REFINED_LAYOUT, LATCHED)
        self.pub_path = self.output(Path, topics.REFINED_EGO_PATH, LATCHED)
        self.pub_fits = self.output(CameraAgentFitArray, topics.AGENT_FIT, LATCHED)
        self.pub_weak = self.output(String, topics.WEAK_PLACES, LATCHED)
        self.stream_input(EgoMap, topics.EGO_MAP, lambda m: setattr(self, "ego_map", m), upstream=topics.EGO_STAGE)
        self.stream_input(SceneLayout, topics.LAYOUT, lambda m: setattr(self, "layout", m), upstream=topics.EGO_STAGE)
        self.stream_input(
            PointCloud2, topics.MAP_POINTS, lambda m: setattr(self, "cloud", m), upstream=topics.EGO_STAGE
        )
        self.stream_input(
            CameraGroupArray, topics.GROUPS, lambda m: setattr(self, "groups", m), upstream=topics.GROUP_SFM_STAGE
        )
        for cam in cameras:
            self.stream_input(
                CameraInfo,
                topics.tracker_camera_info(cam),
                self.acc[cam].take_camera_info,
                upstream=topics.tracker_stage(cam),
            )
            self.stream_input(
                AgentKeypoints,
                topics.tracker_keypoints(cam),
                lambda m, c=cam: self.acc[c].add(frame_from_msg(m)),
                upstream=topics.tracker_stage(cam),
            )
            self.stream_input(
                Image,
                topics.tracker_background(cam),
                lambda m, c=cam: self.backgrounds.__setitem__(c, m),
                upstream=topics.tracker_stage(cam),
            )

    def finalize(self) -> str:
        if self.ego_map is None:
            raise ValueError("no ego map arrived (the ego mapper failed); cannot register cameras")
        if self.groups is None:
            raise ValueError("no CMC groups arrived (the group SfM failed)")
        groups, ungrouped = groups_from_msg(self.groups)
        cmcs = {
            n: CmcInput(
                a.tracks(),
                decode_color(self.backgrounds[n]) if n in self.backgrounds else None,
                n not in self.estimated,
            )
            for n, a in self.acc.items()
            if a.camera is not None
        }
        ungrouped.update({n: a.unusable_reason() for n, a in self.acc.items() if a.camera is None})
        ego = replace(ego_map_from_msg(self.ego_map, self.cloud, self.layout), joins_ns=self.joins_ns)
        result = fuse(ego, groups, ungrouped, cmcs, self.params, self.upstream)
        stamp = max((f.stamp_ns for a in self.acc.values() for f in a.frames), default=0)
        self.pub_poses.publish(registered_to_msg(result.cameras, stamp))
        self.pub_tf.publish(tf_static(result.cameras, stamp))
        if len(ego.stamps_ns):
            self.pub_path.publish(path_msg(ego.stamps_ns, result.T_world_ego))
        if self.cloud is not None:
            self.pub_cloud.publish(points_msg(result.point_cloud, result.point_colors, stamp))
        if result.layout is not None:
            self.pub_layout.publish(scene_layout_msg(result.layout, stamp))
        floors = result.layout.floor_polygons if result.layout is not None else []
        self.pub_markers.publish(layout_markers(result.cameras, floors, stamp))
        self.pub_fits.publish(
            agent_fits_to_msg(result.agent_fits, {n: c.tracks.camera for n, c in cmcs.items()}, self.backgrounds, stamp)
        )
        self.pub_weak.publish(weak_places_msg(result.weak_places))
        return "; ".join(
            f"{c.name}: {c.method} {c.status}" + (f" ({c.reason})" if c.reason else "") for c in result.cameras
        )


def main(args=None):
    spin_node(FusionNode, args)


if __name__ == "__main__":
    main()
