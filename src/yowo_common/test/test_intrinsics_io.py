from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
import yaml

from yowo_common.camera import EQUIDISTANT, PLUMB_BOB, RATIONAL_POLYNOMIAL, CameraModel
from yowo_common.intrinsics_io import IntrinsicsError, camera_info_yaml, read_intrinsics

# As cameracalibrator writes it (camera_calibration_parsers layout).
ROS_YAML = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [423.23, 0, 317.42, 0, 423.89, 241.63, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.3448, 0.1012, 0.00012, -3e-05, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [330.1, 0, 318.2, 0, 0, 370.0, 240.9, 0, 0, 0, 1, 0]
"""

# Kalibr camchain-imucam.yaml (EuRoC-like values); cam1 switched to equidistant.
KALIBR_YAML = """\
cam0:
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cctv/lobby/image_raw
  timeshift_cam_imu: 0.0
cam1:
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.0127, 0.0042, -3e-05, 0.0011]
  distortion_model: equidistant
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cctv/lobby_east/image_raw
"""

# From COLMAP's documentation of the text model, plus one distorted camera.
COLMAP_TXT = """\
# Camera list with one line of data per camera:
#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]
# Number of cameras: 4
1 SIMPLE_PINHOLE 3072 2304 2559.81 1536 1152
2 PINHOLE 3072 2304 2560.56 2560.56 1536 1152
3 SIMPLE_RADIAL 3072 2304 2559.69 1536 1152 -0.0218531
4 OPENCV 1920 1080 1000.5 1001.5 960.25 540.75 -0.12 0.03 0.001 -0.002
"""

# OpenCV's camera calibration tutorial output (OpenCV 4 FileStorage header).
OPENCV4_YAML = """\
%YAML:1.0
---
calibration_time: "Wed 08 Dec 2010 05:25:36 PM CET"
nr_of_frames: 25
image_width: 640
image_height: 480
fisheye_model: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 6.5746697944293521e+002, 0., 3.1950000000000000e+002, 0.,
       6.5746697944293521e+002, 2.3950000000000000e+002, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -4.1802327176423804e-001, 5.0715244063187526e-001, 0., 0.,
       -5.7843597214487474e-001 ]
avg_reprojection_error: 3.9166705010097589e-001
"""

K = np.array([[500.0, 0.0, 320.5], [0.0, 510.0, 240.25], [0.0, 0.0, 1.0]])
POINTS = np.array([[0.3, -0.2, 1.0], [-0.5, 0.4, 2.0], [0.05, 0.1, 0.8], [0.0, 0.0, 3.0]])


def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_camera_calibration_parsers_yaml(tmp_path):
    m = read_intrinsics(write(tmp_path, "narrow.yaml", ROS_YAML), camera="any name: one camera in the file")
    assert (m.width, m.height, m.distortion_model) == (640, 480, PLUMB_BOB)
    np.testing.assert_array_equal(m.K, [[423.23, 0, 317.42], [0, 423.89, 241.63], [0, 0, 1]])
    np.testing.assert_array_equal(m.D, [-0.3448, 0.1012, 0.00012, -3e-05, 0])
    np.testing.assert_array_equal(m.P, [[330.1, 0, 318.2, 0], [0, 370.0, 240.9, 0], [0, 0, 1, 0]])


@pytest.mark.parametrize("camera, key", [("cam1", "cam1"), ("lobby", "cam0"), ("east", "cam1")])
def test_kalibr_camchain(tmp_path, camera, key):
    m = read_intrinsics(write(tmp_path, "camchain-imucam.yaml", KALIBR_YAML), camera)
    if key == "cam0":
        assert m.distortion_model == PLUMB_BOB
        np.testing.assert_array_equal(m.K, [[458.654, 0, 367.215], [0, 457.296, 248.375], [0, 0, 1]])
        np.testing.assert_array_equal(m.D, [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0])
    else:
        assert m.distortion_model == EQUIDISTANT
        np.testing.assert_array_equal(m.K, [[457.587, 0, 379.999], [0, 456.134, 255.238], [0, 0, 1]])
        np.testing.assert_array_equal(m.D, [-0.0127, 0.0042, -3e-05, 0.0011])
    assert (m.width, m.height) == (752, 480)


def test_colmap_cameras_txt(tmp_path):
    path = write(tmp_path, "cameras.txt", COLMAP_TXT)
    m = read_intrinsics(path, "3")
    assert (m.width, m.height, m.distortion_model) == (3072, 2304, PLUMB_BOB)
    # COLMAP's pixel centres sit half a pixel further right and down than OpenCV's.
    np.testing.assert_array_equal(m.K, [[2559.69, 0, 1535.5], [0, 2559.69, 1151.5], [0, 0, 1]])
    np.testing.assert_array_equal(m.D, [-0.0218531, 0, 0, 0, 0])
    m = read_intrinsics(path, "4")
    np.testing.assert_array_equal(m.K, [[1000.5, 0, 959.75], [0, 1001.5, 540.25], [0, 0, 1]])
    np.testing.assert_array_equal(m.D, [-0.12, 0.03, 0.001, -0.002, 0])


@pytest.mark.parametrize(
    "model, params",
    [
        ("SIMPLE_PINHOLE", [500.0, 320.5, 240.25]),
        ("PINHOLE", [500.0, 510.0, 320.5, 240.25]),
        ("SIMPLE_RADIAL", [500.0, 320.5, 240.25, -0.08]),
        ("RADIAL", [500.0, 320.5, 240.25, -0.08, 0.01]),
        ("OPENCV", [500.0, 510.0, 320.5, 240.25, -0.1, 0.02, 0.001, -0.002]),
        ("FULL_OPENCV", [500.0, 510.0, 320.5, 240.25, -0.1, 0.02, 0.001, -0.002, 0.003, 0.01, -0.004, 0.002]),
        ("OPENCV_FISHEYE", [500.0, 510.0, 320.5, 240.25, -0.02, 0.004, -0.001, 0.0005]),
    ],
)
def test_colmap_projection_matches_pycolmap(tmp_path, model, params):
    path = write(tmp_path, "cameras.txt", f"7 {model} 640 480 {' '.join(map(repr, params))}\n")
    m = read_intrinsics(path)
    expected = {"FULL_OPENCV": RATIONAL_POLYNOMIAL, "OPENCV_FISHEYE": EQUIDISTANT}.get(model, PLUMB_BOB)
    assert m.distortion_model == expected
    cam = pycolmap.Camera(model=model, width=640, height=480, params=params)
    np.testing.assert_allclose(m.project(POINTS)[0], cam.img_from_cam(POINTS) - 0.5, rtol=0, atol=1e-6)


def write_filestorage(path: Path, entries: dict) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        if isinstance(value, list):  # a plain sequence, as cv::Size is written
            fs.startWriteStruct(key, cv2.FileNode_SEQ)
            for item in value:
                fs.write("", item)
            fs.endWriteStruct()
        else:
            fs.write(key, value)
    fs.release()
    return path


D5 = np.array([[0.1, -0.05, 0.001, 0.002, 0.01]])
D8 = np.array([0.1, -0.05, 0.001, 0.002, 0.01, 0.02, -0.01, 0.005])
D4 = np.array([-0.02, 0.004, -0.001, 0.0005])


@pytest.mark.parametrize("ext", ["yaml", "xml"])
@pytest.mark.parametrize(
    "entries, model, D",
    [
        ({"image_width": 640, "image_height": 480, "camera_matrix": K, "distortion_coefficients": D5}, PLUMB_BOB, D5),
        ({"cameraMatrix": K, "distCoeffs": D8, "imageSize": np.array([640, 480])}, RATIONAL_POLYNOMIAL, D8),
        ({"K": K, "D": D4, "image_size": [640, 480], "fisheye": 1}, EQUIDISTANT, D4),
        ({"K": K, "D": D4, "image_size": [640, 480], "model": "fisheye"}, EQUIDISTANT, D4),
        ({"K": K, "dist_coeffs": D4, "image_size": [640, 480]}, PLUMB_BOB, np.append(D4, 0.0)),
        ({"K": K, "dist_coeffs": np.append(D8, np.zeros(6)), "imageSize": [640, 480]}, RATIONAL_POLYNOMIAL, D8),
    ],
)
def test_opencv_filestorage(tmp_path, ext, entries, model, D):
    m = read_intrinsics(write_filestorage(tmp_path / f"calib.{ext}", entries))
    assert (m.width, m.height, m.distortion_model) == (640, 480, model)
    np.testing.assert_array_equal(m.K, K)
    np.testing.assert_array_equal(m.D, np.ravel(D))


def test_opencv4_tutorial_yaml(tmp_path):
    m = read_intrinsics(write(tmp_path, "out_camera_data.yml", OPENCV4_YAML))
    assert (m.width, m.height, m.distortion_model) == (640, 480, PLUMB_BOB)
    assert m.K[0, 0] == 657.46697944293521 and m.K[1, 2] == 239.5
    np.testing.assert_array_equal(m.D, [-0.41802327176423804, 0.50715244063187526, 0, 0, -0.57843597214487474])


@pytest.mark.parametrize(
    "model, D", [(PLUMB_BOB, [-0.3, 0.1, 1e-4, -2e-4, 0.02]), (RATIONAL_POLYNOMIAL, D8), (EQUIDISTANT, D4)]
)
def test_camera_info_yaml_round_trip(tmp_path, model, D):
    R = cv2.Rodrigues(np.array([0.01, -0.02, 0.003]))[0]
    P = np.array([[480.123456789, 0, 321.1, -30.5], [0, 480.123456789, 239.9, 0], [0, 0, 1, 0]])
    original = CameraModel(1280, 720, K, D, model, R, P)
    text = camera_info_yaml(original, "lobby_cam")
    assert yaml.safe_load(text)["camera_name"] == "lobby_cam"
    m = read_intrinsics(write(tmp_path, "lobby_cam.yaml", text))
    assert (m.width, m.height, m.distortion_model) == (1280, 720, model)
    for a, b in ((m.K, original.K), (m.D, original.D), (m.R, original.R), (m.P, original.P)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(
    "name, content, camera, message",
    [
        ("calib.yaml", "camera_matrix: [1, 2\n", "", "not YAML"),
        ("calib.yaml", b"\x89PNG\r\n\x1a\n\xff\xfe", "", "not a text file"),
        ("calib.yaml", "just a sentence\n", "", "not a calibration file"),
        ("cameras.txt", "1 FOV 640 480 500 500 320 240 0.9\n", "", "COLMAP model FOV is not supported"),
        ("cameras.txt", "1 PINHOLE 640 480 500 500 320\n", "", "takes 4 parameters, got 3"),
        ("cameras.txt", COLMAP_TXT, "", "holds 4 cameras, select one (camera=...): 1 (SIMPLE_PINHOLE 3072x2304), 2 ("),
        ("cameras.txt", COLMAP_TXT, "9", "no camera '9'; candidates: 1 (SIMPLE_PINHOLE"),
        ("camchain.yaml", KALIBR_YAML, "", "select one (camera=...): cam0 (/cctv/lobby/image_raw), cam1 ("),
        ("camchain.yaml", KALIBR_YAML, "cctv", "camera 'cctv' is ambiguous"),
        (
            "camchain.yaml",
            KALIBR_YAML.replace("camera_model: pinhole", "camera_model: omni"),
            "cam0",
            "camera 'cam0': Kalibr camera_model 'omni' is not supported",
        ),
        (
            "camchain.yaml",
            KALIBR_YAML.replace("distortion_model: radtan", "distortion_model: fov"),
            "cam0",
            "Kalibr distortion_model 'fov' is not supported",
        ),
        ("narrow.yaml", ROS_YAML.replace("plumb_bob", "thin_prism"), "", "'thin_prism' is not supported"),
        ("narrow.yaml", ROS_YAML.replace("data: [423.23,", "data: [0,"), "", "fx=0, fy=423.89 (must be > 0)"),
        ("narrow.yaml", ROS_YAML.replace("rows: 1\n  cols: 5", "rows: 1\n  cols: 4"), "", "rows x cols is 1 x 4"),
        ("out_camera_data.yml", OPENCV4_YAML.replace("image_width: 640\nimage_height: 480\n", ""), "", "no image size"),
        (
            "out_camera_data.yml",
            OPENCV4_YAML.replace("fisheye_model: 0", "fisheye_model: 1"),
            "",
            "the fisheye (equidistant) model takes 4 coefficients k1..k4, got 5",
        ),
    ],
)
def test_bad_input_names_file(tmp_path, name, content, camera, message):
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(IntrinsicsError) as err:
        read_intrinsics(path, camera)
    assert str(path) in str(err.value)
    assert message in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(IntrinsicsError, match="missing.yaml: cannot read"):
        read_intrinsics(tmp_path / "missing.yaml")


@pytest.mark.parametrize(
    "D, message",
    [
        (np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0]), "6 distortion coefficients; OpenCV's models take 4, 5, 8, 12 or 14"),
        (np.append(D8, [0.0, 0.003, 0.0, 0.0, 0.0, 0.001]), "YOWO cannot use the nonzero s2, tauY"),
    ],
)
def test_opencv_unusable_coefficients(tmp_path, D, message):
    path = write_filestorage(tmp_path / "calib.yaml", {"K": K, "D": D, "image_size": [640, 480]})
    with pytest.raises(IntrinsicsError, match=message):
        read_intrinsics(path)
