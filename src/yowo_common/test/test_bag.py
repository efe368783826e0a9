import json

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, TransformStamped
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from yowo_common.geometry import look_at
from yowo_common.ros.bag import (
    BagError,
    BagWriter,
    interface_share_dir,
    list_topics,
    read_messages,
    recording_gaps,
    recording_label,
    recording_span,
    typestore,
)
from yowo_common.rosconv import matrix_to_pose, matrix_to_transform, ns_to_time, pose_to_matrix
from yowo_msgs.msg import AgentKeypoints, Keypoint2D


def compiled_hash(msgtype: str) -> str:
    pkg, _, name = msgtype.split("/")
    desc = json.loads((interface_share_dir(pkg) / "msg" / f"{name}.json").read_text())
    return next(h["hash_string"] for h in desc["type_hashes"] if h["type_name"] == msgtype)


@pytest.mark.parametrize(
    "msgtype",
    [
        "tf2_msgs/msg/TFMessage",
        "yowo_msgs/msg/AgentKeypoints",
        "yowo_msgs/msg/EgoMap",
        "yowo_msgs/msg/RegisteredCameraArray",
        "yowo_msgs/msg/CameraGroupArray",
        "yowo_msgs/msg/SceneLayout",
        "yowo_msgs/msg/ReplayStatus",
    ],
)
def test_type_hashes_match_compiled_interfaces(msgtype):
    """Bags we write carry the hash rclpy's compiled types have (and upstream's, for TFMessage)."""
    assert typestore().hash_rihs01(msgtype) == compiled_hash(msgtype)


def test_tfmessage_matches_upstream_jazzy():
    from rosbags.typesys import Stores, get_typestore

    assert compiled_hash("tf2_msgs/msg/TFMessage") == get_typestore(Stores.ROS2_JAZZY).hash_rihs01(
        "tf2_msgs/msg/TFMessage"
    )


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_write_read_roundtrip(tmp_path, storage):
    path = tmp_path / "bag"
    T = look_at([1, 2, 3], [0, 0, 0])
    with BagWriter(path, storage=storage) as bag:
        for i in range(3):
            stamp = 1_000_000_000 + i * 100_000_000
            kp = AgentKeypoints(
                header=Header(stamp=ns_to_time(stamp), frame_id="cam0_optical_frame"),
                camera_name="cam0",
                keypoints=[Keypoint2D(id=0, x=10.5 + i, y=20.25, confidence=0.9)],
            )
            bag.write("/cmc/cam0/agent_keypoints", kp, stamp)
            bag.write(
                "/gt/ego/pose",
                PoseStamped(header=Header(stamp=ns_to_time(stamp), frame_id="map"), pose=matrix_to_pose(T)),
                stamp,
            )
        tf = TFMessage(
            transforms=[TransformStamped(child_frame_id="cam0_optical_frame", transform=matrix_to_transform(T))]
        )
        bag.write("/tf_static", tf, 1_000_000_000, latched=True)
    topics = {t.name: t for t in list_topics(path)}
    assert topics["/cmc/cam0/agent_keypoints"].count == 3
    assert topics["/tf_static"].msgtype == "tf2_msgs/msg/TFMessage"
    msgs = list(read_messages(path, ["/cmc/cam0/agent_keypoints", "/gt/ego/pose"]))
    assert [m[0] for m in msgs].count("/gt/ego/pose") == 3
    kps = [m[2] for m in msgs if m[0] == "/cmc/cam0/agent_keypoints"]
    assert [k.keypoints[0].x for k in kps] == [10.5, 11.5, 12.5]
    pose = next(m[2] for m in msgs if m[0] == "/gt/ego/pose")
    np.testing.assert_allclose(pose_to_matrix(pose.pose), T, atol=1e-12)


def test_missing_and_damaged_bags_are_named(tmp_path):
    with pytest.raises(BagError, match="no such recording"):
        list_topics(tmp_path / "nope")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "bad_0.mcap").write_bytes(b"\x89MCAP0\r\n" + b"garbage" * 10)
    with pytest.raises(BagError, match=str(bad)):
        list(read_messages(bad))


def _walk(path, start_s: float, n: int, topic_type=Header):
    """A small recording: n messages 0.1 s apart from start_s, on /a (latched /info at the start)."""
    with BagWriter(path) as bag:
        bag.write("/info", Header(frame_id=str(path.name)), int(start_s * 1e9), latched=True)
        for i in range(n):
            stamp = int((start_s + 0.1 * i) * 1e9)
            msg = Header(stamp=ns_to_time(stamp), frame_id=path.name) if topic_type is Header else topic_type()
            bag.write("/a", msg, stamp)


def test_recordings_read_as_one_in_time_order(tmp_path):
    """A second walk recorded after the first (and a file overlapping it) is read as one
    recording: topics counted over all files, messages merged by log time, the silence between
    the walks reported (the replay does not wait it out)."""
    first, second, third = tmp_path / "first", tmp_path / "second", tmp_path / "third"
    _walk(first, 100.0, 5)
    _walk(second, 200.0, 3)
    _walk(third, 100.25, 2)
    joined = [second, first, third]  # any order given: time decides
    topics = {t.name: t for t in list_topics(joined)}
    assert topics["/a"].count == 10 and topics["/info"].count == 3 and topics["/info"].latched
    stamps = [ns for topic, ns, _ in read_messages(joined, ["/a"])]
    assert stamps == sorted(stamps) and len(stamps) == 10
    names = [m.frame_id for _, _, m in read_messages(joined, ["/a"])]
    assert names == ["first"] * 3 + ["third"] + ["first"] + ["third"] + ["first"] + ["second"] * 3
    ms = 1_000_000  # rosbags' end times are 1 ns after the last message
    assert [t // ms for t in recording_span(joined)] == [100_000, 200_200]
    assert [[t // ms for t in gap] for gap in recording_gaps(joined)] == [[100_400, 200_000]]
    assert recording_gaps(first) == [] and recording_label(joined).count(" + ") == 2


def test_recordings_that_disagree_on_a_topics_type_are_refused(tmp_path):
    from std_msgs.msg import String

    _walk(tmp_path / "first", 100.0, 2)
    _walk(tmp_path / "second", 200.0, 2, topic_type=String)
    with pytest.raises(BagError, match=r"second: topic /a is std_msgs/msg/String here and std_msgs/msg/Header"):
        list_topics([tmp_path / "first", tmp_path / "second"])
    with pytest.raises(BagError, match="no recording given"):
        list_topics([])
