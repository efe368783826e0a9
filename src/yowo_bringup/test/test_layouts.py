"""Which recorded topic fills which input role: YOWO's own names, the drivers' layouts,
image_transport camera namespaces and the user's mapping."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_bringup.imu_source import ImuNoiseDefaults, kalibr_camchain, kalibr_imu_noise, resolve_imu, static_transform
from yowo_bringup.layouts import InputMapError, map_inputs
from yowo_common import topics

REALSENSE = [
    "/camera/camera/color/image_raw",
    "/camera/camera/color/camera_info",
    "/camera/camera/aligned_depth_to_color/image_raw",
    "/camera/camera/aligned_depth_to_color/camera_info",
    "/camera/camera/depth/image_rect_raw",
    "/camera/camera/infra1/image_rect_raw",
    "/camera/camera/gyro/sample",
    "/camera/camera/accel/sample",
    "/tf_static",
]
CCTV = ["/cctv/lobby/image_raw/compressed", "/cctv/lobby/camera_info", "/cctv/hall/image_raw/compressed"]


def test_realsense_with_split_imu_and_cctv_namespaces():
    m = map_inputs(REALSENSE + CCTV)
    assert m.recorded(topics.EGO_COLOR[0]) == "/camera/camera/color/image_raw"
    assert m.recorded(topics.EGO_DEPTH[0]) == "/camera/camera/aligned_depth_to_color/image_raw"
    assert m.recorded(topics.EGO_INFO) == "/camera/camera/color/camera_info"
    assert m.recorded(topics.EGO_GYRO) == "/camera/camera/gyro/sample"
    assert m.recorded(topics.EGO_ACCEL) == "/camera/camera/accel/sample"
    assert not m.recorded(topics.EGO_IMU)
    assert m.recorded("/cmc/lobby/image_raw/compressed") == "/cctv/lobby/image_raw/compressed"
    assert m.recorded("/cmc/lobby/camera_info") == "/cctv/lobby/camera_info"
    assert m.recorded("/cmc/hall/image_raw/compressed") == "/cctv/hall/image_raw/compressed"
    assert not m.recorded("/cmc/hall/camera_info")
    # The device's own streams are never ceiling cameras.
    assert {n.split("/")[2] for n in m.roles if n.startswith("/cmc/")} == {"lobby", "hall"}
    assert not m.problems and any("realsense2_camera under /camera/camera" in n for n in m.notes), m.notes


@pytest.mark.parametrize(
    "recorded, imu",
    [
        (
            [
                "/camera/color/image_raw/compressed",
                "/camera/color/camera_info",
                "/camera/aligned_depth_to_color/image_raw/compressedDepth",
                "/camera/imu",
            ],
            "/camera/imu",
        ),
        (
            [
                "/rgb/image_raw",
                "/rgb/camera_info",
                "/depth_to_rgb/image_raw",
                "/depth/image_raw",
                "/ir/image_raw",
                "/imu",
            ],
            "/imu",
        ),
        (
            [
                "/zed/zed_node/rgb/image_rect_color",
                "/zed/zed_node/rgb/camera_info",
                "/zed/zed_node/depth/depth_registered",
                "/zed/zed_node/imu/data",
            ],
            "/zed/zed_node/imu/data",
        ),
    ],
)
def test_driver_layouts_with_a_united_imu(recorded, imu):
    m = map_inputs(recorded + ["/nvr/ch3/image_raw", "/nvr/ch3/camera_info"])
    assert m.recorded(topics.EGO_IMU) == imu
    color = m.recorded(topics.EGO_COLOR[0]) or m.recorded(topics.EGO_COLOR[1])
    depth = m.recorded(topics.EGO_DEPTH[0]) or m.recorded(topics.EGO_DEPTH[1])
    assert color == recorded[0] and depth == recorded[2] and m.recorded(topics.EGO_INFO) == recorded[1]
    # Azure's depth and infrared images at the top level are its own streams; the NVR channel is a camera.
    cmcs = {topics.parse_cmc_topic(n)[0] for n in m.roles if topics.parse_cmc_topic(n)}
    assert cmcs == {"ch3"} and m.recorded("/cmc/ch3/image_raw") == "/nvr/ch3/image_raw"


def test_own_layout_is_kept_and_explicit_mapping_wins():
    own = [
        topics.EGO_COLOR[1],
        topics.EGO_DEPTH[0],
        topics.EGO_INFO,
        "/cmc/cam00/image_raw/compressed",
        "/cmc/cam00/camera_info",
        "/cmc/cam00/agent_keypoints",
    ]
    m = map_inputs(own)
    assert m.roles == {t: t for t in own} and not m.renamed
    m = map_inputs(REALSENSE + ["/other/rgb"], remaps=["/ego/color/image_raw:=/other/rgb"])
    assert m.recorded(topics.EGO_COLOR[0]) == "/other/rgb"
    # ROS order is input:=recorded; the other order is read the same (one side is an input name).
    assert (
        map_inputs(["/other/rgb"], remaps=["/other/rgb:=/ego/color/image_raw"]).recorded(topics.EGO_COLOR[0])
        == "/other/rgb"
    )


def test_bad_mappings_and_ambiguity_are_named():
    with pytest.raises(InputMapError, match="no topic /nope"):
        map_inputs(REALSENSE, remaps=["/ego/color/image_raw:=/nope"])
    with pytest.raises(InputMapError, match="exactly one side"):
        map_inputs(REALSENSE, remaps=["/a:=/b"])
    two = REALSENSE + [t.replace("/camera/camera/", "/head/") for t in REALSENSE if "camera/camera" in t]
    m = map_inputs(two)
    assert not m.recorded(topics.EGO_INFO)
    (problem,) = m.problems
    assert "--set inputs.ego_namespace=/camera/camera" in problem and "--set inputs.ego_namespace=/head" in problem
    m = map_inputs(two, ego_namespace="/head")
    assert m.recorded(topics.EGO_INFO) == "/head/color/camera_info" and not m.problems


def test_camera_names_from_namespaces_stay_unique_and_valid():
    m = map_inputs(["/site_a/cam/image_raw", "/site_b/cam/image_raw", "/3rd-floor/image_raw"])
    names = sorted(topics.parse_cmc_topic(n)[0] for n in m.roles)
    assert names == ["cam", "cam_3rd_floor", "site_b_cam"], names


def _rot(deg, axis):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler(axis, deg, degrees=True).as_matrix()
    return T


def test_imu_extrinsics_from_tf_static_and_kalibr(tmp_path):
    T_link_color = _rot(-90, "x") @ _rot(5, "z")
    T_link_color[:3, 3] = (0.0, 0.015, 0.0)
    T_link_gyro = _rot(-90, "x")
    T_link_gyro[:3, 3] = (-0.01, 0.005, 0.001)
    edges = [
        ("camera_link", "camera_color_optical_frame", T_link_color),
        ("camera_link", "camera_gyro_optical_frame", T_link_gyro),
    ]
    T_cam_imu = np.linalg.inv(T_link_color) @ T_link_gyro
    assert np.allclose(
        static_transform(edges, "camera_color_optical_frame", "camera_gyro_optical_frame"), T_cam_imu, atol=1e-12
    )
    assert static_transform(edges, "camera_color_optical_frame", "elsewhere") is None
    found = resolve_imu(
        camchain="",
        imu_yaml="",
        defaults=ImuNoiseDefaults(),
        rate_hz=200.0,
        camera_frame="camera_color_optical_frame",
        imu_frame="camera_gyro_optical_frame",
        tf_edges=edges,
    )
    assert np.allclose(found.T_cam_imu, T_cam_imu) and "/tf_static" in found.extrinsics
    assert "defaults" in found.noise
    missing = resolve_imu(
        camchain="",
        imu_yaml="",
        defaults=ImuNoiseDefaults(),
        rate_hz=200.0,
        camera_frame="camera_color_optical_frame",
        imu_frame="imu_link",
        tf_edges=edges,
    )
    assert not missing.calibration_yaml and "inputs.imu_camchain" in missing.reason
    camchain = tmp_path / "camchain-imucam.yaml"
    camchain.write_text(
        "cam0:\n  T_cam_imu: " + str(T_cam_imu.tolist()) + "\n  timeshift_cam_imu: 0.004\n"
        "  rostopic: /camera/camera/color/image_raw\n"
    )
    imu = tmp_path / "imu.yaml"
    imu.write_text(
        "imu0:\n  accelerometer_noise_density: 0.002\n  accelerometer_random_walk: 0.0003\n"
        "  gyroscope_noise_density: 0.0002\n  gyroscope_random_walk: 2.0e-05\n  update_rate: 200.0\n"
    )
    T, shift = kalibr_camchain(str(camchain))
    assert np.allclose(T, T_cam_imu) and shift == 0.004
    assert kalibr_imu_noise(str(imu))["gyroscope_random_walk"] == 2.0e-05
    found = resolve_imu(
        camchain=str(camchain),
        imu_yaml=str(imu),
        defaults=ImuNoiseDefaults(),
        rate_hz=200.0,
        camera_frame="",
        imu_frame="",
        tf_edges=[],
    )
    assert str(camchain) in found.extrinsics and str(imu) in found.noise
    imu.write_text("update_rate: 200\n")
    with pytest.raises(ValueError, match="missing gyroscope_noise_density"):
        kalibr_imu_noise(str(imu))


@pytest.mark.parametrize(
    "topic, suggested",
    [
        ("/cmc/../image_raw", "/cmc/camera/image_raw"),
        ("/cmc/a/../../x/image_raw", "/cmc/a_______x/image_raw"),
        ("/cmc/caméra/camera_info", "/cmc/cam_ra/camera_info"),
        ("/cmc/1st/agent_keypoints", "/cmc/cam_1st/agent_keypoints"),
        ("/cmc/" + "x" * 300 + "/image_raw/compressed", "/cmc/" + "x" * 63 + "/image_raw/compressed"),
    ],
)
def test_camera_names_that_cannot_be_used_are_named_with_a_remapping(topic, suggested):
    why = topics.unusable_cmc_topic(topic)
    assert "cannot be a camera name" in why and f"-r {suggested}:={topic}" in why, why
    assert topics.parse_cmc_topic(topic) is None
    assert topics.parse_cmc_topic(suggested) is not None
    assert not topics.unusable_cmc_topic("/cmc/lobby_2/image_raw") and not topics.unusable_cmc_topic("/other")
