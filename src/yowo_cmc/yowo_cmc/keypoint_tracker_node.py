"""keypoint_tracker_node: one per CMC (parameter `camera`, node renamed to
keypoint_tracker_<camera>). Publishes the camera's agent keypoints on
/yowo/cmc/<name>/agent_keypoints for the group SfM (our outputs live under /yowo so
they never loop back into inputs), from one of three sources (parameter `source`):

- `keypoints`: an external detector's /cmc/<name>/agent_keypoints, validated;
- `pose`: the human-pose model on `image_topic` (yowo_cmc.pose_model), or the
  model-free detector for a camera in whose images the model never finds the agent;
- `images`: the built-in model-free detector on `image_topic`.

Its final status says which source the camera used. It also publishes the camera's
agent-free background once (latched) when images arrive. Smoothing and undistortion
happen in the group SfM, which sees whole tracks.

Intrinsics, republished latched on /yowo/cmc/<name>/tracker_camera_info: the CameraInfo
on `info_topic`; or, with `camera_info` (camera_calibration_parsers YAML text, from an
intrinsics file), those; or, with `info_topic:=""` (no CameraInfo at all), a nominal model
(cmc.nominal_hfov_deg) at the first image's size, which the group SfM then estimates."""
from __future__ import annotations

from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header

from yowo_common import topics
from yowo_common.camera import CameraModel
from yowo_common.intrinsics_io import intrinsics_from_text
from yowo_common.ros.context import spin_node
from yowo_common.ros.stage import LATCHED, StageNode
from yowo_common.rosconv import (
    camera_info_to_model,
    decode_color,
    encode_raw,
    model_to_camera_info,
    ns_to_time,
    stamp_to_ns,
)
from yowo_msgs.msg import AgentKeypoints

from .background import BackgroundSampler
from .config import CmcParams
from .keypoint_input import ImageKeypointSource, KeypointFrame, TrackAccumulator, frame_from_msg, frame_to_msg
from .pose_model import PoseOrDetectorSource

SOURCES = ("keypoints", "pose", "images")


class KeypointTrackerNode(StageNode):
    def __init__(self, name: str = "keypoint_tracker"):
        super().__init__(name)
        camera = self.declare_parameter("camera", "").value
        if not camera:
            raise ValueError("keypoint_tracker_node needs the parameter camera:=<name>")
        self.camera = camera
        self.source = self.declare_parameter("source", "keypoints").value
        image_topic = self.declare_parameter("image_topic", "").value
        # Recorded or driver names of the camera's topics (the planner's input mapping).
        # "": the camera has no CameraInfo (a nominal model from its first image).
        self.info_topic = self.declare_parameter("info_topic", topics.cmc_info_topic(camera)).value
        # camera_calibration_parsers YAML text of an intrinsics file; used instead of info_topic.
        info_text = self.declare_parameter("camera_info", "").value
        keypoints_topic = self.declare_parameter("keypoints_topic", topics.cmc_keypoints_topic(camera)).value
        if self.source not in SOURCES:
            raise ValueError(f"camera '{camera}': unknown source '{self.source}' (choose from {', '.join(SOURCES)})")
        if self.source in ("images", "pose") and not image_topic:
            raise ValueError(f"camera '{camera}': source:={self.source} needs image_topic:=<topic>")
        self.acc = TrackAccumulator(camera)
        params = self.section(CmcParams, "cmc")
        self.nominal_hfov_deg = params.nominal_hfov_deg
        self.info_problem = ""
        self.frame_id = f"{camera}_optical_frame"    # the images' frame, once one arrived
        self.pub = self.output(AgentKeypoints, topics.tracker_keypoints(camera))
        self.pub_background = self.output(Image, topics.tracker_background(camera), LATCHED)
        self.pub_info = self.output(CameraInfo, topics.tracker_camera_info(camera), LATCHED)
        self.nominal = not info_text and not self.info_topic   # a nominal model from the first image
        if self.nominal and not image_topic:
            self.info_problem = (f"camera '{camera}': no CameraInfo (info_topic empty), no intrinsics file and no "
                                 "images, so its image size is unknown: the camera is left out")
            self.get_logger().error(self.info_problem)
        elif self.info_topic and not info_text:
            self.stream_input(CameraInfo, self.info_topic, self.on_info)
        self.detector = (ImageKeypointSource(camera, params.detector, params.max_pending_frames)
                         if self.source == "images" else
                         PoseOrDetectorSource(camera, params.pose, params.pose_min_frames, params.detector,
                                              params.max_pending_frames) if self.source == "pose" else None)
        if self.source == "pose" and self.detector.problem:
            self.get_logger().error(self.detector.problem)
        if self.detector is None:
            self.stream_input(AgentKeypoints, keypoints_topic, self.on_keypoints)
        # With external keypoints, images (when recorded) only give the background for scene keypoints.
        self.background = BackgroundSampler(params.background_period_s)
        if image_topic:
            msg_type = CompressedImage if image_topic.endswith("/compressed") else Image
            self.stream_input(msg_type, image_topic, self.on_image)
        if info_text:
            try:
                self.set_camera(intrinsics_from_text(info_text, f"camera '{camera}': parameter camera_info"))
            except ValueError as exc:
                self.info_problem = str(exc)
                self.get_logger().error(self.info_problem)

    def on_image(self, msg) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        rgb = None
        if self.nominal and self.acc.camera is None:
            rgb = decode_color(msg)
            self.set_camera(CameraModel.from_fov(rgb.shape[1], rgb.shape[0], self.nominal_hfov_deg))
        if self.detector is None and not self.background.wants(stamp):
            return
        rgb = decode_color(msg) if rgb is None else rgb
        if self.detector is not None:
            self.frame_id = msg.header.frame_id or self.frame_id
            self.publish_frames(self.detector.push(stamp, rgb))
        if self.background.wants(stamp) and (self.detector is None or self.source == "pose"):
            self.background.add(stamp, rgb)      # the pose model needs no background; the scene keypoints do

    def on_info(self, msg: CameraInfo) -> None:
        if self.acc.camera is None and not self.info_problem:
            try:
                self.set_camera(camera_info_to_model(msg), msg)
            except ValueError as exc:
                self.info_problem = f"{self.info_topic}: {exc}"
                self.get_logger().error(self.info_problem)
                self.pub_info.publish(msg)    # relayed: the stages downstream report the reason

    def set_camera(self, camera: CameraModel, msg: CameraInfo | None = None) -> None:
        """The camera's intrinsics, published latched (the received CameraInfo as it came)."""
        self.acc.camera = camera
        self.pub_info.publish(msg if msg is not None else model_to_camera_info(
            camera, Header(frame_id=f"{self.camera}_optical_frame")))
        if self.detector is not None:
            self.publish_frames(self.detector.set_camera(camera))

    def on_keypoints(self, msg: AgentKeypoints) -> None:
        kept = self.acc.add(frame_from_msg(msg))
        if kept is None:
            return
        out = AgentKeypoints(header=msg.header, camera_name=self.camera,
                             keypoints=[k for k in msg.keypoints if k.id in set(kept.ids.tolist())])
        self.pub.publish(out)

    def publish_frames(self, frames: list[KeypointFrame]) -> None:
        for f in frames:
            kept = self.acc.add(f)
            if kept is not None:
                self.pub.publish(frame_to_msg(kept, self.camera, self.frame_id))

    def finalize(self) -> str:
        background, parts = self.background.image(), ["source: recorded keypoints", self.acc.summary()]
        if self.detector is not None:
            self.publish_frames(self.detector.flush())
            background = self.detector.background if self.detector.background is not None else background
            parts = [self.detector.summary() if self.source == "pose" else
                     f"source: model-free detector; {self.detector.summary()}", self.acc.summary()]
        if self.info_problem:
            parts.append(self.info_problem)
        if background is not None:
            self.pub_background.publish(encode_raw(background, "rgb8", Header(
                stamp=ns_to_time(self.acc.frames[-1].stamp_ns if self.acc.frames else 0),
                frame_id=self.frame_id)))
            parts.append("background published")
        return "; ".join(p for p in parts if p)


def main(args=None):
    spin_node(KeypointTrackerNode, args)


if __name__ == "__main__":
    main()
