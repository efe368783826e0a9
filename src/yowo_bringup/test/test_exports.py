"""cameras.yaml's intrinsics, clock and noise fields, and every export read back by its
tool's own reader (pycolmap, evo) or, where the tool has none on PyPI
(camera_calibration_parsers, kalibr), parsed the way its parser does and projected
through yowo's camera model: the numbers equal cameras.yaml's."""

import argparse
import ast

import numpy as np
import pytest
import yaml
from sensor_msgs.msg import CameraInfo

from cmc_synthetic import ceiling_camera
from yowo_bringup.exports import ExportImages, write_exports
from yowo_bringup.results import pose_from_entry, write_cameras_yaml
from yowo_cmc.group_sfm import CameraGroupResult
from yowo_common.camera import EQUIDISTANT, RATIONAL_POLYNOMIAL, CameraModel
from yowo_common.geometry import inv_se3, transform_points
from yowo_common.rosconv import camera_info_to_model
from yowo_fusion.records import EgoMapData, RegisteredCmc, unregistered

TARGET = np.array([2.0, 1.5, 1.0])  # a point every camera sees


def _cameras() -> list[RegisteredCmc]:
    specs = {
        "a_pinhole": (0.3, 0.3, None, "plumb_bob"),
        "b_radtan": (3.7, 0.3, [-0.12, 0.03, 1e-3, -5e-4, 0.0], "plumb_bob"),
        "c_fisheye": (3.7, 2.7, [0.05, -0.01, 0.002, -0.001], EQUIDISTANT),
        "d_rational": (0.3, 2.7, [-0.2, 0.05, 0.0, 0.0, 0.01, 0.02, 0.0, 0.0], RATIONAL_POLYNOMIAL),
    }
    out = []
    for name, (x, y, D, model) in specs.items():
        cam, T = ceiling_camera(x, y, TARGET[:2], D=D)
        cam.distortion_model = model
        cam.P = np.column_stack([cam.K * [[0.9], [0.9], [1]], np.zeros(3)])  # a rectified P that is not [K | 0]
        out.append(
            RegisteredCmc(
                name=name,
                group="g0",
                method="group_sfm",
                status="ok",
                reason="",
                T_world_cam=T,
                covariance=np.eye(6) * 1e-6,
                camera=cam,
                rmse_px=0.4,
                num_agent=200,
                num_scene=30,
            )
        )
    cam, _ = ceiling_camera(2.0, 2.0, TARGET[:2])
    out.append(unregistered("e_failed", "seen in 0 frames", cam))
    out.append(unregistered("f_no_info", "no usable CameraInfo"))
    return out


def _group(cameras: list[RegisteredCmc]) -> CameraGroupResult:
    members = [c for c in cameras if c.group == "g0"]
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(1.0, 3.0, 200), rng.uniform(0.8, 2.2, 200), rng.uniform(0.0, 1.8, 200)])
    return CameraGroupResult(
        group_id="g0",
        reference=members[0].name,
        names=[c.name for c in members],
        T_local_cam={c.name: c.T_world_cam for c in members},
        point_stamps_ns=np.arange(200, dtype=np.int64),
        point_ids=np.zeros(200, int),
        points=points,
        rmse_px={c.name: 0.4 for c in members},
        num_observations={c.name: 100 for c in members},
        sigma_px_by_id={0: 0.8, 1: 1.6, 5: 12.0},
        initial_pair=(members[0].name, members[1].name),
        cameras={c.name: c.camera for c in members},
    )


def _ego() -> EgoMapData:
    cam = CameraModel.from_fov(320, 240, 70.0)
    cam.D = np.array([-0.05, 0.01, 0.0, 0.0, 0.0])
    rng = np.random.default_rng(1)
    landmarks = np.column_stack([rng.uniform(0, 4, 30), np.full(30, 3.0), rng.uniform(0.2, 2.5, 30)])
    poses = []
    for x in (1.0, 1.5, 2.0):
        _, T = ceiling_camera(x, 0.5, (x, 3.0), z=1.6)  # looking at the wall y = 3
        poses.append(T)
    obs_pose, obs_lm, obs_uv = [], [], []
    for f, T in enumerate(poses):
        uv, front = cam.project_world(T, landmarks)
        seen = np.flatnonzero(front & cam.in_image(uv))
        obs_pose += [f] * len(seen)
        obs_lm += seen.tolist()
        obs_uv.append(uv[seen])
    # The map's cloud: a point 1 mm from each landmark but the last, in a colour of its own.
    cloud = landmarks[:-1] + [0.001, 0.0, 0.0]
    colours = rng.uniform(0, 1, (len(cloud), 3))
    return EgoMapData(
        camera=cam,
        stamps_ns=np.array([10**18, 10**18 + 10**8, 10**18 + 2 * 10**8]),
        T_world_ego=np.array(poses),
        landmarks=landmarks,
        descriptor_type="ORB",
        descriptors=np.zeros((30, 32), np.uint8),
        obs_pose=np.array(obs_pose),
        obs_landmark=np.array(obs_lm),
        obs_uv=np.vstack(obs_uv),
        cloud_points=cloud,
        cloud_colors=colours,
    )


def _images(cameras, ego) -> ExportImages:
    """A background per registered CMC; pixels for two of the three keyframes."""
    rng = np.random.default_rng(2)
    return ExportImages(
        cmc={c.name: rng.integers(0, 255, (480, 640, 3), dtype=np.uint8) for c in cameras[:4]},
        ego={int(s): rng.integers(0, 255, (240, 320, 3), dtype=np.uint8) for s in ego.stamps_ns[:2]},
    )


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("results")
    cameras, ego = _cameras(), _ego()
    group = _group(cameras)
    write_cameras_yaml(out / "cameras.yaml", cameras, [group])
    images = _images(cameras, ego)
    files = write_exports(out / "export", cameras, [group], ego, images)
    doc = {c["name"]: c for c in yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]}
    return out, files, doc, cameras, ego, images


def _model_from_cameras_yaml(entry: dict) -> CameraModel:
    return CameraModel(
        entry["image_width"],
        entry["image_height"],
        entry["K"],
        entry["distortion_coefficients"],
        entry["distortion_model"],
    )


def _target_in(entry: dict) -> np.ndarray:
    return transform_points(inv_se3(pose_from_entry(entry["T_world_camera"])), TARGET[None])


def test_cameras_yaml_intrinsics_clock_and_noise(written):
    _, _, doc, cameras, _, _ = written
    for c in cameras[:4]:
        e = doc[c.name]
        assert (e["image_width"], e["image_height"]) == (640, 480) and e[
            "distortion_model"
        ] == c.camera.distortion_model
        np.testing.assert_allclose(e["K"], c.camera.K, atol=1e-6)
        np.testing.assert_allclose(e["distortion_coefficients"], c.camera.D, atol=1e-9)
        assert e["clock_offset_s"] is None and "assumed synchronised" in e["clock"]
        noise = e["keypoint_noise"]
        assert noise["sigma_px_by_keypoint_id"] == {0: 0.8, 1: 1.6, 5: 12.0} and noise["median_px"] == 1.6
        assert noise["min_px"] == 0.8 and noise["max_px"] == 12.0 and "g0" in noise["estimated_by"]
    assert doc["e_failed"]["keypoint_noise"] is None and "not estimated" in doc["e_failed"]["keypoint_noise_note"]
    assert doc["e_failed"]["image_width"] == 640  # its CameraInfo arrived; the pose did not
    assert doc["f_no_info"]["K"] is None and doc["f_no_info"]["distortion_model"] is None


def read_calibration_yml(path) -> CameraInfo:
    """camera_calibration_parsers' readCalibrationYml (parse_yml.cpp) in Python: every key
    it reads, the fixed matrix shapes it asserts, D sized rows x cols."""
    doc = yaml.safe_load(path.read_text())
    info = CameraInfo(width=int(doc["image_width"]), height=int(doc["image_height"]))
    for key, field, shape in (
        ("camera_matrix", "k", (3, 3)),
        ("rectification_matrix", "r", (3, 3)),
        ("projection_matrix", "p", (3, 4)),
    ):
        m = doc[key]
        assert (m["rows"], m["cols"]) == shape and len(m["data"]) == shape[0] * shape[1], (path, key)
        setattr(info, field, [float(v) for v in m["data"]])
    D = doc["distortion_coefficients"]
    assert D["rows"] == 1 and len(D["data"]) == D["rows"] * D["cols"], path
    info.d = [float(v) for v in D["data"]]
    info.distortion_model = doc["distortion_model"]
    assert isinstance(doc["camera_name"], str)
    return info


def test_camera_info_yaml_loads_as_the_registered_camera(written):
    out, _, doc, cameras, _, _ = written
    for c in cameras[:5]:
        info = read_calibration_yml(out / "export" / "camera_info" / f"{c.name}.yaml")
        model = camera_info_to_model(info)
        np.testing.assert_allclose(np.reshape(info.p, (3, 4)), c.camera.P)  # CameraInfo's P as it came
        if c.T_world_cam is not None:
            expected, _ = _model_from_cameras_yaml(doc[c.name]).project(_target_in(doc[c.name]))
            np.testing.assert_allclose(model.project(_target_in(doc[c.name]))[0], expected, atol=1e-6)
    assert not (out / "export" / "camera_info" / "f_no_info.yaml").exists()
    assert "f_no_info" in (out / "export" / "README.md").read_text()


def test_colmap_model_reads_back_with_pycolmap(written):
    import pycolmap  # in requirements.txt: a missing one is a failure, not a skip

    out, _, doc, _, ego, _ = written
    rec = pycolmap.Reconstruction(str(out / "export" / "colmap"))
    images = {im.name: im for im in rec.images.values()}
    models = {"a_pinhole": "PINHOLE", "b_radtan": "OPENCV", "c_fisheye": "OPENCV_FISHEYE", "d_rational": "FULL_OPENCV"}
    for name, model in models.items():
        im, e = images[f"cmc/{name}.png"], doc[name]
        cam = rec.cameras[im.camera_id]
        assert cam.model.name == model and (cam.width, cam.height) == (640, 480)
        np.testing.assert_allclose(im.projection_center(), e["T_world_camera"]["position"], atol=1e-6)
        K = np.asarray(e["K"])
        np.testing.assert_allclose([cam.focal_length_x, cam.focal_length_y], [K[0, 0], K[1, 1]], atol=1e-6)
        # COLMAP's pixel centres are at +0.5
        np.testing.assert_allclose([cam.principal_point_x, cam.principal_point_y], K[:2, 2] + 0.5, atol=1e-6)
        P_cam = _target_in(e)
        np.testing.assert_allclose(
            cam.img_from_cam(P_cam)[0] - 0.5, _model_from_cameras_yaml(e).project(P_cam)[0][0], atol=1e-6
        )
    assert not any("e_failed" in n or "f_no_info" in n for n in images)
    keyframes = sorted((im for im in rec.images.values() if im.name.startswith("ego/")), key=lambda im: im.name)
    assert len(keyframes) == 3 and len(rec.points3D) == len(ego.landmarks)
    for im, T in zip(keyframes, ego.T_world_ego):
        np.testing.assert_allclose(im.projection_center(), T[:3, 3], atol=1e-6)
        assert im.num_points3D == np.sum(ego.obs_pose == keyframes.index(im))
    assert sum(p.track.length() for p in rec.points3D.values()) == len(ego.obs_pose)
    # exact observations: every point reprojects onto its 2D points, as we wrote and as COLMAP computes it
    assert max(p.error for p in rec.points3D.values() if p.track.length()) < 1e-4
    rec.update_point_3d_errors()
    assert rec.compute_mean_reprojection_error() < 1e-4


def test_colmap_images_are_written_and_points_coloured_from_the_map(written):
    import cv2
    import pycolmap

    out, _, _, _, ego, images = written
    folder = out / "export" / "colmap"
    rec = pycolmap.Reconstruction(str(folder))
    named = sorted(im.name for im in rec.images.values())
    written_png = sorted(str(p.relative_to(folder)) for p in folder.rglob("*.png"))
    missing = f"ego/{int(ego.stamps_ns[2])}.png"
    assert written_png == sorted(set(named) - {missing}), (named, written_png)
    for name, rgb in images.cmc.items():
        np.testing.assert_array_equal(cv2.imread(str(folder / f"cmc/{name}.png"))[:, :, ::-1], rgb)
    assert "1 of the 7 images named in images.txt have no pixels" in (out / "export" / "README.md").read_text()
    # Each landmark in its cloud point's colour; the last, with none near, grey.
    colours = np.array([rec.points3D[j + 1].color for j in range(len(ego.landmarks))])
    np.testing.assert_array_equal(colours[:-1], np.round(ego.cloud_colors * 255).astype(np.uint8))
    np.testing.assert_array_equal(colours[-1], [128, 128, 128])


def _static_tf_parser() -> argparse.ArgumentParser:
    """The named arguments of Jazzy's static_transform_publisher."""
    p = argparse.ArgumentParser()
    for k in ("x", "y", "z", "qx", "qy", "qz", "qw"):
        p.add_argument(f"--{k}", type=float, required=True)
    p.add_argument("--frame-id", required=True)
    p.add_argument("--child-frame-id", required=True)
    return p


def test_static_tf_yaml_and_launch_file(written):
    out, _, doc, _, _, _ = written
    tf = yaml.safe_load((out / "export" / "static_tf.yaml").read_text())["transforms"]
    source = (out / "export" / "static_tf.launch.py").read_text()
    compile(source, "static_tf.launch.py", "exec")
    (transforms,) = [
        ast.literal_eval(n.value)
        for n in ast.parse(source).body
        if isinstance(n, ast.Assign) and n.targets[0].id == "TRANSFORMS"
    ]
    registered = [n for n, e in doc.items() if "T_world_camera" in e]
    assert (
        [t["child_frame_id"] for t in tf]
        == [f"{n}_optical_frame" for n in registered]
        == [_static_tf_parser().parse_args(args).child_frame_id for _, args in transforms]
    )
    for entry, (_, args), name in zip(tf, transforms, registered):
        a = _static_tf_parser().parse_args(args)
        pose = doc[name]["T_world_camera"]
        assert a.frame_id == entry["frame_id"] == "map"
        np.testing.assert_allclose([a.x, a.y, a.z], pose["position"], atol=1e-6)
        np.testing.assert_allclose([a.qx, a.qy, a.qz, a.qw], pose["orientation_xyzw"], atol=1e-6)
        np.testing.assert_allclose(list(entry["translation"].values()), pose["position"], atol=1e-6)
        assert entry["command"].split()[4:] == args


def test_kalibr_camchain(written):
    out, _, doc, _, _, _ = written
    path = out / "export" / "camchain_g0.yaml"
    text = path.read_text()
    chain = yaml.safe_load(text)
    assert list(chain) == ["cam0", "cam1", "cam2"]  # d_rational: kalibr has no model for it
    assert "skipped d_rational" in text and "d_rational" in (out / "export" / "README.md").read_text()
    names = ["a_pinhole", "b_radtan", "c_fisheye"]
    required = {
        "camera_model",
        "intrinsics",
        "distortion_model",
        "distortion_coeffs",
        "resolution",
        "rostopic",
        "cam_overlaps",
    }
    for i, name in enumerate(names):
        cam, e = chain[f"cam{i}"], doc[name]
        assert required <= cam.keys() and ("T_cn_cnm1" in cam) == (i > 0)
        assert cam["camera_model"] == "pinhole" and cam["rostopic"] == f"/cmc/{name}/image_raw"
        assert len(cam["intrinsics"]) == 4 and cam["resolution"] == [640, 480]
        assert sorted(cam["cam_overlaps"]) == [j for j in range(3) if j != i]  # all look at TARGET
        fu, fv, pu, pv = cam["intrinsics"]
        ros_model = {"radtan": "plumb_bob", "equidistant": EQUIDISTANT}[cam["distortion_model"]]
        info = CameraInfo(
            width=cam["resolution"][0],
            height=cam["resolution"][1],
            k=[fu, 0, pu, 0, fv, pv, 0, 0, 1],
            d=cam["distortion_coeffs"] + ([0.0] if ros_model == "plumb_bob" else []),
            distortion_model=ros_model,
        )
        expected, _ = _model_from_cameras_yaml(e).project(_target_in(e))
        np.testing.assert_allclose(camera_info_to_model(info).project(_target_in(e))[0], expected, atol=1e-6)
        if i:
            T = np.asarray(cam["T_cn_cnm1"])
            prev = pose_from_entry(doc[names[i - 1]]["T_world_camera"])
            np.testing.assert_allclose(T @ inv_se3(prev) @ [*TARGET, 1], [*_target_in(e)[0], 1], atol=1e-6)


def test_ego_trajectory_tum_reads_with_evo(tmp_path):
    from evo.tools import file_interface

    from yowo_common.geometry import quat_xyzw_from_rotation
    from yowo_common.trajectory import Trajectory, write_tum

    ego = _ego()
    write_tum(tmp_path / "ego_trajectory.tum", Trajectory(ego.stamps_ns, ego.T_world_ego))
    traj = file_interface.read_tum_trajectory_file(str(tmp_path / "ego_trajectory.tum"))
    np.testing.assert_allclose(traj.timestamps, ego.stamps_ns / 1e9, atol=1e-6)
    np.testing.assert_allclose(traj.positions_xyz, ego.T_world_ego[:, :3, 3], atol=1e-6)
    wxyz = np.array([np.roll(quat_xyzw_from_rotation(T[:3, :3]), 1) for T in ego.T_world_ego])
    np.testing.assert_allclose(np.abs(np.sum(traj.orientations_quat_wxyz * wxyz, axis=1)), 1.0, atol=1e-9)


def test_messages_carry_the_camera_info(tmp_path):
    """RegisteredCamera and CameraGroup carry each camera's CameraInfo over ROS: the
    cameras.yaml written from the messages is the one written from the fusion's objects."""
    from yowo_cmc.group_sfm import GroupingResult
    from yowo_cmc.messages import groups_from_msg, groups_to_msg
    from yowo_fusion.messages import registered_from_msg, registered_to_msg

    cameras = _cameras()
    group = _group(cameras)
    back = registered_from_msg(registered_to_msg(cameras, 10**18))
    (group_back,), _ = groups_from_msg(groups_to_msg(GroupingResult([group], {}, []), 10**18))
    assert back[-1].camera is None and group_back.cameras.keys() == group.cameras.keys()
    for c, b in zip(cameras[:-1], back):
        np.testing.assert_array_equal(b.camera.P, c.camera.P)
        np.testing.assert_array_equal(b.camera.D, c.camera.D)
    write_cameras_yaml(tmp_path / "direct.yaml", cameras, [group])
    write_cameras_yaml(tmp_path / "messages.yaml", back, [group_back])
    assert (tmp_path / "direct.yaml").read_text() == (tmp_path / "messages.yaml").read_text()
