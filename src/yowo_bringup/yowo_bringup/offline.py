"""The pipeline's algorithms called directly on a recording, without the node graph
(for the benchmark and scripting). The graph runs the same functions inside nodes."""
from __future__ import annotations

from yowo_cmc.keypoint_input import TrackAccumulator, frame_from_msg
from yowo_cmc.tracks import CameraTracks
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import camera_info_to_model

from .contract import discover_inputs
from .run import cmc_info_topic, cmc_keypoints_topic


def read_cmc_tracks(bag) -> list[CameraTracks]:
    """Every CMC's validated agent keypoint tracks (cameras sorted by name, as the graph does)."""
    names = discover_inputs(bag).cmc_names
    acc = {n: TrackAccumulator(n) for n in names}
    by_topic = {cmc_info_topic(n): n for n in names} | {cmc_keypoints_topic(n): n for n in names}
    for topic, _, msg in read_messages(bag, by_topic):
        a = acc[by_topic[topic]]
        if topic.endswith("/camera_info"):
            if a.camera is None:
                a.camera = camera_info_to_model(msg)
        else:
            a.add(frame_from_msg(msg))
    return [a.tracks() for a in acc.values() if a.camera is not None and a.frames]
