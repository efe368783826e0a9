"""The pipeline's algorithms called directly on a recording, without the node graph
(for the benchmark and scripting). The graph runs the same functions inside nodes."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from yowo_cmc.config import CmcParams
from yowo_cmc.keypoint_input import TrackAccumulator, frame_from_msg, frame_to_msg
from yowo_cmc.tracks import CameraTracks
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import camera_info_to_model

from .config import YowoConfig, fusion_upstream
from .contract import discover_inputs
from .run import cmc_info_topic, cmc_source

log = logging.getLogger(__name__)


def read_cmc_tracks(bag, source: str = "auto", params: CmcParams | None = None) -> list[CameraTracks]:
    """Every CMC's validated agent keypoint tracks (cameras sorted by name, as the graph
    does), from recorded keypoints, the pose model or the model-free image detector (see
    run.cmc_source)."""
    return read_cmc_inputs(bag, source, params, backgrounds=False)[0]


def read_cmc_inputs(bag, source: str = "auto", params: CmcParams | None = None, backgrounds: bool = True
                    ) -> tuple[list[CameraTracks], dict]:
    """What the keypoint trackers hand on, computed as they do in one pass over the
    recording: each CMC's tracks (its validated frames as published messages, validated
    again on receipt) and, with `backgrounds`, its agent-free background (the detector's
    model, or the median of sampled images when the keypoints were recorded)."""
    from std_msgs.msg import Header

    from yowo_cmc.background import BackgroundSampler
    from yowo_cmc.keypoint_input import ImageKeypointSource
    from yowo_cmc.pose_model import PoseOrDetectorSource
    from yowo_common.rosconv import decode_color, encode_raw, stamp_to_ns

    params = params or CmcParams()
    inputs = discover_inputs(bag)
    present, recorded = set(inputs.map.roles), inputs.map.recorded
    acc, detectors, samplers, by_topic, unusable = {}, {}, {}, {}, set()
    for n in inputs.cmc_names:
        kind, keypoints, image = cmc_source(n, present, source)
        if not kind:
            continue
        acc[n] = TrackAccumulator(n)
        by_topic[recorded(cmc_info_topic(n))] = n
        if kind in ("images", "pose"):
            detectors[n] = (ImageKeypointSource(n, params.detector, params.max_pending_frames) if kind == "images"
                            else PoseOrDetectorSource(n, params.pose, params.pose_min_frames, params.detector,
                                                      params.max_pending_frames))
            by_topic[recorded(image)] = n
            if kind == "pose" and backgrounds:       # the pose model has no background model of its own
                samplers[n] = BackgroundSampler(params.background_period_s)
        else:
            by_topic[recorded(keypoints)] = n
            if image and backgrounds:
                samplers[n] = BackgroundSampler(params.background_period_s)
                by_topic[recorded(image)] = n
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
        elif topic.endswith("/agent_keypoints"):
            frames = [frame_from_msg(msg)]
        else:
            stamp, rgb = stamp_to_ns(msg.header.stamp), decode_color(msg)
            frames = detector.push(stamp, rgb) if detector else []
            if n in samplers and samplers[n].wants(stamp):
                samplers[n].add(stamp, rgb)
        for f in frames:
            a.add(f)
    for n, detector in detectors.items():
        for f in detector.flush():
            acc[n].add(f)
    tracks = []
    for a in acc.values():
        if a.camera is None or not a.frames:
            continue
        received = TrackAccumulator(a.name, a.camera)
        for f in a.frames:
            received.add(frame_from_msg(frame_to_msg(f, a.name, "")))
        tracks.append(received.tracks())
    found = {n: s.image() for n, s in samplers.items() if s.count}
    found.update({n: d.background for n, d in detectors.items() if backgrounds and d.background is not None})
    # As published: an rgb8 image.
    return tracks, {n: decode_color(encode_raw(img, "rgb8", Header())) for n, img in found.items()}


def ego_map_data(ego):
    """yowo_ego's EgoMapResult -> the fusion's input: every frame's pose (the a2e factor
    needs the dense trajectory), observations re-indexed from keyframes to frames, and the
    cloud and layout (refined after joint optimisation)."""
    from yowo_ego.odometry import MEASURED
    from yowo_fusion.pipeline import EgoMapData

    return EgoMapData(ego.camera, ego.stamps_ns, ego.T_world_cam, ego.landmarks, "SIFT", ego.descriptors,
                      ego.keyframe_frames[ego.obs_keyframe], ego.obs_landmark, ego.obs_uv, ego.cloud_points,
                      ego.cloud_colors, ego.layout, np.isin(ego.tracking, MEASURED), ego.tracking_fitness, ego.imu,
                      ego.attitude_held)


@dataclass
class OfflineResult:
    ego: object                     # yowo_ego EgoMapResult
    grouping: object                # yowo_cmc GroupingResult
    fusion: object                  # yowo_fusion FusionResult
    seconds: dict[str, float]
    tracks: list[CameraTracks]      # the CMC keypoint tracks it used
    backgrounds: dict               # camera -> agent-free background (RGB), when images were recorded


def process(bag, config: YowoConfig | None = None, source: str = "auto") -> OfflineResult:
    """The whole method on one recording (what `yowo run` computes, with the same tree):
    ego map, CMC groups, collaborative processing."""
    from yowo_cmc.pipeline import calibrate_cmcs
    from yowo_ego.recording import map_bag
    from yowo_fusion.pipeline import CmcInput, fuse

    config = config or YowoConfig()
    seconds = {}
    t0 = time.perf_counter()
    ego, _ = map_bag(bag, config.ego)
    seconds["ego"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tracks, backgrounds = read_cmc_inputs(bag, source, config.cmc)
    grouping = calibrate_cmcs(tracks, config.cmc)
    seconds["cmc"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fusion = fuse(ego_map_data(ego), grouping.groups, grouping.ungrouped,
                  {t.name: CmcInput(t, backgrounds.get(t.name)) for t in tracks}, config.fusion,
                  fusion_upstream(config))
    seconds["fusion"] = time.perf_counter() - t0
    return OfflineResult(ego, grouping, fusion, seconds, tracks, backgrounds)
