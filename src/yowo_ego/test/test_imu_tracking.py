"""Gyro-aided ego tracking: the gyro rotation between camera stamps against the simulator's
ground truth, a scripted stretch that vision alone cannot track, bridged with the IMU,
and the wiring (offline reader, node, run planner)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from std_msgs.msg import String

from yowo_bringup.config import YowoConfig
from yowo_bringup.run import EGO, FULL, plan_run
from yowo_common import topics
from yowo_common.ros.bag import BagWriter, list_topics, read_messages
from yowo_common.rosconv import stamp_to_ns
from yowo_common.trajectory import Trajectory
from yowo_ego.config import EgoParams
from yowo_ego.ego_messages import ego_map_msg
from yowo_ego.imu import CoverageWait, ImuBuffer, ImuCalibration, ImuSamples
from yowo_ego.odometry import INTERPOLATED, SKIPPED
from yowo_ego.pipeline import map_recording
from yowo_ego.recording import COLOR_TOPICS, DEPTH_TOPICS, INFO_TOPIC, map_bag
from yowo_eval.ground_truth import read_ground_truth
from yowo_eval.metrics import ate
from yowo_sim.capture import EGO_FRAME, build_capture
from yowo_sim.imu import ImuParams, calibration_yaml, simulate_imu
from yowo_sim.presets import get_preset

IMU_TOPICS = {topics.EGO_IMU, topics.EGO_IMU_CALIBRATION, topics.GT_EGO_IMU_BIAS, topics.TF_STATIC}


def _deg(Ra, Rb) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(Ra.T @ Rb).as_rotvec())))


def _buffer(data, params: ImuParams) -> ImuBuffer:
    imu = ImuBuffer(ImuCalibration.from_yaml(calibration_yaml(params, EGO_FRAME)))
    imu.extend(ImuSamples(data.stamps_ns, data.gyro, data.accel))
    return imu


@pytest.fixture(scope="module")
def walk():
    """The tiny preset's walk (seed 3: ~6 s, head turns up to ~300 deg/s)."""
    return build_capture(get_preset("tiny"), 3).walk


def _windows(walk, length_s: float):
    """(t0, t1) in seconds: 1 s windows every 0.5 s, ends off the IMU's sample grid."""
    t0 = np.arange(0.013, walk.duration_s - length_s - 0.01, 0.5)
    return [(a, a + length_s) for a in t0]


def _truth(walk, a: float, b: float) -> np.ndarray:
    return walk.ego_pose_at(a)[:3, :3].T @ walk.ego_pose_at(b)[:3, :3]


def test_gyro_rotation_matches_the_ground_truth(walk):
    """rotation_between (camera frame, T_cam_imu applied) over 1 s windows of a real walk:
    noise-free within 0.05 deg; with the default noise within the turn-on bias' drift
    (|b| t) plus a few sigma of white noise, and with the true bias removed within the
    white noise alone (0.014 deg per axis over 1 s)."""
    params = ImuParams()
    free = _buffer(simulate_imu(walk, params.noise_free(), 3, 0), params)
    noisy_data = simulate_imu(walk, params, 3, 0)
    noisy = _buffer(noisy_data, params)
    windows = _windows(walk, 1.0)
    assert len(windows) >= 8
    err_free, err_noisy, err_debiased, turned = [], [], [], []
    for a, b in windows:
        t0, t1 = int(a * 1e9), int(b * 1e9)
        R_true = _truth(walk, a, b)
        turned.append(_deg(np.eye(3), R_true))
        err_free.append(_deg(free.rotation_between(t0, t1), R_true))
        err_noisy.append(_deg(noisy.rotation_between(t0, t1), R_true))
        noisy.bias = noisy_data.gyro_bias[int(a * params.rate_hz)]
        err_debiased.append(_deg(noisy.rotation_between(t0, t1), R_true))
        noisy.bias = np.zeros(3)
    assert max(turned) > 30.0  # the head turns: a still camera proves nothing
    assert max(err_free) < 0.05
    bias_drift_deg = np.degrees(np.linalg.norm(noisy_data.gyro_bias[0])) * 1.0
    white_deg = np.degrees(params.gyro_noise_density)  # per axis over 1 s
    assert max(err_noisy) < bias_drift_deg + 5 * white_deg
    assert max(err_debiased) < 5 * white_deg
    assert np.median(err_noisy) > 2 * np.median(err_debiased)  # the bias is what is left


def test_bias_follows_tracked_rotations(walk):
    """Fed the true rotations of consecutive 15 Hz frames, the running estimate converges
    on the true gyro bias (IMU frame); integrated with it, the gyro drifts less."""
    params = ImuParams()
    data = simulate_imu(walk, params, 5, 0)
    imu = _buffer(data, params)
    stamps = np.arange(0, int((walk.duration_s - 0.05) * 1e9), 66_666_667)
    for a, b in zip(stamps[:-1], stamps[1:]):
        imu.update_bias(_truth(walk, a * 1e-9, b * 1e-9), int(a), int(b), time_constant_s=1.0)
    true_bias = data.gyro_bias[int(stamps[-1] * 1e-9 * params.rate_hz)]
    assert np.linalg.norm(true_bias) > 1.5e-3  # a bias worth estimating (0.12 deg/s)
    assert np.linalg.norm(imu.bias - true_bias) < 0.2 * np.linalg.norm(true_bias)
    errors = []
    for bias in (imu.bias, np.zeros(3)):
        imu.bias = bias
        errors.append(
            np.mean(
                [
                    _deg(imu.rotation_between(int(a * 1e9), int(b * 1e9)), _truth(walk, a, b))
                    for a, b in _windows(walk, 1.0)
                ]
            )
        )
    assert errors[0] < 0.5 * errors[1]


def test_calibration_errors_name_the_topic():
    good = calibration_yaml(ImuParams(), EGO_FRAME)
    cal = ImuCalibration.from_yaml(good)
    np.testing.assert_allclose(cal.T_cam_imu, ImuParams().T_cam_imu)
    assert cal.gyroscope_noise_density == ImuParams().gyro_noise_density and cal.update_rate_hz == 200.0
    bad = {
        "not: [yaml": "not YAML",
        "- 1\n- 2": "expected a YAML mapping",
        good.replace("gyroscope_noise_density", "gyro_noise"): "missing gyroscope_noise_density",
        good.replace("update_rate: 200.0", "update_rate: fast"): "update_rate must be a number",
        good.replace("update_rate: 200.0", "update_rate: 0"): "update_rate must be > 0",
    }
    doc_T = "T_cam_imu:\n- [2, 0, 0, 0]\n- [0, 1, 0, 0]\n- [0, 0, 1, 0]\n- [0, 0, 0, 1]\n"
    bad[good.split("T_cam_imu:")[0] + doc_T] = "T_cam_imu is not a rigid transform"
    for text, why in bad.items():
        with pytest.raises(ValueError, match=f"^{topics.EGO_IMU_CALIBRATION}: {why}"):
            ImuCalibration.from_yaml(text)


def test_samples_and_coverage():
    with pytest.raises(ValueError, match="not strictly increasing"):
        ImuSamples(np.array([0, 5, 5]), np.zeros((3, 3)), np.zeros((3, 3)))
    imu = ImuBuffer(ImuCalibration.from_yaml(calibration_yaml(ImuParams(), EGO_FRAME)), capacity=2)
    wait = CoverageWait(imu, max_wait_ns=100)
    assert wait.push(10, "a") == []  # no sample at or after 10 yet
    for t in (0, 5, 5, 12):  # the repeated stamp is dropped
        imu.add(t, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))
    assert len(imu) == 3 and imu.rejected == 1 and imu.covers(12) and not imu.covers(13)
    assert wait.ready() == ["a"] and wait.released_without == 0
    # Constant rate about the IMU's z axis for 12 ns, seen in the camera frame.
    R_ci = imu.calibration.T_cam_imu[:3, :3]
    expected = R_ci @ Rotation.from_rotvec([0, 0, 12e-9]).as_matrix() @ R_ci.T
    np.testing.assert_allclose(imu.rotation_between(0, 12), expected, atol=1e-15)
    with pytest.raises(ValueError, match="do not cover"):
        imu.rotation_between(0, 20)
    # A frame the IMU never covers goes on once a frame 100 ns newer arrived, or at the end.
    assert wait.push(50, "b") == [] and wait.push(151, "c") == ["b"] and wait.released_without == 1
    assert wait.ready(flush=True) == ["c"] and wait.released_without == 2
    # Without a bound (the node), only coverage or the end of the stream release a frame.
    unbounded = CoverageWait(imu, None)
    assert unbounded.push(13, "d") == [] and unbounded.push(10**12, "e") == []
    imu.add(20, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))
    assert unbounded.ready() == ["d"] and unbounded.ready(flush=True) == ["e"]
    # No rotation across a gap in the samples (50 ms here).
    imu.add(20 + 60_000_000, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))
    with pytest.raises(ValueError, match="gap of 0.060 s"):
        imu.rotation_between(15, 30_000_000)


def test_vision_loss_is_bridged_by_the_gyro(dark_walk, tiny_bag):
    """0.53 s (8 frames) in the middle of the tiny walk carry nothing to track. Vision
    alone breaks at every one of them and after (a new segment each; ATE ~0.12 m here
    without relocalisation, which test_relocalisation.py covers and is off here); with
    the IMU each is bridged, the walk stays one segment and the ATE stays at the
    centimetre the walk reaches with every frame visible."""
    recording, frames, _ = dark_walk
    assert (frames[68][0] - frames[60][0]) * 1e-9 == pytest.approx(0.53, abs=0.01)
    gt = read_ground_truth(tiny_bag).ego
    params = EgoParams()
    params = replace(params, loops=replace(params.loops, retrieval=replace(params.loops.retrieval, enabled=False)))
    runs = {}
    for name, imu in (("vision", None), ("imu", recording.imu)):
        r = map_recording(frames, recording.camera, params, imu=imu)
        runs[name] = (r, ate(Trajectory(r.stamps_ns, r.T_world_cam), gt).rmse_m)
    (vision, ate_vision), (inertial, ate_imu) = runs["vision"], runs["imu"]
    assert len(vision.stamps_ns) == len(inertial.stamps_ns) == len(frames)  # all reach the tracker
    assert vision.stats["breaks"] >= 8 and vision.stats["imu_bridged"] == 0
    assert inertial.stats["breaks"] == 0 and inertial.stats["imu_bridged"] >= 8
    assert inertial.stats["imu_bridged"] <= 10  # the 8, the first frame after, little more
    assert ate_imu < 0.02 and ate_vision > 3 * ate_imu


def _copy(src, dst, keep) -> None:
    kept = {t.name: t.latched for t in list_topics(src) if keep(t.name)}
    with BagWriter(dst) as out:
        for topic, stamp, msg in read_messages(src, list(kept)):
            out.write(topic, msg, stamp, latched=kept[topic])


def test_planner_plays_the_imu_when_recorded(tiny_bag, tmp_path):
    """Full and ego-only plans play /ego/imu and its calibration to the ego mapper when the
    recording has both; without the calibration topic its extrinsics come from /tf_static;
    with neither, or without the IMU, the plan plays what it did before."""
    _copy(tiny_bag, tmp_path / "no_cmc", lambda t: not t.startswith("/cmc/"))
    _copy(tiny_bag, tmp_path / "no_imu", lambda t: t not in IMU_TOPICS)
    _copy(tiny_bag, tmp_path / "no_calibration", lambda t: t != topics.EGO_IMU_CALIBRATION)
    _copy(tiny_bag, tmp_path / "no_extrinsics", lambda t: t not in (topics.EGO_IMU_CALIBRATION, topics.TF_STATIC))
    for bag, mode, imu, calibration in (
        ("full", FULL, True, "topic"),
        ("no_cmc", EGO, True, "topic"),
        ("no_imu", FULL, False, ""),
        ("no_calibration", FULL, True, "tf"),
        ("no_extrinsics", FULL, False, ""),
    ):
        plan = plan_run(tiny_bag if bag == "full" else tmp_path / bag, tmp_path / f"out_{bag}")
        assert plan.mode == mode, bag
        nodes = {n.name: n for n in plan.nodes}
        ego = nodes["ego_mapper"].parameters
        played = set(nodes["replay"].parameters["topics"])
        assert (topics.EGO_IMU in played) == imu and (topics.EGO_IMU_CALIBRATION in played) == (calibration == "topic")
        assert not any(t.startswith(topics.GT_PREFIX) for t in played)
        assert ego.get("imu_topic", "") == (topics.EGO_IMU if imu else ""), bag
        assert bool(ego.get("imu_calibration")) == (calibration == "tf"), bag
        assert plan.inputs["imu"]["used"] == imu, plan.inputs
        assert plan.replay_messages == sum(t.count for t in list_topics(plan.bag) if t.name in played)
    assert "no extrinsics" in plan.inputs["imu"]["reason"]
    # Told not to use it, the graph neither plays nor waits for it.
    off = plan_run(
        tiny_bag,
        tmp_path / "out_off",
        config=YowoConfig(ego=EgoParams(odometry=replace(EgoParams().odometry, use_imu=False))),
    )
    nodes = {n.name: n for n in off.nodes}
    assert topics.EGO_IMU not in nodes["replay"].parameters["topics"]
    assert not nodes["ego_mapper"].parameters.get("imu_topic")


@pytest.fixture
def imu_node(make_node):
    """The node told of an IMU."""
    return make_node("-p", f"imu_topic:={topics.EGO_IMU}")


def test_node_waits_for_the_imu_covering_each_frame(imu_node, tiny_bag):
    """Frames that arrive before the IMU samples covering them are held (2 s of them:
    no bound in stream time, which would depend on the executor's timing), then tracked
    with the gyro once the samples (and the calibration) are there."""
    node, imu_msgs, calibration, frames = imu_node, [], None, 0
    wanted = [COLOR_TOPICS[1], DEPTH_TOPICS[1], INFO_TOPIC, topics.EGO_IMU, topics.EGO_IMU_CALIBRATION]
    for topic, _, msg in read_messages(tiny_bag, wanted):
        if topic == topics.EGO_IMU:
            imu_msgs.append(msg)
        elif topic == topics.EGO_IMU_CALIBRATION:
            calibration = msg
        elif topic == INFO_TOPIC:
            node.on_info(msg)
        elif frames < 30:  # 2 s of frames, all before any IMU message
            add = node.pairer.add_color if topic == COLOR_TOPICS[1] else node.pairer.add_depth
            node.on_waiting(add(stamp_to_ns(msg.header.stamp), msg))
            frames += topic == COLOR_TOPICS[1]
    assert node.published["/yowo/ego/odometry"] == 0 and len(node.wait._held) >= 29
    last = max(s for s, _ in node.wait._held)
    for msg in imu_msgs:
        node.on_imu(msg)
        if stamp_to_ns(msg.header.stamp) > last:
            break
    assert node.published["/yowo/ego/odometry"] == 0  # no calibration yet: still held
    node.on_imu_calibration(calibration)
    # All released: tracked, but the newest, which is being prepared while the one before is tracked.
    assert len(node.preparing) <= 1
    assert node.published["/yowo/ego/odometry"] + len(node.preparing) >= 29
    # Every frame tracked after the first used the gyro; it also let slow frames be skipped
    # (OdometryParams.skip, only with the IMU).
    tracked = sum(r.status not in (SKIPPED, INTERPOLATED) for r in node.mapper.tracker.results)
    assert node.mapper.tracker.imu_frames == tracked - 1 and tracked < len(node.mapper.tracker.results)
    assert node.wait.released_without == 0


def test_node_with_a_malformed_calibration_tracks_without_the_imu(imu_node, tiny_bag):
    node = imu_node
    node.on_imu_calibration(String(data="T_cam_imu: [1, 2]"))
    assert node.wait.imu is None and f"{topics.EGO_IMU_CALIBRATION}: missing" in node.imu_problem
    frames = 0
    for topic, _, msg in read_messages(tiny_bag, [COLOR_TOPICS[1], DEPTH_TOPICS[1], INFO_TOPIC]):
        if topic == INFO_TOPIC:
            node.on_info(msg)
        elif frames < 45:  # 3 s: enough for a map to finish
            add = node.pairer.add_color if topic == COLOR_TOPICS[1] else node.pairer.add_depth
            node.on_waiting(add(stamp_to_ns(msg.header.stamp), msg))
            frames += topic == COLOR_TOPICS[1]
    assert node.published["/yowo/ego/odometry"] + len(node.preparing) >= 44 and node.mapper.tracker.imu_frames == 0
    assert "the IMU is not used" in node.finalize()


def test_use_imu_off_equals_a_recording_without_imu(tiny_bag, tmp_path):
    """use_imu=False reads and tracks exactly what a recording without the IMU gives."""
    _copy(tiny_bag, tmp_path / "no_imu", lambda t: t not in IMU_TOPICS)
    off, _ = map_bag(tiny_bag, EgoParams(odometry=replace(EgoParams().odometry, use_imu=False)))
    none, _ = map_bag(tmp_path / "no_imu")
    assert off.stats["imu_frames"] == 0 and none.stats["imu_frames"] == 0
    assert not off.imu and not none.imu  # the fusion is told (EgoMap.imu)
    np.testing.assert_array_equal(off.trajectories["odometry"], none.trajectories["odometry"])
    on, _ = map_bag(tiny_bag)
    # Every frame tracked after the first used the gyro (the others were skipped: OdometryParams.skip).
    assert on.stats["skipped_frames"] > 0
    assert on.stats["imu_frames"] == len(on.stamps_ns) - 1 - on.stats["skipped_frames"]
    assert on.imu and ego_map_msg(on).imu
    assert not np.array_equal(on.trajectories["odometry"], off.trajectories["odometry"])
