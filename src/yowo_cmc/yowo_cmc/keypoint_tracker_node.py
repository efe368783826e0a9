"""keypoint_tracker_node: one per CMC (parameter `camera`, node renamed to
keypoint_tracker_<camera>). Validates the agent keypoints of an external detector
on /cmc/<name>/agent_keypoints and passes them on to /yowo/cmc/<name>/agent_keypoints
for the group SfM (our outputs live under /yowo so they never loop back into inputs).
Smoothing and undistortion happen in the group SfM, which sees whole tracks."""
from __future__ import annotations

from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header
from yowo_msgs.msg import AgentKeypoints

from yowo_common import topics
from yowo_common.ros.context import spin_node
from yowo_common.ros.stage import LATCHED, StageNode
from yowo_common.rosconv import camera_info_to_model, decode_color, encode_raw, ns_to_time, stamp_to_ns

from .background import BackgroundSampler
from .keypoint_input import TrackAccumulator, frame_from_msg


class KeypointTrackerNode(StageNode):
    def __init__(self):
        super().__init__("keypoint_tracker")
        camera = self.declare_parameter("camera", "").value
        if not camera:
            raise ValueError("keypoint_tracker_node needs the parameter camera:=<name>")
        self.camera = camera
        self.source = self.declare_parameter("source", "keypoints").value
        if self.source != "keypoints":
            raise ValueError(f"camera '{camera}': source '{self.source}' is not available; "
                             "the image-based detector is not implemented yet (use source:=keypoints)")
        self.acc = TrackAccumulator(camera)
        self.info_problem = ""
        self.pub = self.output(AgentKeypoints, topics.tracker_keypoints(camera))
        self.pub_background = self.output(Image, topics.tracker_background(camera), LATCHED)
        self.stream_input(CameraInfo, f"/cmc/{camera}/camera_info", self.on_info)
        self.stream_input(AgentKeypoints, f"/cmc/{camera}/agent_keypoints", self.on_keypoints)
        # The agent-free background (for scene keypoints in fusion), when images were recorded.
        image_topic = self.declare_parameter("image_topic", "").value
        self.background = BackgroundSampler(self.declare_parameter("background_period_s", 1.0).value)
        if image_topic:
            msg_type = CompressedImage if image_topic.endswith("/compressed") else Image
            self.stream_input(msg_type, image_topic, self.on_image)

    def on_image(self, msg) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        if self.background.wants(stamp):
            self.background.add(stamp, decode_color(msg))

    def on_info(self, msg: CameraInfo) -> None:
        if self.acc.camera is None:
            try:
                self.acc.camera = camera_info_to_model(msg)
            except ValueError as exc:
                if not self.info_problem:
                    self.info_problem = f"/cmc/{self.camera}/camera_info: {exc}"
                    self.get_logger().error(self.info_problem)

    def on_keypoints(self, msg: AgentKeypoints) -> None:
        kept = self.acc.add(frame_from_msg(msg))
        if kept is None:
            return
        out = AgentKeypoints(header=msg.header, camera_name=self.camera,
                             keypoints=[k for k in msg.keypoints if k.id in set(kept.ids.tolist())])
        self.pub.publish(out)

    def finalize(self) -> str:
        text = self.acc.summary() + (f"; {self.info_problem}" if self.info_problem else "")
        background = self.background.image()
        if background is not None:
            self.pub_background.publish(encode_raw(background, "rgb8", Header(
                stamp=ns_to_time(self.background.last_stamp), frame_id=f"{self.camera}_optical_frame")))
            text += f"; background from {self.background.count} frames"
        return text


def main(args=None):
    spin_node(KeypointTrackerNode, args)


if __name__ == "__main__":
    main()
