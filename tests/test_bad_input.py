"""The bad-input catalogue: each case gives a clear message naming what is wrong and
where, partial results where possible, and a non-zero exit only when nothing useful exists."""

import json
import subprocess
import sys
import threading

import pytest
import yaml

from e2e_helpers import kill_when_playing, three_camera_recording, yowo
from yowo_common.ros.bag import BagWriter, list_topics, read_messages


def test_truncated_recording_is_played_up_to_its_last_readable_message(tmp_path, ros_env):
    cams, _ = three_camera_recording(tmp_path / "rec")
    full = {t.name: t.count for t in list_topics(tmp_path / "rec")}
    (mcap,) = (tmp_path / "rec").glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: int(len(data) * 0.7)])  # the recorder died: no summary, no footer
    (tmp_path / "rec" / "metadata.yaml").unlink()  # and it never wrote metadata.yaml
    r = yowo("info", tmp_path / "rec", env=ros_env)
    assert r.returncode == 0 and "damaged" in r.stdout and "recovered" in r.stdout, r.stdout + r.stderr
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", tmp_path / "out", env=ros_env)
    assert r.returncode == 0, r.stderr
    assert "recovered" in r.stderr and str(mcap) in r.stderr  # the console says what was recovered
    log = yaml.safe_load((tmp_path / "out" / "run_log.yaml").read_text())
    played = log["replay_published"]
    # Most of the walk was there and is played, every message of it reaches its stage.
    for topic, n in played.items():
        assert 0.55 * full[topic] < n < full[topic], (topic, n, full[topic])
        assert log["received"][topic] == {f"keypoint_tracker_{topic.split('/')[2]}": n}
    assert "recovered" in log["replay_error"]
    r = yowo(
        "eval", tmp_path / "out", "--bag", tmp_path / "rec", "--metrics", tmp_path / "out" / "metrics.json", env=ros_env
    )
    assert r.returncode == 0, r.stderr
    rel = json.loads((tmp_path / "out" / "metrics.json").read_text())["relative"]["summary"]
    assert rel["count"] == len(cams) and rel["pos_max"] < 0.05, rel
    # Cut inside its first record, nothing is readable: a clear message, exit 2.
    mcap.write_bytes(data[:30])
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", tmp_path / "out2", env=ros_env)
    assert r.returncode == 2 and str(tmp_path / "rec") in r.stderr and "Traceback" not in r.stderr, r.stderr


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


@pytest.mark.parametrize("tracker_processes", [8, 2])
def test_killed_stages_are_restarted_and_every_camera_is_calibrated(tmp_path, ros_env, tracker_processes):
    """With 8 tracker processes each camera has its own; with 2, c1 and c3 share one (which
    the kill takes down together), c2 has the other."""
    cams, _ = three_camera_recording(tmp_path / "rec", duration_s=40.0)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "yowo_bringup.cli",
            "calibrate-cmc",
            str(tmp_path / "rec"),
            "-o",
            str(out),
            "--rate",
            "1.0",
            "--set",
            f"supervisor.tracker_processes={tracker_processes}",
        ],
        env=ros_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    # The tracker dies mid-replay (it must be sent what it missed), the group SfM later (its
    # inputs come again from the trackers' durable streams).
    killers = [
        threading.Thread(target=kill_when_playing, args=(out, "keypoint_tracker_c1", 8.0)),
        threading.Thread(target=kill_when_playing, args=(out, "group_sfm", 20.0)),
    ]
    for k in killers:
        k.start()
    console, err = proc.communicate(timeout=300)
    for k in killers:
        k.join()
    assert proc.returncode == 0, err
    shared = tracker_processes == 2
    tracker = "keypoint_trackers_0" if shared else "keypoint_tracker_c1"
    hosting = " (hosting keypoint_tracker_c1, keypoint_tracker_c3)" if shared else ""
    assert f"node '{tracker}'{hosting} died (exit -9); restarted it" in console, console
    assert "node 'group_sfm' died (exit -9); restarted it" in console
    doc = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    assert sorted(c["name"] for c in doc if c["status"] == "ok") == sorted(cams)
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    assert log["restarts"] == {tracker: [-9], "group_sfm": [-9]}
    assert len(log["graph"]["processes"]) == (2 if shared else 3) + 2  # + the group SfM and the replay
    assert log["replay_resent"] > 0  # what the tracker had been sent before it died
    for topic, n in log["replay_published"].items():  # the restarted tracker got every message
        assert log["received"][topic] == {f"keypoint_tracker_{topic.split('/')[2]}": n}, topic
    # ... in order: it kept every frame (none "not after the previous frame")
    for c in ("c1", "c3"):
        assert log["stages"][f"keypoint_tracker_{c}"] == log["stages"]["keypoint_tracker_c2"].replace("c2", c)
    r = yowo("eval", out, "--bag", tmp_path / "rec", "--metrics", out / "metrics.json", env=ros_env)
    assert r.returncode == 0, r.stderr
    rel = json.loads((out / "metrics.json").read_text())["relative"]["summary"]
    assert rel["count"] == 3 and rel["pos_max"] < 0.03, rel


def test_killed_replay_ends_the_run_with_its_name(tmp_path, ros_env):
    three_camera_recording(tmp_path / "rec", duration_s=60.0)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "yowo_bringup.cli",
            "calibrate-cmc",
            str(tmp_path / "rec"),
            "-o",
            str(out),
            "--rate",
            "1.0",
        ],
        env=ros_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    killer = threading.Thread(target=kill_when_playing, args=(out, "replay", 3.0))
    killer.start()
    _, err = proc.communicate(timeout=180)
    killer.join()
    assert proc.returncode == 1
    assert "node 'replay' died (exit -9); the replay cannot be restarted" in err
    assert "Traceback (most recent call last)" not in err.split("died")[0]
    assert (out / "run_log.yaml").exists()
