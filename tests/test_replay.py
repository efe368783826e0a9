"""Replay through the real middleware: lossless delivery to a slow subscriber,
ground truth withheld, damaged recordings reported."""

import json
import subprocess
import sys

import numpy as np
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Header

from yowo_common.ros.bag import BagWriter
from yowo_common.rosconv import encode_color_jpeg, ns_to_time
from yowo_msgs.msg import AgentKeypoints, Keypoint2D


def make_bag(path, n_kp=300, img_every=10):
    rng = np.random.default_rng(0)
    with BagWriter(path) as bag:
        for i in range(n_kp):
            stamp = 10**18 + i * 10_000_000
            h = Header(stamp=ns_to_time(stamp), frame_id="cam0_optical_frame")
            bag.write(
                "/cmc/cam0/agent_keypoints",
                AgentKeypoints(header=h, camera_name="cam0", keypoints=[Keypoint2D(id=0, x=float(i))]),
                stamp,
            )
            bag.write("/gt/ego/pose", PoseStamped(header=h), stamp)
            if i % img_every == 0:
                img = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
                bag.write("/cmc/cam0/image_raw/compressed", encode_color_jpeg(img, h), stamp)


def replay_cmd(bag, wait_for, rate=0.0):
    return [
        sys.executable,
        "-m",
        "yowo_bringup.replay_node",
        "--ros-args",
        "-p",
        f"bag:={bag}",
        "-p",
        f"wait_for_topics:=[{','.join(wait_for)}]",
        "-p",
        f'config:="{{rate: {rate}, linger_s: 1.0}}"',
    ]


def test_lossless_replay_to_slow_subscriber(tmp_path, ros_env, start_script):
    bag = tmp_path / "rec"
    make_bag(bag)
    topics = {
        "/cmc/cam0/agent_keypoints": "yowo_msgs/msg/AgentKeypoints",
        "/cmc/cam0/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
        "/gt/ego/pose": "geometry_msgs/msg/PoseStamped",
    }
    listener = start_script("count_listener.py", 0.003, *[f"{t}={m}" for t, m in topics.items()])
    replay = subprocess.run(replay_cmd(bag, list(topics)[:2]), env=ros_env, capture_output=True, text=True, timeout=120)
    out, err = listener.communicate(timeout=120)
    assert replay.returncode == 0, replay.stderr
    result = json.loads(out)
    assert result["published"] == {"/cmc/cam0/agent_keypoints": 300, "/cmc/cam0/image_raw/compressed": 30}
    assert result["received"] == {
        "/cmc/cam0/agent_keypoints": 300,
        "/cmc/cam0/image_raw/compressed": 30,
        "/gt/ego/pose": 0,
    }


def test_replay_of_missing_bag_fails_with_message(tmp_path, ros_env):
    r = subprocess.run(replay_cmd(tmp_path / "nope", []), env=ros_env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert "no such recording" in r.stderr
