"""The pipeline's algorithms called directly on a recording, without the node graph
(for the benchmark and scripting). The graph runs the same functions inside nodes."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from yowo_cmc.keypoint_input import TrackAccumulator, frame_from_msg
from yowo_cmc.tracks import CameraTracks
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import camera_info_to_model

from .contract import discover_inputs
from .run import cmc_info_topic, cmc_source

log = logging.getLogger(__name__)


def read_cmc_tracks(bag, source: str = "auto") -> list[CameraTracks]:
    """Every CMC's validated agent keypoint tracks (cameras sorted by name, as the graph
    does), from recorded keypoints or the built-in image detector (see run.cmc_source)."""
    from yowo_cmc.keypoint_input import ImageKeypointSource
    from yowo_common.rosconv import decode_color, stamp_to_ns

    inputs = discover_inputs(bag)
    present = {t.name for t in inputs.topics if t.count > 0}
    acc, detectors, by_topic, unusable = {}, {}, {}, set()
    for n in inputs.cmc_names:
        kind, keypoints, image = cmc_source(n, present, source)
        if not kind:
            continue
        acc[n] = TrackAccumulator(n)
        by_topic[cmc_info_topic(n)] = n
        if kind == "images":
            detectors[n] = ImageKeypointSource(n)
            by_topic[image] = n
        else:
            by_topic[keypoints] = n
    for topic, _, msg in read_messages(bag, by_topic):
        n = by_topic[topic]
        a, detector = acc[n], detectors.get(n)
        if topic.endswith("/camera_info"):
            if a.camera is not None or n in unusable:
                continue
            try:
                a.camera = camera_info_to_model(msg)
            except ValueError as exc:      # the camera is left out, as the graph does
                unusable.add(n)
                log.warning("%s: %s; camera '%s' left out", topic, exc, n)
                continue
            frames = detector.set_camera(a.camera) if detector else []
        elif detector:
            frames = detector.push(stamp_to_ns(msg.header.stamp), decode_color(msg))
        else:
            frames = [frame_from_msg(msg)]
        for f in frames:
            a.add(f)
    for n, detector in detectors.items():
        for f in detector.flush():
            acc[n].add(f)
    return [a.tracks() for a in acc.values() if a.camera is not None and a.frames]


def ego_map_data(ego) -> "EgoMapData":
    """yowo_ego's EgoMapResult -> the fusion's input: every frame's pose (the a2e factor
    needs the dense trajectory), observations re-indexed from keyframes to frames, and the
    cloud and layout (refined after joint optimisation)."""
    from yowo_fusion.pipeline import EgoMapData

    return EgoMapData(ego.camera, ego.stamps_ns, ego.T_world_cam, ego.landmarks, "SIFT", ego.descriptors,
                      ego.keyframe_frames[ego.obs_keyframe], ego.obs_landmark, ego.obs_uv, ego.cloud_points,
                      ego.cloud_colors, ego.layout)


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
    tracks: list[CameraTracks]      # the CMC keypoint tracks it used
    backgrounds: dict               # camera -> agent-free background (RGB), when images were recorded


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
    return OfflineResult(ego, grouping, fusion, seconds, tracks, backgrounds)
