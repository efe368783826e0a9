"""ego_mapper_node: the head-mounted RGB-D stream (and its IMU, when the plan names
one) -> frame-to-frame odometry online on /yowo/ego/odometry, and at the end of the
walk the ego map (EgoMap), the map point cloud, the ego path and the scene layout,
all latched. With an IMU, each frame waits for the samples covering its stamp (topics
arrive in no common order: rclpy's executor takes one message per subscription in
turn, so the 200 Hz IMU falls seconds behind the frames of a fast replay); frames the
IMU never covers are tracked without it at the end of the stream. No bound in stream
time: it would make the result depend on timing (a replay gives the same map every run)."""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from nav_msgs.msg import Odometry, Path
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, Imu, PointCloud2
from std_msgs.msg import Header, String

from yowo_common import topics
from yowo_common.ros.context import spin_node
from yowo_common.ros.stage import LATCHED, StageNode
from yowo_common.rosconv import (
    camera_info_to_model,
    decode_color,
    decode_depth,
    matrix_to_pose,
    ns_to_time,
    stamp_to_ns,
)
from yowo_msgs.msg import EgoMap, SceneLayout

from .config import EgoParams
from .ego_messages import cloud_msg, ego_map_msg, layout_msg, path_msg
from .frames import FrameError, StampPairer
from .imu import CoverageWait, ImuBuffer, ImuCalibration, ImuUniter
from .pipeline import EgoMapper

MAX_EARLY_FRAMES = 30  # frames kept while waiting for the first CameraInfo
# Online odometry is expressed in the first ego camera's optical frame: gravity and
# the map frame are only known once the floor has been found at the end of the walk.
ODOM_FRAME, EGO_FRAME = "odom", "ego_optical_frame"


@dataclass
class _Queued:
    """An admitted frame pair waiting for tracking: being prepared ahead (``future``), or
    not (predicted to be skipped: prepared only should it be tracked after all)."""

    stamp_ns: int
    color_msg: object
    depth_msg: object
    future: Future | None


class EgoMapperNode(StageNode):
    def __init__(self):
        super().__init__(topics.EGO_STAGE)
        self.color_topic = self.declare_parameter("color_topic", topics.EGO_COLOR[1]).value
        self.depth_topic = self.declare_parameter("depth_topic", topics.EGO_DEPTH[1]).value
        self.info_topic = self.declare_parameter("info_topic", topics.EGO_INFO).value
        # "": no IMU. The planner names one united Imu topic, or a driver's separate gyro and
        # accelerometer topics, when it knows the IMU's calibration.
        self.imu_topic = self.declare_parameter("imu_topic", "").value
        self.gyro_topic = self.declare_parameter("gyro_topic", "").value
        self.accel_topic = self.declare_parameter("accel_topic", "").value
        self.imu_calibration_topic = self.declare_parameter("imu_calibration_topic", topics.EGO_IMU_CALIBRATION).value
        # The calibration as text (Kalibr's keys), when the planner found it elsewhere than on
        # imu_calibration_topic (Kalibr files, /tf_static).
        imu_calibration = self.declare_parameter("imu_calibration", "").value
        self.params = self.section(EgoParams, "ego")
        use_imu = bool(self.imu_topic or (self.gyro_topic and self.accel_topic)) and self.params.odometry.use_imu
        self.imu = ImuBuffer() if use_imu else None
        self.uniter = ImuUniter()
        self.imu_problem = ""
        self.wait = CoverageWait(self.imu, None)
        self.mapper: EgoMapper | None = None
        self.info_problem = ""
        self.early: list[tuple[int, object, object]] = []
        self.early_dropped = 0  # frames beyond MAX_EARLY_FRAMES before the first CameraInfo
        self.pairer = StampPairer()
        # Decoding, undistorting and downsampling a frame (EgoMapper.prepare) on a thread of its
        # own overlaps the previous frame's tracking (OpenCV and Open3D release the GIL);
        # tracking stays in stamp order. A frame predicted to be skipped (slow motion,
        # ego.odometry.skip) is not prepared unless it is tracked after all.
        self.preparer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ego_prepare")
        self.preparing: deque[_Queued] = deque()
        self.logged_problems: set[str] = set()
        self.pub_odom = self.output(Odometry, topics.EGO_ODOMETRY)
        self.pub_map = self.output(EgoMap, topics.EGO_MAP, LATCHED)
        self.pub_path = self.output(Path, topics.EGO_PATH, LATCHED)
        self.pub_cloud = self.output(PointCloud2, topics.MAP_POINTS, LATCHED)
        self.pub_layout = self.output(SceneLayout, topics.LAYOUT, LATCHED)
        image_type = lambda t: CompressedImage if t.endswith(("/compressed", "/compressedDepth")) else Image  # noqa: E731
        self.stream_input(CameraInfo, self.info_topic, self.on_info)
        self.stream_input(
            image_type(self.color_topic),
            self.color_topic,
            lambda m: self.on_waiting(self.pairer.add_color(stamp_to_ns(m.header.stamp), m)),
        )
        self.stream_input(
            image_type(self.depth_topic),
            self.depth_topic,
            lambda m: self.on_waiting(self.pairer.add_depth(stamp_to_ns(m.header.stamp), m)),
        )
        if self.imu is not None:
            if self.imu_topic:
                self.stream_input(Imu, self.imu_topic, self.on_imu)
            else:
                self.stream_input(Imu, self.gyro_topic, self.on_gyro)
                self.stream_input(Imu, self.accel_topic, self.on_accel)
            if imu_calibration:
                self.on_imu_calibration(String(data=imu_calibration), "the run's IMU calibration")
            else:
                self.stream_input(String, self.imu_calibration_topic, self.on_imu_calibration)

    def on_imu(self, msg: Imu) -> None:
        v, a = msg.angular_velocity, msg.linear_acceleration
        self._add_imu([(stamp_to_ns(msg.header.stamp), (v.x, v.y, v.z), (a.x, a.y, a.z))])

    def on_gyro(self, msg: Imu) -> None:
        v = msg.angular_velocity
        self._add_imu(self.uniter.add_gyro(stamp_to_ns(msg.header.stamp), (v.x, v.y, v.z)))

    def on_accel(self, msg: Imu) -> None:
        a = msg.linear_acceleration
        self._add_imu(self.uniter.add_accel(stamp_to_ns(msg.header.stamp), (a.x, a.y, a.z)))

    def _add_imu(self, samples) -> None:
        for stamp_ns, gyro, accel in samples:
            self.imu.add(stamp_ns, gyro, accel)
        if samples:
            self.on_pairs(self.wait.ready())

    def on_imu_calibration(self, msg: String, where: str = "") -> None:
        if self.imu.calibration is None and not self.imu_problem:
            try:
                self.imu.calibration = ImuCalibration.from_yaml(msg.data, where or self.imu_calibration_topic)
            except ValueError as exc:
                self.imu_problem = f"{exc}; the IMU is not used"
                self.get_logger().error(self.imu_problem)
                self.wait.imu = None  # nothing to wait for
        self.on_pairs(self.wait.ready())

    def on_waiting(self, pairs) -> None:
        """Frame pairs to track once the IMU covers them (at once without an IMU)."""
        self.on_pairs([r for pair in pairs for r in self.wait.push(pair[0], pair)])

    def on_info(self, msg: CameraInfo) -> None:
        if self.mapper is not None or self.info_problem or self.finished:
            return
        try:
            self.mapper = EgoMapper(camera_info_to_model(msg), self.params, self.info_topic, self.imu)
        except ValueError as exc:
            self.info_problem = f"{self.info_topic}: {exc}"
            self.get_logger().error(self.info_problem)
            return
        pending, self.early = self.early, []
        self.on_pairs(pending)

    def on_pairs(self, pairs) -> None:
        if self.mapper is None:
            self.early += pairs
            if len(self.early) > MAX_EARLY_FRAMES:
                if not self.early_dropped:
                    self.get_logger().warning(
                        f"no usable {self.info_topic} yet: keeping the last {MAX_EARLY_FRAMES} "
                        "frames, dropping older ones"
                    )
                self.early_dropped += len(self.early) - MAX_EARLY_FRAMES
                self.early = self.early[-MAX_EARLY_FRAMES:]
            return
        for stamp, color_msg, depth_msg in pairs:
            try:
                self.mapper.admit(stamp, self.color_topic)
            except FrameError as exc:
                self._log_problem(exc)
                continue
            # Whether it will be skipped is known for certain only once the frames before it are
            # tracked; the prediction decides only whether it is prepared ahead.
            ahead = not self.mapper.skips(stamp, tuple(q.stamp_ns for q in self.preparing))
            future = self.preparer.submit(self._prepare, stamp, color_msg, depth_msg) if ahead else None
            self.preparing.append(_Queued(stamp, color_msg, depth_msg, future))
        self._track_prepared(keep=1)

    def _prepare(self, stamp: int, color_msg, depth_msg):
        """Decoded, checked, undistorted, odometry images made (EgoMapper.prepare): on the
        preparing thread, or on this one for a frame not prepared ahead."""
        color = self._decode(self.color_topic, color_msg, decode_color, stamp)
        depth = self._decode(self.depth_topic, depth_msg, decode_depth, stamp)
        return self.mapper.prepare(stamp, color, depth, self.color_topic, self.depth_topic, admitted=True)

    def _prepared(self, queued: _Queued):
        if queued.future is not None:
            return queued.future.result()
        return self._prepare(queued.stamp_ns, queued.color_msg, queued.depth_msg)

    def _log_problem(self, exc: FrameError) -> None:
        """Counted (reported in the final status); logged the first time it happens."""
        if exc.key not in self.logged_problems:
            self.logged_problems.add(exc.key)
            self.get_logger().warning(f"{exc}; further frames with this problem are only counted")

    def _track_prepared(self, keep: int) -> None:
        """Track (or skip) the queued frames in order, all but the newest ``keep`` (still
        being prepared while the one before is tracked); publish the odometry of every
        frame settled (a skipped frame's once the next is tracked)."""
        while len(self.preparing) > keep:
            queued = self.preparing.popleft()
            if self.mapper.skips(queued.stamp_ns):
                self.mapper.skip(queued.stamp_ns, lambda q=queued: self._prepared(q))
                continue
            try:
                frame = self._prepared(queued)
            except FrameError as exc:
                self._log_problem(exc)
                continue
            self.mapper.track(frame)
            for result in self.mapper.settled():
                self.pub_odom.publish(self._odometry(result))

    def _decode(self, topic: str, msg, decode, stamp_ns: int):
        try:
            return decode(msg)
        except ValueError as exc:
            error = FrameError(topic, "cannot decode the image", f": {exc}", stamp_ns)
            self.mapper.reject(error)
            raise error from exc

    def _odometry(self, result) -> Odometry:
        msg = Odometry(header=Header(stamp=ns_to_time(result.stamp_ns), frame_id=ODOM_FRAME), child_frame_id=EGO_FRAME)
        msg.pose.pose = matrix_to_pose(result.T_odom_cam)
        return msg

    def finalize(self) -> str:
        self.on_pairs(self.wait.ready(flush=True))
        self._track_prepared(keep=0)
        self.preparer.shutdown()
        if self.mapper is None:
            waited = len(self.early) + self.early_dropped
            raise ValueError(
                self.info_problem
                or f"no usable {self.info_topic} received ({waited} frame(s) waited for it); no ego map"
            )
        r = self.mapper.finish()  # tracks a skipped frame that ends the walk
        for result in self.mapper.settled():
            self.pub_odom.publish(self._odometry(result))
        self.pub_map.publish(ego_map_msg(r))
        self.pub_path.publish(path_msg(r.stamps_ns, r.T_world_cam))
        self.pub_cloud.publish(cloud_msg(r))
        self.pub_layout.publish(layout_msg(r))
        text = (
            f"{len(r.stamps_ns)} frames, {len(r.keyframe_frames)} keyframes, {len(r.landmarks)} landmarks, "
            f"{len(r.cloud_points)} cloud points, {len(r.layout.floor_polygons)} floor polygon(s)"
        )
        self.mapper = None  # published: the keyframes' images can go
        # Input the map was made without: unpaired images (the offline reader reports the same) and the IMU.
        lost = [self.pairer.problem(self.color_topic, self.depth_topic)] if self.pairer.dropped else []
        if self.early_dropped:
            lost.append(
                f"{self.early_dropped} frame(s) before the first usable {self.info_topic} dropped "
                f"(the last {MAX_EARLY_FRAMES} were kept)"
            )
        if self.imu_problem:
            lost.append(self.imu_problem)
        if self.wait.released_without:
            imu = self.imu_topic or f"{self.gyro_topic} with {self.accel_topic}"
            lost.append(
                f"{self.wait.released_without} frame(s) tracked without the IMU: {imu} did not cover their stamps"
            )
        return "; ".join([text, *r.warnings, *lost])


def main(args=None):
    spin_node(EgoMapperNode, args)


if __name__ == "__main__":
    main()
