"""Ego frames (and the ego IMU's samples, when recorded) from a rosbag2 recording
for the offline entry ``map_recording`` (bag I/O through yowo_common.ros.bag, which
deserialises with rclpy; the algorithm modules never import it)."""

from __future__ import annotations

import itertools
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from yowo_common.camera import CameraModel
from yowo_common.ros.bag import list_topics, read_messages
from yowo_common.rosconv import camera_info_to_model, decode_color, decode_depth, stamp_to_ns
from yowo_common.topics import EGO_COLOR, EGO_DEPTH, EGO_IMU, EGO_IMU_CALIBRATION, EGO_INFO

from .config import EgoParams
from .frames import StampPairer
from .imu import CoverageWait, ImuBuffer, ImuCalibration, ImuUniter
from .pipeline import EgoMapResult, map_recording

COLOR_TOPICS, DEPTH_TOPICS, INFO_TOPIC = EGO_COLOR, EGO_DEPTH, EGO_INFO


@dataclass(kw_only=True)
class EgoTopics:
    color: str
    depth: str
    info: str = INFO_TOPIC
    imu: str = ""  # one sensor_msgs/Imu topic; "" when the recording has no usable united IMU
    gyro: str = ""  # separate gyro and accelerometer streams (a driver's), united as read
    accel: str = ""
    imu_calibration: str = ""  # the topic with the IMU's calibration (String YAML)
    imu_calibration_text: str = ""  # or the calibration itself (Kalibr files, /tf_static)

    @property
    def has_imu(self) -> bool:
        return bool(self.imu or (self.gyro and self.accel)) and bool(self.imu_calibration or self.imu_calibration_text)

    @classmethod
    def from_node_parameters(cls, parameters: dict) -> EgoTopics:
        """The topics the run's plan gives the ego mapper node (yowo_bringup.run)."""
        return cls(
            color=parameters["color_topic"],
            depth=parameters["depth_topic"],
            info=parameters["info_topic"],
            imu=parameters.get("imu_topic", ""),
            gyro=parameters.get("gyro_topic", ""),
            accel=parameters.get("accel_topic", ""),
            imu_calibration=parameters.get("imu_calibration_topic", "") or EGO_IMU_CALIBRATION,
            imu_calibration_text=parameters.get("imu_calibration", ""),
        )


@dataclass
class EgoRecording:
    """Frames of one recording; ``camera`` is known once the first CameraInfo was read."""

    topics: EgoTopics
    camera: CameraModel | None = None
    problems: list[str] = field(default_factory=list)
    imu: ImuBuffer | None = None  # filled while the frames are read (topics.imu set)


def find_ego_topics(bag) -> EgoTopics:
    present = {t.name for t in list_topics(bag) if t.count > 0}
    color = next((t for t in COLOR_TOPICS if t in present), None)
    depth = next((t for t in DEPTH_TOPICS if t in present), None)
    missing = [
        what
        for what, t in (("colour " + " or ".join(COLOR_TOPICS), color), ("depth " + " or ".join(DEPTH_TOPICS), depth))
        if t is None
    ]
    if INFO_TOPIC not in present:
        missing.append(INFO_TOPIC)
    if missing:
        raise ValueError(f"{bag}: no ego camera: missing {'; '.join(missing)}")
    imu = EGO_IMU in present and EGO_IMU_CALIBRATION in present
    return EgoTopics(
        color=color, depth=depth, imu=EGO_IMU if imu else "", imu_calibration=EGO_IMU_CALIBRATION if imu else ""
    )


def read_ego_frames(
    bag, recording: EgoRecording, imu_wait_s: float = 0.5
) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(stamp_ns, RGB, depth m) pairs in stamp order; undecodable messages and a
    bad CameraInfo are recorded in ``recording.problems``. Frames arriving before
    the first CameraInfo are held back until it comes. With ``recording.imu``, its
    samples are appended as they are read and a frame is yielded once they cover its
    stamp (or ``imu_wait_s`` of frames later without)."""
    t = recording.topics
    pairer = StampPairer()
    pending: list[tuple[int, np.ndarray, np.ndarray]] = []
    imu = recording.imu
    wait = CoverageWait(imu, int(imu_wait_s * 1e9))
    uniter = ImuUniter()
    streams = [s for s in (t.imu, t.gyro, t.accel) if s]
    wanted = [t.color, t.depth, t.info] + (streams + [t.imu_calibration] if imu is not None else [])
    if imu is not None and t.imu_calibration_text:
        try:
            imu.calibration = ImuCalibration.from_yaml(t.imu_calibration_text, "the run's IMU calibration")
        except ValueError as exc:
            recording.problems.append(f"{exc}; the IMU is not used")
            wait.imu = None
    for topic, _, msg in read_messages(bag, wanted):
        if topic == t.info:
            if recording.camera is None:
                try:
                    recording.camera = camera_info_to_model(msg)
                except ValueError as exc:
                    problem = f"{t.info}: {exc}"
                    if problem not in recording.problems:
                        recording.problems.append(problem)
            continue
        if topic in streams:
            stamp, v, a = stamp_to_ns(msg.header.stamp), msg.angular_velocity, msg.linear_acceleration
            if topic == t.imu:
                samples = [(stamp, (v.x, v.y, v.z), (a.x, a.y, a.z))]
            else:
                samples = (
                    uniter.add_gyro(stamp, (v.x, v.y, v.z))
                    if topic == t.gyro
                    else uniter.add_accel(stamp, (a.x, a.y, a.z))
                )
            for sample in samples:
                imu.add(*sample)
            released = wait.ready()
        elif topic == t.imu_calibration:
            if imu.calibration is None and wait.imu is not None:
                try:
                    imu.calibration = ImuCalibration.from_yaml(msg.data, topic)
                except ValueError as exc:
                    recording.problems.append(f"{exc}; the IMU is not used")
                    wait.imu = None  # nothing to wait for
            released = wait.ready()
        else:
            stamp = stamp_to_ns(msg.header.stamp)
            try:
                image = decode_color(msg) if topic == t.color else decode_depth(msg)
            except ValueError as exc:
                recording.problems.append(f"{topic} @ {stamp} ns: {exc}")
                continue
            pairs = pairer.add_color(stamp, image) if topic == t.color else pairer.add_depth(stamp, image)
            released = [r for pair in pairs for r in wait.push(pair[0], pair)]
        pending.extend(released)
        if recording.camera is not None:
            yield from pending
            pending.clear()
    if recording.camera is None:
        if not any(p.startswith(t.info) for p in recording.problems):
            recording.problems.append(f"{t.info}: no CameraInfo in the recording")
        return
    yield from pending + wait.ready(flush=True)
    if wait.released_without:
        recording.problems.append(
            f"{wait.released_without} frame(s) tracked without the IMU: {t.imu} did not cover "
            f"their stamps within {imu_wait_s:g} s"
        )
    if pairer.dropped:
        recording.problems.append(pairer.problem(t.color, t.depth))


def prefetch(items: Iterator, depth: int = 8) -> Iterator:
    """``items`` produced on a background thread, ``depth`` ahead of the consumer:
    image decoding (OpenCV releases the GIL) overlaps with tracking (so does
    Open3D). Exceptions of the producer are raised in the consumer."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    done = object()
    stop = threading.Event()

    def produce():
        try:
            for item in items:
                if stop.is_set():
                    return
                q.put(item)
        except BaseException as exc:  # handed over to the consumer
            q.put(exc)
        q.put(done)

    thread = threading.Thread(target=produce, name="ego_decode", daemon=True)
    thread.start()
    try:
        while (item := q.get()) is not done:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        while thread.is_alive():  # unblock a producer waiting on a full queue
            try:
                q.get_nowait()
            except queue.Empty:
                thread.join(0.01)


def map_bag(bag, params: EgoParams = EgoParams(), topics: EgoTopics | None = None) -> tuple[EgoMapResult, EgoRecording]:
    """``map_recording`` on a recording's ego frames, with its IMU (and its calibration)
    when recorded and ``params.odometry.use_imu``. `topics`: which recorded topics are the
    ego camera's and its IMU's (a driver's layout, as the run's plan maps it); default
    YOWO's own names. Raises ValueError naming the topic when nothing usable exists (no
    ego topics, no valid CameraInfo, no frames)."""
    recording = EgoRecording(topics or find_ego_topics(bag))
    if recording.topics.has_imu and params.odometry.use_imu:
        recording.imu = ImuBuffer()
    elif EGO_IMU in {t.name for t in list_topics(bag) if t.count > 0} and not recording.topics.has_imu:
        recording.problems.append(
            f"{EGO_IMU} without {EGO_IMU_CALIBRATION}: the IMU's extrinsics are unknown; tracking without it"
        )
    frames = prefetch(read_ego_frames(bag, recording, params.odometry.imu_wait_s))
    first = next(frames, None)
    if first is None:
        raise ValueError(f"{bag}: no usable ego frames: " + ("; ".join(recording.problems) or "none recorded"))
    result = map_recording(
        itertools.chain([first], frames),
        recording.camera,
        params,
        recording.topics.color,
        recording.topics.depth,
        recording.imu,
    )
    result.warnings.extend(recording.problems)
    return result, recording
