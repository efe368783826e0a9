"""A recording in YOWO's own layout (docs/design.md §3) rewritten as real camera
drivers publish it: their default topic names, frame ids, depth encodings, IMU split
and /tf_static tree, with the ceiling cameras under image_transport's names. The input
mapping is tested on these recordings as it would meet a user's.

Every message keeps its log time and header stamps; payloads change only where a driver
publishes differently (frame ids, the split IMU, ZED's metric depth, PNG-compressed CCTV
images). Ground truth (/gt/...) is copied unchanged: evaluation reads it by its own names.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from geometry_msgs.msg import TransformStamped, Vector3
from sensor_msgs.msg import CompressedImage, Image, Imu
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from yowo_common import topics
from yowo_common.geometry import inv_se3, se3
from yowo_common.ros.bag import BagWriter, list_topics, read_messages, read_raw
from yowo_common.rosconv import (
    decode_color,
    decode_depth,
    depth_to_mm,
    encode_raw,
    matrix_to_transform,
    ns_to_time,
    transform_to_matrix,
)

# A body frame (x forward, y left, z up) -> its optical frame (x right, y down, z forward), REP 103.
T_BODY_OPTICAL = se3(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.zeros(3))
# The D435i accelerometer's rate in realsense2_camera's default profile (the gyro's: the IMU's rate).
ACCEL_HZ = 63.0
# The default of image_transport's compressed plugin's png_level parameter.
PNG_LEVEL = 3
NO_COVARIANCE = [-1.0] + [0.0] * 8  # REP 145: the field is not measured


def _offset(x: float, y: float, z: float, optical: bool = False) -> np.ndarray:
    """A mount: translation (x, y, z) in the parent, rotated to an optical frame if asked."""
    return se3(T_BODY_OPTICAL[:3, :3] if optical else np.eye(3), (x, y, z))


@dataclass(frozen=True)
class ImuMount:
    """An IMU frame on the driver's tree: `body` hangs from `parent`; the samples are stamped
    in `data` (an optical frame under `body`) or in `body` itself when `data` is ''."""

    parent: str
    body: str
    data: str = ""


@dataclass(frozen=True)
class DriverLayout:
    """One driver's default names. Image topics are the raw ones; image_transport's
    /compressed and /compressedDepth are appended for compressed sources."""

    color: str
    color_info: str
    depth: str
    depth_info: str
    camera_frame: str  # colour, aligned depth and their CameraInfo
    # The driver's static tree as (parent, child, T_parent_child), parents listed first;
    # it holds camera_frame. The IMU frames are solved from the source's T_cam_imu.
    tree: tuple[tuple[str, str, np.ndarray], ...]
    imu: str = ""  # one Imu topic with both rates ...
    gyro: str = ""  # ... or the driver's separate streams
    accel: str = ""
    imu_mounts: tuple[ImuMount, ...] = ()  # united: one; split: gyro's, then accel's
    depth_in_metres: bool = False  # 32FC1 [m], NaN invalid (else 16UC1 [mm])


_RS = "/camera/camera"
_RS_TREE = (
    ("camera_link", "camera_color_frame", _offset(0.0, 0.015, 0.0)),
    ("camera_color_frame", "camera_color_optical_frame", T_BODY_OPTICAL),
    ("camera_link", "camera_depth_frame", _offset(0.0, 0.0, 0.0)),
    ("camera_depth_frame", "camera_depth_optical_frame", T_BODY_OPTICAL),
)
_RS_CAMERA = dict(
    color=f"{_RS}/color/image_raw",
    color_info=f"{_RS}/color/camera_info",
    depth=f"{_RS}/aligned_depth_to_color/image_raw",
    depth_info=f"{_RS}/aligned_depth_to_color/camera_info",
    camera_frame="camera_color_optical_frame",
    tree=_RS_TREE,
)
LAYOUTS: dict[str, DriverLayout] = {
    # realsense2_camera 4.x: camera_namespace and camera_name 'camera', align_depth, unite_imu_method 0.
    "realsense": DriverLayout(
        **_RS_CAMERA,
        gyro=f"{_RS}/gyro/sample",
        accel=f"{_RS}/accel/sample",
        imu_mounts=(
            ImuMount("camera_link", "camera_gyro_frame", "camera_gyro_optical_frame"),
            ImuMount("camera_link", "camera_accel_frame", "camera_accel_optical_frame"),
        ),
    ),
    # The same with unite_imu_method 2 (linear interpolation): one Imu topic.
    "realsense_united": DriverLayout(
        **_RS_CAMERA,
        imu=f"{_RS}/imu",
        imu_mounts=(ImuMount("camera_link", "camera_imu_frame", "camera_imu_optical_frame"),),
    ),
    # Azure Kinect ROS driver (and Orbbec's Femto wrapper): rgb_camera_link is an optical frame.
    "azure": DriverLayout(
        color="/rgb/image_raw",
        color_info="/rgb/camera_info",
        depth="/depth_to_rgb/image_raw",
        depth_info="/depth_to_rgb/camera_info",
        camera_frame="rgb_camera_link",
        tree=(
            ("camera_base", "rgb_camera_link", _offset(0.0, 0.032, 0.0, optical=True)),
            ("camera_base", "depth_camera_link", _offset(0.0, 0.0, 0.0, optical=True)),
        ),
        imu="/imu",
        imu_mounts=(ImuMount("camera_base", "imu_link"),),
    ),
    # zed-ros2-wrapper, camera_name 'zed': registered depth in metres, the IMU under the left camera.
    "zed": DriverLayout(
        color="/zed/zed_node/rgb/image_rect_color",
        color_info="/zed/zed_node/rgb/camera_info",
        depth="/zed/zed_node/depth/depth_registered",
        depth_info="/zed/zed_node/depth/camera_info",
        camera_frame="zed_left_camera_optical_frame",
        tree=(
            ("zed_camera_link", "zed_camera_center", _offset(0.0, 0.0, 0.015)),
            ("zed_camera_center", "zed_left_camera_frame", _offset(0.0, 0.06, 0.0)),
            ("zed_left_camera_frame", "zed_left_camera_optical_frame", T_BODY_OPTICAL),
            ("zed_camera_center", "zed_right_camera_frame", _offset(0.0, -0.06, 0.0)),
            ("zed_right_camera_frame", "zed_right_camera_optical_frame", T_BODY_OPTICAL),
        ),
        imu="/zed/zed_node/imu/data",
        imu_mounts=(ImuMount("zed_left_camera_frame", "zed_imu_link"),),
        depth_in_metres=True,
    ),
}
CCTV_PREFIX = "/cctv"


def cctv_topic(name: str, relative: str) -> str:
    """A ceiling camera's topic under its own image_transport namespace."""
    return f"{CCTV_PREFIX}/{name}/{relative}"


def driver_tree(layout: DriverLayout, T_cam_imu: np.ndarray | None) -> list[tuple[str, str, np.ndarray]]:
    """The layout's static tree, with its IMU frames placed so that the camera frame ->
    IMU data frame composes to T_cam_imu (no IMU frames without one)."""
    edges = list(layout.tree)
    if T_cam_imu is None:
        return edges
    T_root = {edges[0][0]: np.eye(4)}
    for parent, child, T in edges:
        T_root[child] = T_root[parent] @ T
    for mount in layout.imu_mounts:
        T_body_data = T_BODY_OPTICAL if mount.data else np.eye(4)
        T_parent_cam = inv_se3(T_root[mount.parent]) @ T_root[layout.camera_frame]
        edges.append((mount.parent, mount.body, T_parent_cam @ T_cam_imu @ inv_se3(T_body_data)))
        if mount.data:
            edges.append((mount.body, mount.data, T_BODY_OPTICAL))
    return edges


def _source_T_cam_imu(src, camera_frame: str, imu_frame: str) -> np.ndarray:
    """The source's /tf_static transform between the ego camera and its IMU."""
    for _, _, msg in read_messages(src, [topics.TF_STATIC]):
        for tf in msg.transforms:
            T = transform_to_matrix(tf.transform)
            if (tf.header.frame_id, tf.child_frame_id) == (camera_frame, imu_frame):
                return T
            if (tf.header.frame_id, tf.child_frame_id) == (imu_frame, camera_frame):
                return inv_se3(T)
    raise ValueError(
        f"{src}: {topics.EGO_IMU} is recorded but /tf_static has no transform {camera_frame} -> {imu_frame} (T_cam_imu)"
    )


def _first(src, topic_names: Sequence[str]):
    """(log time, message) of the first message on any of the topics, None if none."""
    for _, log_ns, msg in read_messages(src, topic_names):
        return log_ns, msg
    return None


def _with_frame(msg, frame_id: str):
    msg.header.frame_id = frame_id
    return msg


def _split_imu(msg: Imu, frame_id: str, gyro: bool) -> Imu:
    """One stream of the driver's split IMU: the other's field zero and marked unmeasured."""
    out = _with_frame(copy.deepcopy(msg), frame_id)
    out.orientation_covariance = NO_COVARIANCE
    if gyro:
        out.linear_acceleration, out.linear_acceleration_covariance = Vector3(), NO_COVARIANCE
    else:
        out.angular_velocity, out.angular_velocity_covariance = Vector3(), NO_COVARIANCE
    return out


def png_compressed(msg: Image, frame_id: str) -> CompressedImage:
    """A colour Image as image_transport's compressed plugin writes it with format png:
    lossless, the PNG holding bgr8."""
    ok, png = cv2.imencode(
        ".png", cv2.cvtColor(decode_color(msg), cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL]
    )
    if not ok:
        raise ValueError("PNG encoding failed")
    return CompressedImage(
        header=Header(stamp=msg.header.stamp, frame_id=frame_id),
        format=f"{msg.encoding}; png compressed bgr8",
        data=png.tobytes(),
    )


def _depth_image(msg, layout: DriverLayout):
    """The driver's depth message: 32FC1 metres for ZED (decoded from any source form), else
    16UC1 millimetres with compressedDepth kept as it is."""
    frame = layout.camera_frame
    if layout.depth_in_metres:
        return encode_raw(decode_depth(msg), "32FC1", Header(stamp=msg.header.stamp, frame_id=frame))
    if isinstance(msg, Image) and msg.encoding == "32FC1":
        return encode_raw(depth_to_mm(decode_depth(msg)), "16UC1", Header(stamp=msg.header.stamp, frame_id=frame))
    return _with_frame(msg, frame)


class _Converter:
    """Source message -> the driver's messages, [(topic, message)]."""

    def __init__(self, driver: DriverLayout, accel_every: int, no_camera_info: Sequence[str]):
        self.driver, self.accel_every, self.no_camera_info = driver, accel_every, set(no_camera_info)
        self.imu_samples = 0

    def __call__(self, topic: str, msg) -> list[tuple[str, object]]:
        driver, frame = self.driver, self.driver.camera_frame
        if topic in (topics.TF_STATIC, topics.EGO_IMU_CALIBRATION):
            return []  # the driver's tree replaces them; drivers publish no calibration text
        if topic == topics.EGO_COLOR[0]:
            return [(driver.color, _with_frame(msg, frame))]
        if topic == topics.EGO_COLOR[1]:
            return [(f"{driver.color}/compressed", _with_frame(msg, frame))]
        if topic == topics.EGO_INFO:
            return [(driver.color_info, _with_frame(msg, frame)), (driver.depth_info, msg)]
        if topic == topics.EGO_DEPTH[0] or (topic == topics.EGO_DEPTH[1] and driver.depth_in_metres):
            return [(driver.depth, _depth_image(msg, driver))]
        if topic == topics.EGO_DEPTH[1]:
            return [(f"{driver.depth}/compressedDepth", _depth_image(msg, driver))]
        if topic == topics.EGO_IMU:
            return self._imu(msg)
        cmc = topics.parse_cmc_topic(topic)
        if cmc is None:
            return [(topic, msg)]
        name, kind = cmc
        if kind == "image_raw":
            return [(cctv_topic(name, "image_raw/compressed"), png_compressed(msg, f"{name}_optical_frame"))]
        if kind == "camera_info":
            return (
                []
                if name in self.no_camera_info
                else [(cctv_topic(name, kind), _with_frame(msg, f"{name}_optical_frame"))]
            )
        return [(cctv_topic(name, kind), msg)]

    def _imu(self, msg: Imu) -> list[tuple[str, object]]:
        driver = self.driver
        if driver.imu:
            mount = driver.imu_mounts[0]
            return [(driver.imu, _with_frame(msg, mount.data or mount.body))]
        gyro_mount, accel_mount = driver.imu_mounts
        out = [(driver.gyro, _split_imu(msg, gyro_mount.data, gyro=True))]
        if self.imu_samples % self.accel_every == 0:
            out.append((driver.accel, _split_imu(msg, accel_mount.data, gyro=False)))
        self.imu_samples += 1
        return out


def accel_decimation(imu_stamps_ns: Sequence[int]) -> int:
    """Every how many IMU samples the split accelerometer stream keeps one (at least every
    other): the driver's accelerometer runs at about ACCEL_HZ."""
    if len(imu_stamps_ns) < 2:
        return 2
    rate_hz = (len(imu_stamps_ns) - 1) / max((imu_stamps_ns[-1] - imu_stamps_ns[0]) / 1e9, 1e-9)
    return max(2, round(rate_hz / ACCEL_HZ))


def write_driver_layout(src, dst, layout: str, no_camera_info: Sequence[str] = ()) -> None:
    """Write the recording `src` (YOWO's layout) to the new recording `dst` as driver
    `layout` publishes it (one of LAYOUTS). The ceiling cameras named in no_camera_info
    get no camera_info topic."""
    if layout not in LAYOUTS:
        raise ValueError(f"unknown driver layout '{layout}' (choose from {', '.join(LAYOUTS)})")
    driver = LAYOUTS[layout]
    source_topics = list_topics(src)
    cameras = {parsed[0] for t in source_topics if (parsed := topics.parse_cmc_topic(t.name))}
    if unknown := sorted(set(no_camera_info) - cameras):
        raise ValueError(f"{src}: no ceiling camera {', '.join(unknown)} (it has {', '.join(sorted(cameras))})")
    latched = {t.name for t in source_topics if t.latched}

    T_cam_imu, accel_every = None, 2
    if (first_imu := _first(src, [topics.EGO_IMU])) is not None:
        if (first_color := _first(src, topics.EGO_COLOR)) is None:
            raise ValueError(f"{src}: {topics.EGO_IMU} without an ego colour camera to place it by")
        T_cam_imu = _source_T_cam_imu(src, first_color[1].header.frame_id, first_imu[1].header.frame_id)
        accel_every = accel_decimation([raw.log_time_ns for raw in read_raw(src, [topics.EGO_IMU])])
    # The driver's tree replaces the source's /tf_static at its log time and stamp (none: the first message's).
    first = _first(src, [topics.TF_STATIC]) or _first(src, [t.name for t in source_topics])
    if first is None:
        raise ValueError(f"{src}: the recording holds no messages")
    tf_log_ns, first_msg = first
    tf_stamp = (
        first_msg.transforms[0].header.stamp
        if isinstance(first_msg, TFMessage) and first_msg.transforms
        else ns_to_time(tf_log_ns)
    )
    tree = TFMessage(
        transforms=[
            TransformStamped(
                header=Header(stamp=tf_stamp, frame_id=parent), child_frame_id=child, transform=matrix_to_transform(T)
            )
            for parent, child, T in driver_tree(driver, T_cam_imu)
        ]
    )

    convert = _Converter(driver, accel_every, no_camera_info)
    with BagWriter(dst) as bag:
        bag.write(topics.TF_STATIC, tree, tf_log_ns, latched=True)
        for topic, log_ns, msg in read_messages(src):
            for name, out in convert(topic, msg):
                bag.write(name, out, log_ns, latched=topic in latched)
