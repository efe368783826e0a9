"""A user's own recording as it comes: a RealSense driver's topic names with its split IMU and
/tf_static extrinsics, ceiling cameras under their own image_transport namespaces, CCTV
footage as video files; and the clear messages when such input cannot be used."""

import json

import numpy as np
import pytest
import yaml

from e2e_helpers import yowo
from yowo_bringup.config import load_config
from yowo_bringup.run import plan_run
from yowo_common.ros.bag import BagWriter, read_messages
from yowo_sim.capture import generate
from yowo_sim.cmc_video import write_cmc_videos
from yowo_sim.driver_layout import write_driver_layout
from yowo_sim.presets import get_preset


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """One tiny capture in YOWO's layout, the same as realsense2_camera and a NVR would give it."""
    root = tmp_path_factory.mktemp("user")
    generate(get_preset("tiny"), 0, root / "own")
    write_driver_layout(root / "own", root / "realsense", "realsense")
    write_driver_layout(root / "own", root / "no_info", "realsense", no_camera_info=["cam02"])
    write_cmc_videos(root / "own", root / "with_videos", root / "videos", start_error_s=3.0)
    return root


def _eval(out, bag, env):
    r = yowo("eval", out, "--bag", bag, "--metrics", out / "metrics.json", env=env)
    assert r.returncode == 0, r.stderr
    return json.loads((out / "metrics.json").read_text())["registration"]["summary"]


def test_realsense_layout_runs_as_recorded_and_matches_the_own_layout(recordings, tmp_path, ros_env):
    runs = {}
    for name in ("own", "realsense"):
        out = tmp_path / name
        r = yowo("run", recordings / name, "-o", out, env=ros_env)
        assert r.returncode == 0, r.stdout + r.stderr
        cams = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
        assert [c["status"] for c in cams] == ["ok"] * 3, cams
        runs[name] = (_eval(out, recordings / name, ros_env), yaml.safe_load((out / "run_log.yaml").read_text()))
    (own, _), (rs, log) = runs["own"], runs["realsense"]
    # result.mcap carries each registered camera's intrinsics in its optical frame (frustums in Foxglove).
    infos = {t: m for t, _, m in read_messages(tmp_path / "own" / "result.mcap") if t.endswith("/camera_info")}
    assert sorted(infos) == [f"/cmc/cam0{i}/camera_info" for i in range(3)], sorted(infos)
    assert infos["/cmc/cam01/camera_info"].header.frame_id == "cam01_optical_frame"
    # evo against the ground truth as `yowo eval` writes it in the map frame: no alignment needed.
    gt = tmp_path / "gt.tum"
    (tmp_path / "own" / "metrics.json").unlink()
    r = yowo("eval", tmp_path / "own", "--bag", recordings / "own", "--gt-tum", gt, env=ros_env)
    assert r.returncode == 0 and not (tmp_path / "own" / "metrics.json").exists(), r.stderr  # written when asked
    from evo.core import metrics, sync
    from evo.tools import file_interface

    ref, est = sync.associate_trajectories(
        file_interface.read_tum_trajectory_file(str(gt)),
        file_interface.read_tum_trajectory_file(str(tmp_path / "own" / "ego_trajectory.tum")),
    )
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    assert ape.get_statistic(metrics.StatisticsType.rmse) < 0.03
    imu = log["inputs"]["imu"]
    assert imu["used"] and imu["topics"] == ["/camera/camera/gyro/sample", "/camera/camera/accel/sample"]
    assert imu["extrinsics"].startswith("/tf_static") and "defaults" in imu["noise"]
    assert "ego camera: realsense2_camera under /camera/camera" in log["inputs"]["layout"]
    # The same recording under other names: the same quality (different IMU noise model, accel interpolated).
    assert rs["pos_avg"] <= 2.0 * own["pos_avg"] + 0.005, (rs, own)


def test_cctv_videos_started_seconds_off_register_every_camera(recordings, tmp_path, ros_env):
    out = tmp_path / "out"
    r = yowo(
        "run",
        recordings / "with_videos",
        "--cmc-videos",
        recordings / "videos" / "videos.yaml",
        "-o",
        out,
        env=ros_env,
        timeout=600,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    cams = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    assert all(c["T_world_camera"] for c in cams) and len(cams) == 3, cams
    # Each video started 3 s off the recording's clock: the offsets found say so.
    offsets = [c["clock_offset_s"] for c in cams]
    assert np.allclose(offsets, 3.0, atol=0.06), offsets
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    assert sorted(log["inputs"]["videos"]) == ["cam00", "cam01", "cam02"]


def _config(**inputs):
    return load_config(None, [f"inputs.{k}={json.dumps(v)}" for k, v in inputs.items()])


def test_input_problems_name_the_topic_or_file_and_the_option(recordings, tmp_path, ros_env):
    rs = recordings / "realsense"
    # A mapping to a topic the recording does not have.
    r = yowo("run", rs, "-o", tmp_path / "a", "-r", "/ego/color/image_raw:=/camera/rgb", env=ros_env)
    assert r.returncode == 2 and "no topic /camera/rgb" in r.stderr and "Traceback" not in r.stderr, r.stderr
    # Two devices that could be the ego camera: both named with the option that picks one.
    two = tmp_path / "two"
    with BagWriter(two) as bag:
        for topic, log_ns, msg in read_messages(rs):
            bag.write(topic, msg, log_ns)
            if topic.startswith("/camera/camera/") and "gyro" not in topic and "accel" not in topic:
                bag.write(topic.replace("/camera/camera/", "/head/"), msg, log_ns)
    r = yowo("info", two, env=ros_env)
    said = " ".join(r.stdout.split())
    assert "--set inputs.ego_namespace=/camera/camera" in said and "--set inputs.ego_namespace=/head" in said, said
    r = yowo("run", two, "-o", tmp_path / "b", env=ros_env)
    assert r.returncode == 2 and "inputs.ego_namespace" in r.stderr, r.stderr
    plan = plan_run(two, tmp_path / "c", config=_config(ego_namespace="/head"))
    assert plan.inputs["mapping"]["/ego/color/camera_info"] == "/head/color/camera_info"
    # An IMU whose extrinsics are nowhere: not used, and the run log says why and what to pass.
    no_tf = tmp_path / "no_tf"
    with BagWriter(no_tf) as bag:
        for topic, log_ns, msg in read_messages(rs):
            if topic != "/tf_static":
                bag.write(topic, msg, log_ns)
    imu = plan_run(no_tf, tmp_path / "d").inputs["imu"]
    assert not imu["used"] and "no extrinsics" in imu["reason"] and "inputs.imu_camchain" in imu["reason"], imu
    # A video that cannot be decoded, and one shorter than the walk.
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    own = recordings / "with_videos"
    r = yowo("run", own, "-o", tmp_path / "e", "--cmc-video", f"cam00={bad}@1700000000", env=ros_env)
    assert r.returncode == 2 and str(bad) in r.stderr and "Traceback" not in r.stderr, r.stderr
    short = tmp_path / "short.mp4"
    _cut_video(recordings / "videos" / "cam00.mp4", short, frames=30)
    start = yaml.safe_load((recordings / "videos" / "videos.yaml").read_text())["videos"][0]["start"]
    plan = plan_run(own, tmp_path / "f", config=_config(videos=[f"cam00={short}@{start}"]))
    assert any(str(short) in w and "sees only that part of the walk" in w for w in plan.warnings), plan.warnings
    # A video without a start time in its metadata (OpenCV writes none) and none given.
    r = yowo("info", own, "--cmc-video", f"cam00={short}", env=ros_env)
    assert r.returncode == 2 and "no start time" in r.stderr and "cam00=" in r.stderr, r.stderr


def _cut_video(src, dst, frames):
    import cv2

    cap = cv2.VideoCapture(str(src))
    fps = cap.get(cv2.CAP_PROP_FPS)
    out = None
    for _ in range(frames):
        ok, bgr = cap.read()
        assert ok
        if out is None:
            out = cv2.VideoWriter(str(dst), cv2.VideoWriter_fourcc(*"mp4v"), fps, (bgr.shape[1], bgr.shape[0]))
        out.write(bgr)
    out.release()
    cap.release()


def test_a_cctv_without_camera_info_gets_its_intrinsics_from_a_file_or_estimated(recordings, tmp_path, ros_env):
    from yowo_common.intrinsics_io import camera_info_yaml
    from yowo_common.rosconv import camera_info_to_model

    truth = next(camera_info_to_model(m) for _, _, m in read_messages(recordings / "own", ["/cmc/cam02/camera_info"]))
    bag = recordings / "no_info"
    # Estimated: every camera registered, the focal close to the truth, marked as estimated.
    out = tmp_path / "estimated"
    r = yowo("run", bag, "-o", out, env=ros_env)
    assert r.returncode == 0, r.stdout + r.stderr
    cams = {c["name"]: c for c in yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]}
    assert all(c["status"] == "ok" for c in cams.values()), cams
    est = cams["cam02"]
    assert est["intrinsics_estimated"] and est["focal_sigma_px"] > 0
    assert not cams["cam00"]["intrinsics_estimated"]
    f = est["K"][0][0]
    assert abs(f / truth.K[0, 0] - 1) < 0.05, (f, truth.K[0, 0])
    # Measured 0.042-0.052 m on this recording (the others 0.008-0.027): its focal is about 2 % off.
    errors = {e["name"]: e["eps_pos_m"] for e in _eval_cameras(out, bag, ros_env)}
    assert errors["cam02"] < 0.08, errors
    # From a file (what cameracalibrator writes): used as given.
    calib = tmp_path / "cam02.yaml"
    calib.write_text(camera_info_yaml(truth, "cam02"))
    out = tmp_path / "from_file"
    r = yowo("run", bag, "-o", out, "--intrinsics", f"cam02={calib}", env=ros_env)
    assert r.returncode == 0, r.stdout + r.stderr
    cams = {c["name"]: c for c in yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]}
    assert not cams["cam02"]["intrinsics_estimated"] and np.allclose(cams["cam02"]["K"], truth.K, atol=1e-5)


def _eval_cameras(out, bag, env):
    r = yowo("eval", out, "--bag", bag, "--metrics", out / "metrics.json", env=env)
    assert r.returncode == 0, r.stderr
    return json.loads((out / "metrics.json").read_text())["registration"]["cameras"]


def test_the_offline_api_maps_a_driver_layout_with_its_split_imu(recordings):
    """yowo_bringup.offline takes the ego camera's and IMU's topics from the run's plan, as the
    graph does: the realsense layout's colour, depth, split gyro/accelerometer and /tf_static
    extrinsics give the map the own layout gives."""
    from yowo_bringup.config import YowoConfig
    from yowo_bringup.offline import ego_topics
    from yowo_ego.recording import map_bag

    topics = ego_topics(recordings / "realsense", YowoConfig())
    assert topics.color.startswith("/camera/camera/color/") and topics.gyro and topics.accel
    assert "T_cam_imu" in topics.imu_calibration_text
    ego, recording = map_bag(recordings / "realsense", topics=topics)
    own, _ = map_bag(recordings / "own")
    assert ego.imu and own.imu and not recording.problems, recording.problems
    assert len(ego.stamps_ns) == len(own.stamps_ns)
    gap = np.linalg.norm(np.asarray(ego.T_world_cam)[:, :3, 3] - np.asarray(own.T_world_cam)[:, :3, 3], axis=1)
    assert gap.max() < 0.02, gap.max()
