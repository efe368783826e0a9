"""The pipeline's algorithms called directly on a recording, without the node graph
(for the benchmark and scripting). The graph runs the same functions inside nodes."""
from __future__ import annotations

import time
from dataclasses import dataclass

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


def ego_map_data(ego) -> "EgoMapData":
    """yowo_ego's EgoMapResult -> the fusion's input: every frame's pose (the a2e factor
    needs the dense trajectory), observations re-indexed from keyframes to frames."""
    from yowo_fusion.pipeline import EgoMapData

    return EgoMapData(ego.camera, ego.stamps_ns, ego.T_world_cam, ego.landmarks, "SIFT", ego.descriptors,
                      ego.keyframe_frames[ego.obs_keyframe], ego.obs_landmark, ego.obs_uv)


def read_backgrounds(bag, names: list[str], period_s: float = 1.0) -> dict:
    """Each CMC's agent-free background (temporal median of sampled frames), when images were recorded."""
    from yowo_cmc.background import BackgroundSampler
    from yowo_common.rosconv import decode_color, stamp_to_ns

    from .contract import cmc_image_topics

    by_topic = {t: n for n in names for t in cmc_image_topics(n)}
    samplers = {n: BackgroundSampler(period_s) for n in names}
    for topic, _, msg in read_messages(bag, by_topic):
        s = samplers[by_topic[topic]]
        stamp = stamp_to_ns(msg.header.stamp)
        if s.wants(stamp):
            s.add(stamp, decode_color(msg))
    return {n: s.image() for n, s in samplers.items() if s.count}


@dataclass
class OfflineResult:
    ego: object                     # yowo_ego EgoMapResult
    grouping: object                # yowo_cmc GroupingResult
    fusion: object                  # yowo_fusion FusionResult
    seconds: dict[str, float]


def process(bag, fusion_params=None, ego_params=None) -> OfflineResult:
    """The whole method on one recording: ego map, CMC groups, collaborative processing."""
    from yowo_cmc.group_sfm import calibrate_groups
    from yowo_ego.pipeline import EgoParams
    from yowo_ego.recording import map_bag
    from yowo_fusion.pipeline import CmcInput, FusionParams, fuse

    seconds = {}
    t0 = time.perf_counter()
    ego, _ = map_bag(bag, ego_params or EgoParams())
    seconds["ego"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tracks = read_cmc_tracks(bag)
    grouping = calibrate_groups(tracks)
    seconds["cmc"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    backgrounds = read_backgrounds(bag, [t.name for t in tracks])
    fusion = fuse(ego_map_data(ego), grouping.groups, grouping.ungrouped,
                  {t.name: CmcInput(t, backgrounds.get(t.name)) for t in tracks}, fusion_params or FusionParams())
    seconds["fusion"] = time.perf_counter() - t0
    return OfflineResult(ego, grouping, fusion, seconds)
