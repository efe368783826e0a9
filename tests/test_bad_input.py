"""The bad-input catalogue: each case gives a clear message naming what is wrong and
where, partial results where possible, and a non-zero exit only when nothing useful exists."""
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import yaml

from e2e_helpers import three_camera_recording, yowo
from yowo_common.ros.bag import BagWriter, read_messages


def test_missing_and_empty_recordings(tmp_path, ros_env):
    r = yowo("calibrate-cmc", tmp_path / "nope", "-o", tmp_path / "out", env=ros_env)
    assert r.returncode == 2 and "no such recording" in r.stderr and "Traceback" not in r.stderr
    with BagWriter(tmp_path / "empty"):
        pass
    r = yowo("calibrate-cmc", tmp_path / "empty", "-o", tmp_path / "out", env=ros_env)
    assert r.returncode == 2 and "holds no messages" in r.stderr and "Traceback" not in r.stderr


def test_truncated_mcap_is_named(tmp_path, ros_env):
    three_camera_recording(tmp_path / "rec")
    (mcap,) = (tmp_path / "rec").glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    r = yowo("info", tmp_path / "rec", env=ros_env)
    assert r.returncode == 2 and str(tmp_path / "rec") in r.stderr and "Traceback" not in r.stderr


def test_zero_camera_info_and_blind_camera_give_partial_results(tmp_path, ros_env):
    def tamper(cams, tracks):
        tracks[2].camera.K = np.zeros((3, 3))              # c3: CameraInfo with K = 0
    three_camera_recording(tmp_path / "rec", tamper=tamper)
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", tmp_path / "out", env=ros_env)
    doc = yaml.safe_load((tmp_path / "out" / "cameras.yaml").read_text())["cameras"]
    by_name = {c["name"]: c for c in doc}
    assert by_name["c3"]["status"] == "failed" and "CameraInfo" in by_name["c3"]["reason"]
    assert by_name["c1"]["status"] == "ok" and by_name["c2"]["status"] == "ok"
    assert r.returncode == 0, r.stderr
    log = (tmp_path / "out" / "logs" / "keypoint_tracker_c3.log").read_text()
    assert "/cmc/c3/camera_info" in log and "focal" in log


def test_non_monotonic_stamps_are_rejected_and_counted(tmp_path, ros_env):
    three_camera_recording(tmp_path / "good")
    # Rewrite the recording with two of c1's keypoint messages carrying swapped header stamps.
    msgs = list(read_messages(tmp_path / "good"))
    c1 = [i for i, (t, _, _) in enumerate(msgs) if t == "/cmc/c1/agent_keypoints"]
    a, b = msgs[c1[10]][2], msgs[c1[11]][2]
    a.header.stamp, b.header.stamp = b.header.stamp, a.header.stamp
    with BagWriter(tmp_path / "rec") as bag:
        for topic, stamp, msg in msgs:
            bag.write(topic, msg, stamp)
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", tmp_path / "out", env=ros_env)
    assert r.returncode == 0, r.stderr
    stages = yaml.safe_load((tmp_path / "out" / "run_log.yaml").read_text())["stages"]
    assert "1 stamp not after the previous frame" in stages["keypoint_tracker_c1"]


def test_killed_node_fails_the_run_with_its_name(tmp_path, ros_env):
    three_camera_recording(tmp_path / "rec", duration_s=60.0)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "yowo_bringup.cli", "calibrate-cmc", str(tmp_path / "rec"),
                             "-o", str(out), "--rate", "1.0"], env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)

    def kill_group_sfm():
        # The supervisor records each node's pid; kill that one process once it exists.
        pid_file = out / "logs" / "group_sfm.pid"
        deadline = time.monotonic() + 60
        while not pid_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        time.sleep(2.0)  # mid-run
        os.kill(int(pid_file.read_text()), signal.SIGKILL)
    killer = threading.Thread(target=kill_group_sfm)
    killer.start()
    _, err = proc.communicate(timeout=180)
    killer.join()
    assert proc.returncode == 1
    assert "node 'group_sfm' died" in err and "Traceback (most recent call last)" not in err.split("died")[0]
