"""Recordings in real drivers' layouts (yowo_sim.driver_layout): the drivers' default names,
the same messages and payloads as the YOWO-layout source, a /tf_static tree that puts the
IMU where the source's T_cam_imu does, and ceiling cameras as image_transport writes them."""

import numpy as np
import pytest
from std_msgs.msg import Header

from yowo_bringup.cli import build_parser
from yowo_common import topics
from yowo_common.geometry import inv_se3
from yowo_common.ros.bag import BagWriter, list_topics, read_messages
from yowo_common.rosconv import (
    decode_color,
    decode_depth,
    encode_raw,
    message_fields,
    ns_to_time,
    stamp_to_ns,
    transform_to_matrix,
)
from yowo_sim.capture import START_NS, generate
from yowo_sim.driver_layout import LAYOUTS, write_driver_layout
from yowo_sim.presets import get_preset
from yowo_sim.verbs import LAYOUT_HELP

IMAGE, COMPRESSED, INFO, IMU = (
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/Imu",
)
NO_INFO_CAMERA = "cam01"
# The drivers' default names (written out here on purpose: the module's table is what is
# tested) for a raw source: the ego camera's (colour, its camera_info, depth, depth's
# camera_info) and the IMU topics, and the frames their messages carry.
EGO_STREAMS = {
    "realsense": (
        "/camera/camera/color/image_raw",
        "/camera/camera/color/camera_info",
        "/camera/camera/aligned_depth_to_color/image_raw",
        "/camera/camera/aligned_depth_to_color/camera_info",
    ),
    "azure": ("/rgb/image_raw", "/rgb/camera_info", "/depth_to_rgb/image_raw", "/depth_to_rgb/camera_info"),
    "zed": (
        "/zed/zed_node/rgb/image_rect_color",
        "/zed/zed_node/rgb/camera_info",
        "/zed/zed_node/depth/depth_registered",
        "/zed/zed_node/depth/camera_info",
    ),
}
EGO_STREAMS["realsense_united"] = EGO_STREAMS["realsense"]
IMU_TOPICS = {
    "realsense": ("/camera/camera/gyro/sample", "/camera/camera/accel/sample"),
    "realsense_united": ("/camera/camera/imu",),
    "azure": ("/imu",),
    "zed": ("/zed/zed_node/imu/data",),
}
CAMERA_FRAME = {
    "realsense": "camera_color_optical_frame",
    "realsense_united": "camera_color_optical_frame",
    "azure": "rgb_camera_link",
    "zed": "zed_left_camera_optical_frame",
}
IMU_FRAMES = {
    "realsense": ("camera_gyro_optical_frame", "camera_accel_optical_frame"),
    "realsense_united": ("camera_imu_optical_frame",),
    "azure": ("imu_link",),
    "zed": ("zed_imu_link",),
}


def _tree_frames(layout: str) -> set[str]:
    return {
        "realsense": {
            "camera_link",
            "camera_color_frame",
            "camera_color_optical_frame",
            "camera_depth_frame",
            "camera_depth_optical_frame",
            "camera_gyro_frame",
            "camera_gyro_optical_frame",
            "camera_accel_frame",
            "camera_accel_optical_frame",
        },
        "realsense_united": {
            "camera_link",
            "camera_color_frame",
            "camera_color_optical_frame",
            "camera_depth_frame",
            "camera_depth_optical_frame",
            "camera_imu_frame",
            "camera_imu_optical_frame",
        },
        "azure": {"camera_base", "rgb_camera_link", "depth_camera_link", "imu_link"},
        "zed": {
            "zed_camera_link",
            "zed_camera_center",
            "zed_left_camera_frame",
            "zed_left_camera_optical_frame",
            "zed_right_camera_frame",
            "zed_right_camera_optical_frame",
            "zed_imu_link",
        },
    }[layout]


@pytest.fixture(scope="module")
def raw_source(tmp_path_factory):
    """A short tiny capture with raw images (low frame rates keep the render short)."""
    path = tmp_path_factory.mktemp("raw") / "tiny_raw"
    generate(get_preset("tiny", raw_images=True, ego_hz=4.0, cmc_hz=3.0), 5, path)
    return path


@pytest.fixture(scope="module")
def raw_layouts(raw_source, tmp_path_factory):
    out = tmp_path_factory.mktemp("layouts")
    for layout in LAYOUTS:
        write_driver_layout(raw_source, out / layout, layout, no_camera_info=[NO_INFO_CAMERA])
    return {layout: out / layout for layout in LAYOUTS}


def _messages(path, topic_names) -> dict[str, list[tuple[int, object]]]:
    out: dict[str, list[tuple[int, object]]] = {t: [] for t in topic_names}
    for topic, log_ns, msg in read_messages(path, topic_names):
        out[topic].append((log_ns, msg))
    return out


def _T_in_tree(tf_msg, parent: str, child: str) -> np.ndarray:
    """T_parent_child composed along a TFMessage's tree (both frames under one root)."""
    edges = {tf.child_frame_id: (tf.header.frame_id, transform_to_matrix(tf.transform)) for tf in tf_msg.transforms}

    def T_root(frame):
        T = np.eye(4)
        while frame in edges:
            frame, T_edge = edges[frame]
            T = T_edge @ T
        return frame, T

    (root_p, T_root_parent), (root_c, T_root_child) = T_root(parent), T_root(child)
    assert root_p == root_c
    return inv_se3(T_root_parent) @ T_root_child


def _source_T_cam_imu(path) -> np.ndarray:
    (tf,) = [tf for _, _, msg in read_messages(path, [topics.TF_STATIC]) for tf in msg.transforms]
    return transform_to_matrix(tf.transform)


def test_the_cli_offers_every_driver_layout():
    assert set(LAYOUT_HELP) == {"yowo", *LAYOUTS}


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_topics_and_counts(raw_source, raw_layouts, layout):
    source = {t.name: t for t in list_topics(raw_source)}
    written = {t.name: t for t in list_topics(raw_layouts[layout])}
    cams = ("cam00", "cam01", "cam02")
    ground_truth = {t.name: t.msgtype for t in source.values() if t.name.startswith(topics.GT_PREFIX)}
    expected = dict(
        zip(EGO_STREAMS[layout], (IMAGE, INFO, IMAGE, INFO)),
        **{t: IMU for t in IMU_TOPICS[layout]},
        **{f"/cctv/{c}/image_raw/compressed": COMPRESSED for c in cams},
        **{f"/cctv/{c}/agent_keypoints": "yowo_msgs/msg/AgentKeypoints" for c in cams},
        **{f"/cctv/{c}/camera_info": INFO for c in cams if c != NO_INFO_CAMERA},
        **ground_truth,
        **{topics.TF_STATIC: "tf2_msgs/msg/TFMessage"},
    )
    assert {t: w.msgtype for t, w in written.items()} == expected
    assert written[topics.TF_STATIC].latched and written[topics.TF_STATIC].count == 1

    ego_frames, imu_samples = source[topics.EGO_COLOR[0]].count, source[topics.EGO_IMU].count
    assert all(written[t].count == ego_frames for t in EGO_STREAMS[layout])
    for topic in IMU_TOPICS[layout]:  # split accelerometer: every k-th sample, k = round(source rate / ACCEL_HZ)
        assert written[topic].count == (len(range(0, imu_samples, 3)) if "accel" in topic else imu_samples)
    for name, topic in written.items():
        if name.startswith("/cctv/"):
            assert topic.count == source[name.replace("/cctv/", "/cmc/").removesuffix("/compressed")].count
        if name in ground_truth:
            assert (topic.count, topic.latched) == (source[name].count, source[name].latched)


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_ego_payloads_and_stamps(raw_source, raw_layouts, layout):
    """Colour and CameraInfo (also as the depth's) as the source's but for the frame id; 16UC1
    depth byte for byte, ZED's 32FC1 the millimetres in metres with NaN where invalid."""
    color, info, depth, depth_info = EGO_STREAMS[layout]
    src = _messages(raw_source, [topics.EGO_COLOR[0], topics.EGO_INFO, topics.EGO_DEPTH[0]])
    out = _messages(raw_layouts[layout], EGO_STREAMS[layout])
    frame = CAMERA_FRAME[layout]
    for src_topic, out_topic in ((topics.EGO_COLOR[0], color), (topics.EGO_INFO, info), (topics.EGO_INFO, depth_info)):
        for (src_ns, a), (out_ns, b) in zip(src[src_topic], out[out_topic], strict=True):
            assert (out_ns, stamp_to_ns(b.header.stamp), b.header.frame_id) == (
                src_ns,
                stamp_to_ns(a.header.stamp),
                frame,
            )
            a.header.frame_id = frame
            assert message_fields(a) == message_fields(b)
    for (src_ns, a), (out_ns, b) in zip(src[topics.EGO_DEPTH[0]], out[depth], strict=True):
        assert (out_ns, stamp_to_ns(b.header.stamp), b.header.frame_id) == (src_ns, stamp_to_ns(a.header.stamp), frame)
        if layout == "zed":
            mm = np.frombuffer(bytes(a.data), np.uint16).reshape(a.height, a.width)
            metres = np.frombuffer(bytes(b.data), np.float32).reshape(b.height, b.width)
            assert b.encoding == "32FC1" and (mm == 0).any()
            np.testing.assert_array_equal(np.isnan(metres), mm == 0)
            np.testing.assert_array_equal(metres[mm > 0], (mm[mm > 0] / np.float32(1000.0)).astype(np.float32))
        else:
            assert (b.encoding, bytes(b.data)) == ("16UC1", bytes(a.data))


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_tf_static_places_the_imu_as_the_source(raw_source, raw_layouts, layout):
    (tree,) = [msg for _, _, msg in read_messages(raw_layouts[layout], [topics.TF_STATIC])]
    assert {f for tf in tree.transforms for f in (tf.header.frame_id, tf.child_frame_id)} == _tree_frames(layout)
    T_cam_imu = _source_T_cam_imu(raw_source)
    for imu_frame in IMU_FRAMES[layout]:
        np.testing.assert_allclose(_T_in_tree(tree, CAMERA_FRAME[layout], imu_frame), T_cam_imu, rtol=0, atol=1e-9)
    if layout.startswith("realsense"):  # optical frames under their body frames, as the driver has them
        for tf in tree.transforms:
            if tf.child_frame_id.endswith("_optical_frame"):
                np.testing.assert_allclose(
                    transform_to_matrix(tf.transform)[:3, :3], [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-12
                )


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_imu_samples(raw_source, raw_layouts, layout):
    (source,) = _messages(raw_source, [topics.EGO_IMU]).values()
    written = _messages(raw_layouts[layout], IMU_TOPICS[layout])
    for topic, frame in zip(IMU_TOPICS[layout], IMU_FRAMES[layout], strict=True):
        accel_only = topic.endswith("accel/sample")
        expected = source[::3] if accel_only else source
        for (src_ns, a), (out_ns, b) in zip(expected, written[topic], strict=True):
            assert (out_ns, stamp_to_ns(b.header.stamp), b.header.frame_id) == (
                src_ns,
                stamp_to_ns(a.header.stamp),
                frame,
            )
            assert b.orientation_covariance[0] == -1
            gyro, accel = message_fields(b.angular_velocity), message_fields(b.linear_acceleration)
            if topic.endswith("gyro/sample"):
                assert gyro == message_fields(a.angular_velocity) and accel == {"x": 0.0, "y": 0.0, "z": 0.0}
                assert b.linear_acceleration_covariance[0] == -1
            elif accel_only:
                assert accel == message_fields(a.linear_acceleration) and gyro == {"x": 0.0, "y": 0.0, "z": 0.0}
                assert b.angular_velocity_covariance[0] == -1
            else:
                a.header.frame_id = frame
                assert message_fields(a) == message_fields(b)


def test_cctv_png_decodes_to_the_source_pixels(raw_source, raw_layouts):
    for layout in ("realsense", "zed"):
        for name in ("cam00", NO_INFO_CAMERA):
            (src,) = _messages(raw_source, [topics.cmc_image_topics(name)[0]]).values()
            (out,) = _messages(raw_layouts[layout], [f"/cctv/{name}/image_raw/compressed"]).values()
            for (src_ns, a), (out_ns, b) in zip(src, out, strict=True):
                assert b.format == "rgb8; png compressed bgr8" and b.header.frame_id == f"{name}_optical_frame"
                assert (out_ns, stamp_to_ns(b.header.stamp)) == (src_ns, stamp_to_ns(a.header.stamp))
                np.testing.assert_array_equal(decode_color(b), decode_color(a))


def test_compressed_source_is_copied(tiny_bag, tmp_path):
    """A compressed source: JPEG colour, compressedDepth and JPEG CCTV images are written unchanged
    (ZED decodes the depth: it publishes metres)."""
    source, _ = tiny_bag
    src = _messages(source, [topics.EGO_COLOR[1], topics.EGO_DEPTH[1], topics.cmc_image_topics("cam02")[1]])
    for layout, color, depth in (
        ("azure", "/rgb/image_raw/compressed", "/depth_to_rgb/image_raw/compressedDepth"),
        ("zed", "/zed/zed_node/rgb/image_rect_color/compressed", "/zed/zed_node/depth/depth_registered"),
    ):
        write_driver_layout(source, tmp_path / layout, layout)
        out = _messages(tmp_path / layout, [color, depth, "/cctv/cam02/image_raw/compressed"])
        for src_topic, out_topic in (
            (topics.EGO_COLOR[1], color),
            (topics.EGO_DEPTH[1], depth),
            (topics.cmc_image_topics("cam02")[1], "/cctv/cam02/image_raw/compressed"),
        ):
            for (src_ns, a), (out_ns, b) in zip(src[src_topic], out[out_topic], strict=True):
                assert out_ns == src_ns
                if out_topic.endswith("depth_registered"):
                    assert b.encoding == "32FC1"
                    np.testing.assert_array_equal(decode_depth(b), decode_depth(a))
                    continue
                if not out_topic.startswith("/cctv/"):
                    a.header.frame_id = CAMERA_FRAME[layout]
                assert message_fields(a) == message_fields(b)


def test_metric_depth_source_without_imu(tmp_path):
    """A hand-written source with 32FC1 depth and neither IMU nor /tf_static: 16UC1 millimetres
    for the drivers that publish them, NaN kept for ZED, and a tree of camera frames only."""
    depth_m = np.array([[0.5, np.nan, 1.25], [0.0, 2.0, 0.75]], np.float32)
    source = tmp_path / "metric"
    stamps_ns = (START_NS + 5, START_NS + 70_000_000)
    with BagWriter(source) as bag:
        for stamp_ns in stamps_ns:
            header = Header(stamp=ns_to_time(stamp_ns), frame_id="ego_optical_frame")
            bag.write(topics.EGO_COLOR[0], encode_raw(np.zeros((2, 3, 3), np.uint8), "rgb8", header), stamp_ns)
            bag.write(topics.EGO_DEPTH[0], encode_raw(depth_m, "32FC1", header), stamp_ns)
    for layout in ("azure", "zed"):
        write_driver_layout(source, tmp_path / layout, layout)
        (tree,) = [(log_ns, msg) for _, log_ns, msg in read_messages(tmp_path / layout, [topics.TF_STATIC])]
        assert tree[0] == stamps_ns[0] and not {tf.child_frame_id for tf in tree[1].transforms} & set(
            IMU_FRAMES[layout]
        )
        depths = [msg for _, _, msg in read_messages(tmp_path / layout, [EGO_STREAMS[layout][2]])]
        assert [stamp_to_ns(m.header.stamp) for m in depths] == list(stamps_ns)
        if layout == "zed":
            np.testing.assert_array_equal(decode_depth(depths[0]), np.where(depth_m > 0, depth_m, np.nan))
        else:
            assert depths[0].encoding == "16UC1"
            mm = np.frombuffer(bytes(depths[0].data), np.uint16).reshape(depth_m.shape)
            np.testing.assert_array_equal(mm, [[500, 0, 1250], [0, 2000, 750]])


def test_unknown_camera_is_refused(tiny_bag, tmp_path):
    with pytest.raises(ValueError, match="no ceiling camera cam09"):
        write_driver_layout(tiny_bag[0], tmp_path / "x", "azure", no_camera_info=["cam09"])
    assert not (tmp_path / "x").exists()


def test_simulate_verb_writes_a_driver_layout(tmp_path):
    out = tmp_path / "rs"
    args = build_parser().parse_args(
        [
            "simulate",
            "--preset",
            "tiny",
            "--seed",
            "1",
            "-o",
            str(out),
            "--raw",
            "--ego-hz",
            "2",
            "--cmc-hz",
            "1",
            "--no-cmc-images",
            "--layout",
            "realsense",
            "--no-camera-info",
            "cam00",
            "cam02",
        ]
    )
    assert args.func(args) == 0
    names = {t.name for t in list_topics(out)}
    assert {*EGO_STREAMS["realsense"], *IMU_TOPICS["realsense"]} <= names and "/cctv/cam01/camera_info" in names
    assert not {"/cctv/cam00/camera_info", "/cctv/cam02/camera_info"} & names
    assert [p.name for p in tmp_path.iterdir()] == ["rs"]  # the YOWO-layout recording is removed
