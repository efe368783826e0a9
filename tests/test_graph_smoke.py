"""Smoke tests on the real middleware (Fast DDS, separate processes)."""

import os
import queue
import signal
import threading
import time

import numpy as np
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from yowo_common.camera import CameraModel
from yowo_common.ros.bag import BagWriter, read_messages
from yowo_common.ros.context import FLUSH_S
from yowo_common.rosconv import encode_raw, message_fields, model_to_camera_info, ns_to_time
from yowo_msgs.msg import AgentKeypoints, Keypoint2D

N = 200


def test_agent_keypoints_cross_process_all_arrive(start_script):
    listener = start_script("kp_listener.py", N)
    talker = start_script("kp_talker.py", N)
    t_out, t_err = talker.communicate(timeout=60)
    l_out, l_err = listener.communicate(timeout=60)
    assert talker.returncode == 0, t_err
    assert listener.returncode == 0, l_err
    lines = l_out.splitlines()
    assert len(lines) == N
    # Order and every field survive: rebuild what the talker sent.
    expected = [f"cam{i} " + " ".join(f"{j}:{i + 0.25 * j}:{2.0 * i - j}:0.5" for j in range(3)) for i in range(N)]
    assert lines == expected


def test_tf_static_reaches_late_joiner(start_script):
    pub = start_script("tf_static_late.py", "pub", 15)
    assert pub.stdout.readline().strip() == "published"
    time.sleep(1.0)  # the subscriber joins after the only publish
    sub = start_script("tf_static_late.py", "sub", 12)
    out, err = sub.communicate(timeout=30)
    assert sub.returncode == 0, err
    assert out.splitlines() == ["cam0_optical_frame 0.0", "cam1_optical_frame 1.0", "cam2_optical_frame 2.0"]


def test_bag_roundtrip_field_by_field(tmp_path):
    rng = np.random.default_rng(0)
    cam = CameraModel(64, 48, [[50.5, 0, 31.7], [0, 51.25, 23.9], [0, 0, 1]], [-0.1, 0.02, 0.001, 0, 0.003])
    sent = []
    with BagWriter(tmp_path / "rt") as bag:
        for i in range(4):
            stamp = 5_000_000_000 + i * 66_666_667
            header = Header(stamp=ns_to_time(stamp), frame_id="ego_optical_frame")
            img = encode_raw(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8), "rgb8", header)
            info = model_to_camera_info(cam, header)
            kp = AgentKeypoints(
                header=header,
                camera_name="ceiling_a",
                keypoints=[
                    Keypoint2D(id=k, x=float(rng.normal()), y=float(rng.normal()), confidence=0.25) for k in range(i)
                ],
            )
            for topic, msg in (
                ("/ego/color/image_raw", img),
                ("/ego/color/camera_info", info),
                ("/cmc/ceiling_a/agent_keypoints", kp),
            ):
                bag.write(topic, msg, stamp)
                sent.append((topic, stamp, msg))
    got = list(read_messages(tmp_path / "rt"))
    assert len(got) == len(sent)
    key = lambda item: (item[0], item[1])  # noqa: E731
    for (t_a, s_a, m_a), (t_b, s_b, m_b) in zip(sorted(sent, key=key), sorted(got, key=key)):
        assert (t_a, s_a, type(m_a)) == (t_b, s_b, type(m_b))
        assert message_fields(m_a) == message_fields(m_b)
    assert isinstance(got[0][2], (Image, CameraInfo, AgentKeypoints))


def _lines(proc) -> queue.Queue:
    """The process's stdout lines as they come (a reader thread): waits have a timeout."""
    lines = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line.strip()) for line in proc.stdout], daemon=True).start()
    return lines


def test_a_stopped_node_first_delivers_what_it_published(tmp_path, start_script):
    """Ctrl-C on a node right after its last publish (the supervisor stopping a stage that
    just finished): it stays up until its reader acknowledged the message, then ends."""
    go = tmp_path / "go"
    sub = start_script("flush_on_stop.py", "sub", 90)
    pub = start_script("flush_on_stop.py", "pub", go)
    sub_lines, pub_lines = _lines(sub), _lines(pub)
    assert sub_lines.get(timeout=60) == "matched" and pub_lines.get(timeout=60) == "matched"
    os.kill(sub.pid, signal.SIGSTOP)  # matched both ways, but cannot acknowledge anything now
    try:
        go.touch()
        assert pub_lines.get(timeout=30) == "published"
        pub.send_signal(signal.SIGINT)
        time.sleep(1.5)
        assert pub.poll() is None, "the publisher ended before its reader acknowledged the message"
    finally:
        os.kill(sub.pid, signal.SIGCONT)
    sub.wait(timeout=30)
    assert sub.returncode == 0 and sub_lines.get(timeout=5) == "final status"
    pub.wait(timeout=FLUSH_S + 5)
    assert pub.returncode == 0


def test_a_stopped_node_with_everything_delivered_ends_at_once(tmp_path, start_script):
    go = tmp_path / "go"
    go.touch()
    sub = start_script("flush_on_stop.py", "sub", 90)
    pub = start_script("flush_on_stop.py", "pub", go)
    sub_lines, pub_lines = _lines(sub), _lines(pub)
    assert pub_lines.get(timeout=60) == "matched" and pub_lines.get(timeout=30) == "published"
    assert sub_lines.get(timeout=60) == "matched" and sub_lines.get(timeout=30) == "final status"
    sub.wait(timeout=30)
    pub.send_signal(signal.SIGINT)
    pub.wait(timeout=FLUSH_S / 2)
    assert pub.returncode == 0
