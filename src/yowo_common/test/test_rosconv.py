import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at
from yowo_common.rosconv import (
    camera_info_to_model,
    decode_color,
    decode_depth,
    encode_color_jpeg,
    encode_depth_png,
    encode_raw,
    matrix_to_pose,
    matrix_to_transform,
    model_to_camera_info,
    ns_to_time,
    pointcloud2_to_xyz_rgb,
    pose_to_matrix,
    stamp_to_ns,
    transform_to_matrix,
    xyz_rgb_to_pointcloud2,
)


def test_time_roundtrip():
    ns = 1_700_000_123_456_789_012
    assert stamp_to_ns(ns_to_time(ns)) == ns


def test_pose_roundtrip():
    T = look_at([1, 2, 3], [0, 0, 0])
    np.testing.assert_allclose(pose_to_matrix(matrix_to_pose(T)), T, atol=1e-12)
    np.testing.assert_allclose(transform_to_matrix(matrix_to_transform(T)), T, atol=1e-12)


def test_camera_info_roundtrip_and_bad_info():
    cam = CameraModel(640, 480, [[500, 0, 320], [0, 505, 240], [0, 0, 1]], [-0.1, 0.01, 0, 0, 0])
    back = camera_info_to_model(model_to_camera_info(cam))
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.D, cam.D)
    with pytest.raises(ValueError, match="focal"):
        camera_info_to_model(CameraInfo(width=640, height=480))


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8"])
def test_raw_color(encoding):
    rgb = np.random.default_rng(0).integers(0, 255, (4, 5, 3), dtype=np.uint8)
    arr = rgb[:, :, ::-1] if encoding == "bgr8" else rgb
    np.testing.assert_array_equal(decode_color(encode_raw(arr, encoding)), rgb)


def test_mono_and_padded_step():
    mono = np.arange(12, dtype=np.uint8).reshape(3, 4)
    msg = encode_raw(mono, "mono8")
    msg.step = 6
    msg.data = np.pad(mono, ((0, 0), (0, 2))).tobytes()
    out = decode_color(msg)
    assert out.shape == (3, 4, 3)
    np.testing.assert_array_equal(out[:, :, 1], mono)


def test_unknown_encoding_is_named():
    msg = encode_raw(np.zeros((2, 2, 3), np.uint8), "rgb8")
    msg.encoding = "yuv422_weird"
    with pytest.raises(ValueError, match="yuv422_weird"):
        decode_color(msg)


def test_jpeg_color_close():
    rgb = np.full((32, 32, 3), (200, 30, 90), np.uint8)
    out = decode_color(encode_color_jpeg(rgb, Header(frame_id="x")))
    assert np.abs(out.astype(int) - rgb).max() <= 4


def test_depth_encodings():
    depth = np.array([[1.234, np.nan], [0.5, 7.0]], dtype=np.float32)
    for msg in (
        encode_depth_png(depth),
        encode_raw((np.nan_to_num(depth) * 1000).round().astype(np.uint16), "16UC1"),
        encode_raw(depth, "32FC1"),
    ):
        out = decode_depth(msg)
        assert np.isnan(out[0, 1])
        np.testing.assert_allclose(out[[0, 1, 1], [0, 0, 1]], [1.234, 0.5, 7.0], atol=5e-4)


def test_pointcloud2_roundtrip():
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 3))
    rgb = rng.integers(0, 255, (50, 3), dtype=np.uint8)
    back_xyz, back_rgb = pointcloud2_to_xyz_rgb(xyz_rgb_to_pointcloud2(xyz, rgb))
    np.testing.assert_allclose(back_xyz, xyz.astype(np.float32), rtol=1e-6)
    np.testing.assert_array_equal(back_rgb, rgb)
    assert pointcloud2_to_xyz_rgb(xyz_rgb_to_pointcloud2(xyz))[1] is None
