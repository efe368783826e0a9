"""keypoint_tracker_node: one per CMC (parameter `camera`, node renamed to
keypoint_tracker_<camera>). Publishes the camera's agent keypoints on
/yowo/cmc/<name>/agent_keypoints for the group SfM (our outputs live under /yowo so
they never loop back into inputs), from one of three sources (parameter `source`):

- `keypoints`: an external detector's /cmc/<name>/agent_keypoints, validated;
- `pose`: the human-pose model on `image_topic` (yowo_cmc.pose_source), or the
  model-free detector for a camera in whose images the model never finds the agent;
- `images`: the built-in model-free detector on `image_topic`.

Its final status says which source the camera used. With `publish_people` (a CMC-only
run), the pose model's other people go out on /yowo/cmc/<name>/people_keypoints. It also
publishes the camera's agent-free background once (latched) when images arrive. Smoothing
and undistortion happen in the group SfM, which sees whole tracks.

Intrinsics, republished latched on /yowo/cmc/<name>/camera_info: the CameraInfo
on `info_topic`; or, with `camera_info` (camera_calibration_parsers YAML text, from an
intrinsics file), those; or, with `info_topic:=""` (no CameraInfo at all), a nominal model
(cmc.nominal_hfov_deg) at the first image's size, which the group SfM then estimates."""

from __future__ import annotations

import time

import numpy as np
import yaml
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header, String

from yowo_common import topics
from yowo_common.camera import CameraModel
from yowo_common.ros.context import spin_node
from yowo_common.ros.stage import DURABLE_STREAM, LATCHED, OWN_SUB, StageNode
from yowo_common.rosconv import (
    camera_info_to_model,
    decode_color,
    encode_raw,
    model_to_camera_info,
    ns_to_time,
    stamp_to_ns,
)
from yowo_msgs.msg import AgentKeypoints, PersonKeypoints, StageStatus

from .config import CmcParams
from .keypoint_input import KeypointFrame, frame_from_msg, frame_to_msg
from .keypoint_tracker import KeypointTracker
from .walker import EgoMotion


class KeypointTrackerNode(StageNode):
    def __init__(self, name: str = "keypoint_tracker"):
        super().__init__(name)
        camera = self.declare_parameter("camera", "").value
        if not camera:
            raise ValueError("keypoint_tracker_node needs the parameter camera:=<name>")
        self.camera = camera
        source = self.declare_parameter("source", "keypoints").value
        image_topic = self.declare_parameter("image_topic", "").value
        # Recorded or driver names of the camera's topics (the planner's input mapping).
        # "": the camera has no CameraInfo (a nominal model from its first image).
        self.info_topic = self.declare_parameter("info_topic", topics.cmc_info_topic(camera)).value
        # camera_calibration_parsers YAML text of an intrinsics file; used instead of info_topic.
        info_text = self.declare_parameter("camera_info", "").value
        keypoints_topic = self.declare_parameter("keypoints_topic", topics.cmc_keypoints_topic(camera)).value
        cmc = self.section(CmcParams, "cmc")
        self.tracker = KeypointTracker(
            camera=camera,
            source=source,
            params=cmc,
            has_images=bool(image_topic),
            camera_info=info_text,
            nominal=not info_text and not self.info_topic,
        )
        self.frame_id = f"{camera}_optical_frame"  # the images' frame, once one arrived
        self.pub = self.output(AgentKeypoints, topics.tracker_keypoints(camera))
        self.pub_background = self.output(Image, topics.tracker_background(camera), LATCHED)
        self.pub_info = self.output(CameraInfo, topics.tracker_camera_info(camera), LATCHED)
        self.pub_walker = self.output(String, topics.tracker_walker(camera), LATCHED)
        # A CMC-only run's pose-model tracker hands on everyone else it saw too.
        self.pub_people = (
            self.output(PersonKeypoints, topics.tracker_people(camera))
            if self.declare_parameter("publish_people", False).value
            else None
        )
        for problem in (self.tracker.problem, getattr(self.tracker.detector, "problem", "")):
            if problem:
                self.get_logger().error(problem)
        if self.tracker.camera is not None:  # from the intrinsics file
            self.publish_info(self.tracker.camera)
        if self.tracker.wants_camera_info:
            self.stream_input(CameraInfo, self.info_topic, self.on_info)
        if self.tracker.detector is None:
            self.stream_input(AgentKeypoints, keypoints_topic, self.on_keypoints)
        # The ego camera's odometry (a run with one, source pose): which person is the walker.
        # Not a counted input: the tracker needs the walk's odometry, not the ego stage's end
        # (its final adjustment runs meanwhile); it waits until the odometry reaches its last
        # image, the ego stage ends, or the odometry stops coming for cmc.people.ego_wait_s.
        self.ego: dict[int, tuple[float, float, float]] = {}  # stamp -> ego camera position
        self.ego_last_ns = 0  # the latest odometry stamp (ready() asks every tick)
        self.ego_done = False
        self.ego_wait_s = cmc.people.ego_wait_s
        self._ego_heard = time.monotonic()
        self.last_image_ns = 0
        odometry_topic = self.declare_parameter("ego_odometry_topic", "").value
        self.wants_ego = bool(odometry_topic) and self.tracker.needs_ego
        if self.wants_ego:
            self.create_subscription(Odometry, odometry_topic, self.on_odometry, DURABLE_STREAM, **OWN_SUB)
            self.create_subscription(
                StageStatus, topics.status(topics.EGO_STAGE), self.on_ego_status, LATCHED, **OWN_SUB
            )
        # With external keypoints, images (when recorded) only give the background for scene keypoints.
        if image_topic:
            msg_type = CompressedImage if image_topic.endswith("/compressed") else Image
            self.stream_input(msg_type, image_topic, self.on_image)

    def on_image(self, msg) -> None:
        self.frame_id = msg.header.frame_id or self.frame_id
        self.last_image_ns = max(self.last_image_ns, stamp_to_ns(msg.header.stamp))
        frames, nominal = self.tracker.take_image(stamp_to_ns(msg.header.stamp), lambda: decode_color(msg))
        if nominal is not None:
            self.publish_info(nominal)
        self.publish_frames(frames)

    def on_odometry(self, msg: Odometry) -> None:
        p = msg.pose.pose.position
        stamp = stamp_to_ns(msg.header.stamp)
        self.ego[stamp] = (p.x, p.y, p.z)  # a restarted ego stage repeats stamps
        self.ego_last_ns = max(self.ego_last_ns, stamp)
        self._ego_heard = time.monotonic()

    def on_ego_status(self, msg: StageStatus) -> None:
        if self.runs.accept(msg) and msg.state in (StageStatus.STATE_FINISHED, StageStatus.STATE_FAILED):
            self.ego_done = True

    def ready(self) -> bool:
        if not self.wants_ego or self.ego_done:
            return True
        if self.ego and self.ego_last_ns >= self.last_image_ns:
            return True
        if time.monotonic() - self._ego_heard > self.ego_wait_s:
            self.get_logger().warning(
                f"no ego odometry for {self.ego_wait_s:.0f} s: the walker is told by the odometry so far"
            )
            return True
        return False

    def on_info(self, msg: CameraInfo) -> None:
        if not self.tracker.wants_camera_info:
            return
        try:
            self.set_camera(camera_info_to_model(msg), msg)
        except ValueError as exc:
            self.tracker.problem = f"{self.info_topic}: {exc}"
            self.get_logger().error(self.tracker.problem)
            self.pub_info.publish(msg)  # relayed: the stages downstream report the reason

    def set_camera(self, camera: CameraModel, msg: CameraInfo) -> None:
        frames = self.tracker.take_camera(camera)
        self.publish_info(camera, msg)
        self.publish_frames(frames)

    def publish_info(self, camera: CameraModel, msg: CameraInfo | None = None) -> None:
        """The camera's intrinsics, published latched (the received CameraInfo as it came)."""
        self.pub_info.publish(
            msg if msg is not None else model_to_camera_info(camera, Header(frame_id=f"{self.camera}_optical_frame"))
        )

    def on_keypoints(self, msg: AgentKeypoints) -> None:
        kept = self.tracker.take_keypoints(frame_from_msg(msg))
        if kept is None:
            return
        self.pub.publish(frame_to_msg(kept, self.camera, msg.header.frame_id))

    def publish_frames(self, frames: list[KeypointFrame]) -> None:
        for f in frames:
            self.pub.publish(frame_to_msg(f, self.camera, self.frame_id))

    def finalize(self) -> str:
        ego = None
        if self.ego:
            stamps = sorted(self.ego)
            ego = EgoMotion(stamps_ns=np.asarray(stamps), positions=np.asarray([self.ego[s] for s in stamps]))
        self.publish_frames(self.tracker.flush(ego))
        if self.pub_people is not None:
            for person, frames in self.tracker.others().items():
                for f in frames:
                    msg = frame_to_msg(f, self.camera, self.frame_id)
                    self.pub_people.publish(
                        PersonKeypoints(
                            header=msg.header, camera_name=self.camera, person=person, keypoints=msg.keypoints
                        )
                    )
        walker = self.tracker.walker()
        if walker is not None:
            self.pub_walker.publish(String(data=yaml.safe_dump(walker, sort_keys=False)))
        summary, background = self.tracker.summary(), self.tracker.background()
        if background is None:
            return summary
        frames = self.tracker.acc.frames
        self.pub_background.publish(
            encode_raw(
                background,
                "rgb8",
                Header(stamp=ns_to_time(frames[-1].stamp_ns if frames else 0), frame_id=self.frame_id),
            )
        )
        return f"{summary}; background published"


def main(args=None):
    spin_node(KeypointTrackerNode, args)


if __name__ == "__main__":
    main()
