"""group_sfm_node: gathers every CMC's validated agent keypoints and CameraInfo,
and when the streams are complete computes the CMC groups and their relative
calibration; publishes yowo_msgs/CameraGroupArray on /yowo/cmc/groups (latched).
During the walk it publishes the walk guidance (yowo_msgs/WalkGuidance on /yowo/guidance:
every camera's coverage on the keypoints received so far, walk_guidance.WalkGuide) every
cmc.coverage.guidance_period_s, and a final one with the groups once they are computed.
Parameter `estimate_intrinsics`: the cameras without intrinsics (their tracker published a
nominal model); the group SfM estimates their focal length (and k1). Parameter
`people_cameras` (a CMC-only run): the cameras whose trackers hand on everyone else they saw
(yowo_msgs/PersonKeypoints); they are matched across cameras (yowo_cmc.people_identity) and
calibrate the groups with the walker, the matches published on /yowo/cmc/people (latched)."""

from __future__ import annotations

import time

import numpy as np
import yaml
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import String

from yowo_common import topics
from yowo_common.ros.context import spin_node
from yowo_common.ros.stage import LATCHED, StageNode
from yowo_msgs.msg import AgentKeypoints, CameraGroupArray, PersonKeypoints, WalkGuidance

from .config import CmcParams
from .intrinsics import EstimatedCamera
from .keypoint_input import TrackAccumulator, frame_from_msg
from .messages import groups_to_msg, guidance_to_msg
from .people_identity import WALKER, match_people
from .pipeline import calibrate_cmcs_apart
from .walk_guidance import WalkGuide


class GroupSfmNode(StageNode):
    def __init__(self):
        super().__init__(topics.GROUP_SFM_STAGE)
        cameras = [c for c in self.declare_parameter("cameras", [""]).value if c]
        if not cameras:
            raise ValueError("group_sfm_node needs the parameter cameras:=[name, ...]")
        self.estimate = frozenset(c for c in self.declare_parameter("estimate_intrinsics", [""]).value if c)
        unknown = sorted(self.estimate - set(cameras))
        if unknown:
            raise ValueError(f"group_sfm_node: estimate_intrinsics names cameras not in cameras: {', '.join(unknown)}")
        self.cmc = self.section(CmcParams, "cmc")
        self.params = self.cmc.sfm
        self.acc = {c: TrackAccumulator(c) for c in cameras}
        people_cameras = [c for c in self.declare_parameter("people_cameras", [""]).value if c]
        self.people: dict[tuple[str, int], TrackAccumulator] = {}  # (camera, its person) -> frames
        self.people_pub = self.output(String, topics.PEOPLE, LATCHED) if people_cameras else None
        self.last_stamp = 0
        self.pub = self.output(CameraGroupArray, topics.GROUPS, LATCHED)
        self.guide = WalkGuide(cameras, self.cmc.coverage, self.params)
        self.guidance_pub = self.output(WalkGuidance, topics.GUIDANCE)
        self.guidance_ms: list[float] = []  # how long each update of the guidance took
        self.guidance_timer = self.create_timer(self.cmc.coverage.guidance_period_s, self.publish_guidance)
        for cam in cameras:
            streams = [
                (CameraInfo, topics.tracker_camera_info, self.on_camera_info),
                (AgentKeypoints, topics.tracker_keypoints, self.on_keypoints),
            ]
            if cam in people_cameras:
                streams.append((PersonKeypoints, topics.tracker_people, self.on_person))
            for msg_type, topic, handler in streams:
                self.stream_input(
                    msg_type, topic(cam), lambda m, c=cam, h=handler: h(c, m), upstream=topics.tracker_stage(cam)
                )

    def on_person(self, camera: str, msg: PersonKeypoints) -> None:
        self.people.setdefault((camera, int(msg.person)), TrackAccumulator(camera)).add(frame_from_msg(msg))

    def on_camera_info(self, camera: str, msg: CameraInfo) -> None:
        self.acc[camera].take_camera_info(msg)
        self.guide.set_camera(camera, self.acc[camera].camera)

    def on_keypoints(self, camera: str, msg: AgentKeypoints) -> None:
        frame = frame_from_msg(msg)
        self.last_stamp = max(self.last_stamp, frame.stamp_ns)
        kept = self.acc[camera].add(frame)
        if kept is not None:
            self.guide.add(camera, kept.stamp_ns, kept.uv)

    def everyone(self, walkers: list) -> tuple[list, str]:
        """Each camera's tracks with the other people it saw, matched across cameras (those
        matched nowhere left out), and the matches' summary; the matches published."""
        views = {t.name: {WALKER: t} for t in walkers}
        for (cam, person), acc in self.people.items():
            if cam in views and acc.frames:
                acc.camera = views[cam][WALKER].camera
                views[cam][person] = acc.tracks(views[cam][WALKER].frame_period_ns)
        identity = match_people(views, self.params, self.cmc.people)
        self.people_pub.publish(String(data=yaml.safe_dump(identity.as_dict(), sort_keys=False)))
        return identity.tracks, identity.summary()

    def publish_guidance(self, grouping=None) -> None:
        """The walk guidance on what was received so far (none before the first keypoints);
        `grouping`: the final one, with the group SfM's result."""
        if self.guide.last_stamp_ns == 0 or (self.finished and grouping is None):
            return
        started = time.perf_counter()
        coverages = self.guide.coverages(grouping)
        self.guidance_ms.append((time.perf_counter() - started) * 1e3)
        self.guidance_pub.publish(guidance_to_msg(coverages, self.guide.last_stamp_ns, final=grouping is not None))

    def finalize(self) -> str:
        usable = [a for a in self.acc.values() if a.camera is not None and a.frames]
        unusable = {a.name: a.unusable_reason() for a in self.acc.values() if a.camera is None}
        # A tracker that found no walker (or nobody) says why in its summary.
        unusable.update(
            {
                a.name: "its tracker published no agent keypoints: "
                + self.upstream_summaries.get(topics.tracker_stage(a.name), "")
                for a in self.acc.values()
                if a.camera is not None and not a.frames
            }
        )
        tracks = [a.tracks() for a in usable]
        people = ""
        if self.people_pub is not None:
            tracks, people = self.everyone(tracks)
        result = calibrate_cmcs_apart(tracks, self.cmc, self.estimate)
        result.ungrouped.update(unusable)
        self.destroy_timer(self.guidance_timer)
        self.publish_guidance(result)
        self.pub.publish(groups_to_msg(result, self.last_stamp))
        lines = [
            f"{g.group_id}: {', '.join(g.names)} (initial pair {'/'.join(g.initial_pair)}, RMSE "
            + ", ".join(f"{n} {g.rmse_px[n]:.2f}px" for n in g.names)
            + widened_gates(g)
            + estimated_intrinsics(g)
            + ")"
            for g in result.groups
        ]
        lines += [f"{name}: {why}" for name, why in result.ungrouped.items()]
        if people:
            lines.append(people)
        if self.guidance_ms:
            lines.append(
                f"walk guidance: {len(self.guidance_ms)} updates, longest {max(self.guidance_ms):.1f} ms, "
                f"median {float(np.median(self.guidance_ms)):.1f} ms"
            )
        return "; ".join(lines)


def widened_gates(group) -> str:
    if not group.gate_scales:
        return ""
    scales = group.gate_scales.values()
    return (
        f"; reconstructed again with the gates of {len(scales)} noisier keypoint ids widened "
        f"x{min(scales):.1f}-{max(scales):.1f}"
    )


def estimated_intrinsics(group) -> str:
    cams = {n: c for n, c in group.cameras.items() if isinstance(c, EstimatedCamera)}
    return "".join(f"; {n} focal estimated {c.K[0, 0]:.1f} +- {c.focal_sigma_px:.1f} px" for n, c in cams.items())


def main(args=None):
    spin_node(GroupSfmNode, args)


if __name__ == "__main__":
    main()
