"""ROS message <-> numpy conversions (message classes only; no rclpy).

Readers are duck-typed: they accept the rosidl Python classes used by rclpy and
anything with the same fields.
"""

from __future__ import annotations

import struct

import cv2
import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, Quaternion, Transform, Vector3
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField

from .camera import PLUMB_BOB, CameraModel
from .geometry import quat_xyzw_from_rotation, rotation_from_quat_xyzw, se3

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# image_transport's compressed_depth prefixes the PNG with a ConfigHeader
# {int32 format; float depthParam[2]} (12 bytes).
COMPRESSED_DEPTH_HEADER = struct.Struct("<iff")


def message_fields(msg):
    """Every field of a rosidl message as plain Python values, recursively (for
    comparisons: serialised bytes differ in their padding between writes)."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {k: message_fields(getattr(msg, k)) for k in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple)):
        return [message_fields(m) for m in msg]
    if hasattr(msg, "tolist"):
        return msg.tolist()
    return msg


# --- time -------------------------------------------------------------------
def stamp_to_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_time(ns: int) -> Time:
    ns = int(ns)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


# --- poses ------------------------------------------------------------------
def pose_to_matrix(pose) -> np.ndarray:
    q = pose.orientation
    R = rotation_from_quat_xyzw([q.x, q.y, q.z, q.w])
    return se3(R, [pose.position.x, pose.position.y, pose.position.z])


def transform_to_matrix(tf) -> np.ndarray:
    q = tf.rotation
    R = rotation_from_quat_xyzw([q.x, q.y, q.z, q.w])
    return se3(R, [tf.translation.x, tf.translation.y, tf.translation.z])


def _quat(R) -> Quaternion:
    x, y, z, w = quat_xyzw_from_rotation(R)
    return Quaternion(x=float(x), y=float(y), z=float(z), w=float(w))


def matrix_to_pose(T: np.ndarray) -> Pose:
    x, y, z = (float(v) for v in T[:3, 3])
    return Pose(position=Point(x=x, y=y, z=z), orientation=_quat(T[:3, :3]))


def matrix_to_transform(T: np.ndarray) -> Transform:
    x, y, z = (float(v) for v in T[:3, 3])
    return Transform(translation=Vector3(x=x, y=y, z=z), rotation=_quat(T[:3, :3]))


def points_to_array(points) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in points], dtype=float).reshape(-1, 3)


def array_to_points(xyz: np.ndarray) -> list[Point]:
    return [Point(x=float(x), y=float(y), z=float(z)) for x, y, z in np.asarray(xyz).reshape(-1, 3)]


# --- camera info --------------------------------------------------------------
def camera_info_to_model(info) -> CameraModel:
    """CameraInfo -> CameraModel; raises ValueError naming what is wrong."""
    R, P = np.asarray(info.r, dtype=float), np.asarray(info.p, dtype=float)
    model = CameraModel(
        int(info.width),
        int(info.height),
        np.asarray(info.k, dtype=float).reshape(3, 3),
        np.asarray(info.d, dtype=float),
        info.distortion_model or PLUMB_BOB,
        # an uncalibrated driver leaves R and P zero: identity and [K | 0] then
        R if R.any() else None,
        P if P.any() else None,
    )
    problems = model.problems()
    if problems:
        raise ValueError("; ".join(problems))
    return model


def model_to_camera_info(model: CameraModel, header=None) -> CameraInfo:
    info = CameraInfo()
    if header is not None:
        info.header = header
    info.width, info.height = int(model.width), int(model.height)
    info.distortion_model = model.distortion_model
    info.d = [float(v) for v in model.D]
    info.k = [float(v) for v in model.K.reshape(-1)]
    info.r = [float(v) for v in model.R.reshape(-1)]
    info.p = [float(v) for v in model.P.reshape(-1)]
    return info


# --- images -------------------------------------------------------------------
_RAW_LAYOUT = {  # encoding -> (dtype, channels)
    "rgb8": (np.uint8, 3),
    "bgr8": (np.uint8, 3),
    "rgba8": (np.uint8, 4),
    "bgra8": (np.uint8, 4),
    "mono8": (np.uint8, 1),
    "8UC1": (np.uint8, 1),
    "8UC3": (np.uint8, 3),
    "mono16": (np.uint16, 1),
    "16UC1": (np.uint16, 1),
    "32FC1": (np.float32, 1),
}


def _raw_image_array(msg) -> np.ndarray:
    enc = msg.encoding
    if enc not in _RAW_LAYOUT:
        raise ValueError(f"unsupported image encoding '{enc}' (supported: {', '.join(_RAW_LAYOUT)})")
    dtype, ch = _RAW_LAYOUT[enc]
    dtype = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * ch * dtype.itemsize
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if msg.step < row_bytes or len(buf) < msg.step * msg.height:
        raise ValueError(
            f"image data of {len(buf)} bytes does not fit {msg.width}x{msg.height} {enc} with step {msg.step}"
        )
    rows = buf[: msg.step * msg.height].reshape(msg.height, msg.step)[:, :row_bytes]
    arr = np.ascontiguousarray(rows).view(dtype).reshape(msg.height, msg.width, ch)
    return arr.astype(dtype.newbyteorder("="))


def decode_color(msg) -> np.ndarray:
    """Image or CompressedImage -> HxWx3 uint8 RGB (mono is replicated)."""
    if hasattr(msg, "format"):
        buf = np.frombuffer(msg.data, dtype=np.uint8)
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"cannot decode compressed image (format '{msg.format}', {len(buf)} bytes)")
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    arr = _raw_image_array(msg)
    enc = msg.encoding
    if arr.dtype != np.uint8:
        raise ValueError(f"image encoding '{enc}' is not a colour encoding")
    if arr.shape[2] == 1:
        return np.repeat(arr, 3, axis=2)
    if enc.startswith("bgr"):
        arr = arr[:, :, 2::-1]
    return np.ascontiguousarray(arr[:, :, :3])


def decode_depth(msg) -> np.ndarray:
    """Depth Image (16UC1 mm / 32FC1 m) or compressedDepth -> HxW float32 metres, NaN = invalid."""
    if hasattr(msg, "format"):
        data = bytes(msg.data)
        if not data.startswith(PNG_SIGNATURE):
            data = data[COMPRESSED_DEPTH_HEADER.size :]
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or img.dtype != np.uint16:
            raise ValueError(f"cannot decode compressed depth (format '{msg.format}'); expected 16-bit PNG")
        mm = img.astype(np.float32)
    else:
        arr = _raw_image_array(msg)[:, :, 0]
        if arr.dtype == np.float32:
            depth = arr.astype(np.float32)
            depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
            return depth
        if arr.dtype != np.uint16:
            raise ValueError(f"depth encoding '{msg.encoding}' is not 16UC1 or 32FC1")
        mm = arr.astype(np.float32)
    mm[mm == 0] = np.nan
    return mm / 1000.0


def encode_color_jpeg(rgb: np.ndarray, header=None, quality: int = 90) -> CompressedImage:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    msg = CompressedImage(format="rgb8; jpeg compressed bgr8", data=buf.tobytes())
    if header is not None:
        msg.header = header
    return msg


def depth_to_mm(depth_m: np.ndarray) -> np.ndarray:
    mm = np.nan_to_num(np.asarray(depth_m, dtype=np.float64) * 1000.0, nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(mm), 0, 65535).astype(np.uint16)


def encode_depth_png(depth_m: np.ndarray, header=None) -> CompressedImage:
    """Metres (NaN = invalid) -> compressedDepth as image_transport writes it (16UC1 mm PNG)."""
    ok, buf = cv2.imencode(".png", depth_to_mm(depth_m), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("PNG encoding failed")
    msg = CompressedImage(
        format="16UC1; compressedDepth png", data=COMPRESSED_DEPTH_HEADER.pack(0, 0.0, 0.0) + buf.tobytes()
    )
    if header is not None:
        msg.header = header
    return msg


def encode_raw(arr: np.ndarray, encoding: str, header=None) -> Image:
    arr = np.ascontiguousarray(arr)
    msg = Image(
        height=arr.shape[0],
        width=arr.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=arr.shape[1] * (arr.shape[2] if arr.ndim == 3 else 1) * arr.dtype.itemsize,
        data=arr.tobytes(),
    )
    if header is not None:
        msg.header = header
    return msg


# --- point clouds -----------------------------------------------------------------
_PC2_DTYPES = {
    PointField.FLOAT32: "f4",
    PointField.FLOAT64: "f8",
    PointField.UINT32: "u4",
    PointField.UINT8: "u1",
    PointField.INT32: "i4",
    PointField.UINT16: "u2",
    PointField.INT16: "i2",
    PointField.INT8: "i1",
}


def xyz_rgb_to_pointcloud2(xyz: np.ndarray, rgb: np.ndarray | None = None, header=None) -> PointCloud2:
    """Unorganised cloud with x, y, z (float32) and, if given, rgb packed in a float32
    as 0x00RRGGBB (the PCL/RViz convention)."""
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    names = ["x", "y", "z"] + (["rgb"] if rgb is not None else [])
    data = np.empty(len(xyz), dtype=[(n, "<f4") for n in names])
    data["x"], data["y"], data["z"] = xyz.T
    if rgb is not None:
        c = np.asarray(rgb, dtype=np.uint32).reshape(-1, 3)
        data["rgb"] = ((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]).view(np.float32)
    msg = PointCloud2(
        height=1,
        width=len(xyz),
        is_bigendian=False,
        point_step=4 * len(names),
        row_step=4 * len(names) * len(xyz),
        is_dense=True,
        fields=[PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate(names)],
        data=data.tobytes(),
    )
    if header is not None:
        msg.header = header
    return msg


def pointcloud2_to_xyz_rgb(msg) -> tuple[np.ndarray, np.ndarray | None]:
    """PointCloud2 -> (N, 3) float xyz and (N, 3) uint8 rgb (None without an rgb field)."""
    fields = {f.name: f for f in msg.fields}
    if not {"x", "y", "z"} <= set(fields):
        raise ValueError(f"PointCloud2 without x, y, z fields (has {', '.join(fields)})")
    order = ">" if msg.is_bigendian else "<"
    dtype = np.dtype(
        {
            "names": list(fields),
            "offsets": [f.offset for f in fields.values()],
            "formats": [order + _PC2_DTYPES[f.datatype] for f in fields.values()],
            "itemsize": msg.point_step,
        }
    )
    data = np.frombuffer(bytes(msg.data), dtype=dtype, count=msg.width * msg.height)
    xyz = np.column_stack([data["x"], data["y"], data["z"]]).astype(float)
    rgb = None
    if "rgb" in fields:
        packed = (
            np.ascontiguousarray(data["rgb"]).view(np.uint32)
            if fields["rgb"].datatype == PointField.FLOAT32
            else data["rgb"].astype(np.uint32)
        )
        rgb = np.column_stack([(packed >> 16) & 255, (packed >> 8) & 255, packed & 255]).astype(np.uint8)
    return xyz, rgb
