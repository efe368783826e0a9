"""ego_mapper_node wiring: the recording's ego messages handed to the node's
callbacks (no DDS needed), then the end-of-stream outputs."""

import pytest
from sensor_msgs.msg import CameraInfo, CompressedImage

from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import stamp_to_ns
from yowo_ego.ego_mapper_node import MAX_EARLY_FRAMES
from yowo_ego.recording import COLOR_TOPICS, DEPTH_TOPICS, INFO_TOPIC


@pytest.fixture
def node(make_node):
    return make_node()


def test_node_streams_odometry_and_publishes_the_map(node, tiny_bag):
    frames = 0
    # A depth image whose colour never comes (stamp 1 ns, before the whole walk): dropped once
    # the first pair forms, and reported.
    node.on_pairs(node.pairer.add_depth(1, CompressedImage()))
    for topic, _, msg in read_messages(tiny_bag, [COLOR_TOPICS[1], DEPTH_TOPICS[1], INFO_TOPIC]):
        if frames == 45:  # the first 3 s are enough for the wiring
            break
        if topic == INFO_TOPIC:
            node.on_info(msg)
        elif topic == COLOR_TOPICS[1]:
            node.on_pairs(node.pairer.add_color(stamp_to_ns(msg.header.stamp), msg))
            frames += 1
        else:
            node.on_pairs(node.pairer.add_depth(stamp_to_ns(msg.header.stamp), msg))
    # Online, one per frame: all but the last colour image (which may still wait for its depth)
    # and the newest pair (prepared while the one before is tracked).
    assert len(node.preparing) <= 1 and node.published["/yowo/ego/odometry"] >= frames - 2
    # A corrupt image is reported against its topic and skipped, the stream goes on.
    node.on_pairs([(10**19, CompressedImage(format="jpeg", data=b"broken"), CompressedImage(data=b"x"))])
    summary = node.finalize()
    for topic in ("/yowo/ego/map", "/yowo/ego/path", "/yowo/map/points", "/yowo/layout"):
        assert node.published[topic] == 1
    assert (
        f"1 frame(s) rejected, the first: /ego/color/image_raw/compressed @ {10**19} ns: cannot decode the image"
        in summary
    )
    assert (
        f"1 {COLOR_TOPICS[1]} / {DEPTH_TOPICS[1]} image(s) without a partner within 5 ms dropped, the first: "
        f"{DEPTH_TOPICS[1]} @ 1 ns" in summary
    )


def test_node_without_usable_camera_info_fails_with_the_reason(node):
    node.on_info(CameraInfo(width=640, height=480))  # K = 0
    with pytest.raises(ValueError, match="/ego/color/camera_info: .*focal"):
        node.finalize()


def test_frames_before_the_first_camera_info_are_kept_up_to_a_bound_and_the_rest_reported(node, tiny_bag):
    """CameraInfo late (here after 40 frame pairs): the last MAX_EARLY_FRAMES wait for it and
    are mapped, the older ones are dropped and counted in the final status."""
    pairs, before = 0, None
    for topic, _, msg in read_messages(tiny_bag, [COLOR_TOPICS[1], DEPTH_TOPICS[1], INFO_TOPIC]):
        if topic == INFO_TOPIC:
            if pairs >= 40 and before is None:
                before = pairs
                node.on_info(msg)
            continue
        add = node.pairer.add_color if topic == COLOR_TOPICS[1] else node.pairer.add_depth
        paired = add(stamp_to_ns(msg.header.stamp), msg)
        pairs += len(paired)
        node.on_pairs(paired)
        if pairs == 75:
            break
    assert node.early_dropped == before - MAX_EARLY_FRAMES > 0
    summary = node.finalize()
    assert summary.startswith(f"{75 - node.early_dropped} frames")
    assert f"{before - MAX_EARLY_FRAMES} frame(s) before the first usable {INFO_TOPIC} dropped" in summary
