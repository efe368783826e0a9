"""The pipeline's algorithms called directly on a recording, without the node graph
(for the benchmark and scripting). The graph runs the same functions inside nodes."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, replace

import numpy as np

from yowo_cmc.config import CmcParams
from yowo_cmc.keypoint_input import TrackAccumulator, frame_from_msg, frame_to_msg
from yowo_cmc.keypoint_tracks import CameraTracks
from yowo_common import topics
from yowo_common.ros.bag import read_messages, recording_gaps
from yowo_common.rosconv import camera_info_to_model

from .config import YowoConfig, fusion_upstream
from .contract import discover_inputs
from .layouts import InputParams

log = logging.getLogger(__name__)


def read_cmc_tracks(bag, source: str = "auto", params: CmcParams | None = None) -> list[CameraTracks]:
    """Every CMC's validated agent keypoint tracks (cameras sorted by name, as the graph
    does), from recorded keypoints, the pose model or the model-free image detector (see
    run.cmc_source)."""
    return read_cmc_inputs(bag, source, params, backgrounds=False)[0]


def read_cmc_inputs(
    bag,
    source: str = "auto",
    params: CmcParams | None = None,
    backgrounds: bool = True,
    inputs: InputParams | None = None,
    ego=None,
) -> tuple[list[CameraTracks], dict]:
    """What the keypoint trackers hand on, computed as they do in one pass over the
    recording: the run's plan says each CMC's source, topics and intrinsics, and the same
    yowo_cmc.keypoint_tracker runs on them. Returns each CMC's tracks (its validated frames
    as published messages, validated again on receipt) and, with `backgrounds`, its
    agent-free background. `inputs`: the configuration's inputs section (mapping, intrinsics
    files); video files (inputs.videos) are the graph's only. `ego`: the ego camera's
    trajectory (yowo_cmc.walker.EgoMotion), which tells the walker among people in view."""
    from std_msgs.msg import Header

    from yowo_cmc.keypoint_tracker import KeypointTracker
    from yowo_common.rosconv import decode_color, encode_raw, stamp_to_ns

    from .run import CMC, FULL, STAGE_MODULES, plan_run

    params = params or CmcParams()
    config = YowoConfig(inputs=replace(inputs or InputParams(), videos=(), video_list=""), cmc=params)
    mode = FULL if backgrounds and discover_inputs(bag, config.inputs).has_ego else CMC
    specs = [
        n.parameters
        for n in plan_run(bag, ".", mode=mode, config=config, source=source).nodes
        if n.module == STAGE_MODULES[topics.TRACKER_STAGE]
    ]
    trackers, by_topic = {}, {}
    for spec in specs:
        n = spec["camera"]
        trackers[n] = KeypointTracker(
            camera=n,
            source=spec["source"],
            params=params,
            has_images=bool(spec["image_topic"]),
            camera_info=spec.get("camera_info", ""),
            nominal=not spec.get("camera_info") and not spec["info_topic"],
        )
        for role in ("info_topic", "image_topic", "keypoints_topic"):
            if spec[role] and (role != "keypoints_topic" or trackers[n].detector is None):
                by_topic[spec[role]] = (n, role)
    frames: dict[str, list] = {n: [] for n in trackers}
    for topic, _, msg in read_messages(bag, by_topic):
        n, role = by_topic[topic]
        t = trackers[n]
        if role == "info_topic":
            if t.wants_camera_info:
                try:
                    frames[n] += t.take_camera(camera_info_to_model(msg))
                except ValueError as exc:  # the camera is left out, as the graph does
                    t.problem = f"{topic}: {exc}"
                    log.warning("%s; camera '%s' left out", t.problem, n)
        elif role == "keypoints_topic":
            kept = t.take_keypoints(frame_from_msg(msg))
            frames[n] += [kept] if kept is not None else []
        else:
            frames[n] += t.take_image(stamp_to_ns(msg.header.stamp), lambda m=msg: decode_color(m))[0]
    tracks = []
    for n, t in trackers.items():
        frames[n] += t.flush(ego)
        if t.camera is None or not frames[n]:
            continue
        received = TrackAccumulator(n, t.camera)
        for f in frames[n]:
            received.add(frame_from_msg(frame_to_msg(f, n, "")))
        tracks.append(received.tracks())
    found = {n: t.background() for n, t in trackers.items()} if backgrounds else {}
    # As published: an rgb8 image.
    return tracks, {n: decode_color(encode_raw(img, "rgb8", Header())) for n, img in found.items() if img is not None}


def ego_topics(bag, config: YowoConfig):
    """The ego camera's and its IMU's recorded topics as the run's plan maps them (a
    driver's layout, the configuration's mapping, Kalibr files or /tf_static for the IMU)."""
    from yowo_ego.recording import EgoTopics

    from .run import FULL, STAGE_MODULES, plan_run

    plan = plan_run(
        bag, ".", mode=FULL, config=replace(config, inputs=replace(config.inputs, videos=(), video_list=""))
    )
    ego = next(n for n in plan.nodes if n.module == STAGE_MODULES[topics.EGO_STAGE])
    return EgoTopics.from_node_parameters(ego.parameters)


def ego_map_data(ego):
    """yowo_ego's EgoMapResult -> the fusion's input: every frame's pose (the a2e factor
    needs the dense trajectory), observations re-indexed from keyframes to frames, and the
    cloud and layout (refined after joint optimisation)."""
    from yowo_ego.odometry import MEASURED
    from yowo_fusion.records import EgoMapData

    return EgoMapData(
        camera=ego.camera,
        stamps_ns=ego.stamps_ns,
        T_world_ego=ego.T_world_cam,
        landmarks=ego.landmarks,
        descriptor_type="SIFT",
        descriptors=ego.descriptors,
        obs_pose=ego.keyframe_frames[ego.obs_keyframe],
        obs_landmark=ego.obs_landmark,
        obs_uv=ego.obs_uv,
        cloud_points=ego.cloud_points,
        cloud_colors=ego.cloud_colors,
        layout=ego.layout,
        tracking_measured=np.isin(ego.tracking, MEASURED),
        tracking_fitness=ego.tracking_fitness,
        imu=ego.imu,
        attitude_held=ego.attitude_held,
    )


@dataclass
class OfflineResult:
    ego: object  # yowo_ego EgoMapResult
    grouping: object  # yowo_cmc GroupingResult
    fusion: object  # yowo_fusion FusionResult
    seconds: dict[str, float]
    tracks: list[CameraTracks]  # the CMC keypoint tracks it used
    backgrounds: dict  # camera -> agent-free background (RGB), when images were recorded


def process(bag, config: YowoConfig | None = None, source: str = "auto") -> OfflineResult:
    """The whole method on one recording (what `yowo run` computes, with the same tree):
    ego map, CMC groups, collaborative processing."""
    from yowo_cmc.pipeline import calibrate_cmcs_apart
    from yowo_cmc.walker import EgoMotion
    from yowo_ego.recording import map_bag
    from yowo_fusion.pipeline import fuse
    from yowo_fusion.records import CmcInput

    config = config or YowoConfig()
    seconds = {}
    t0 = time.perf_counter()
    ego, _ = map_bag(bag, config.ego, ego_topics(bag, config))
    seconds["ego"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    walk = EgoMotion(stamps_ns=np.asarray(ego.stamps_ns), positions=np.asarray(ego.T_world_cam)[:, :3, 3])
    tracks, backgrounds = read_cmc_inputs(bag, source, config.cmc, inputs=config.inputs, ego=walk)
    # Cameras without intrinsics: the group SfM estimates them, the fusion takes its estimate.
    estimated = frozenset(discover_inputs(bag, config.inputs).estimated_intrinsics)
    grouping = calibrate_cmcs_apart(tracks, config.cmc, estimated)
    seconds["cmc"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    joins = np.array([start for _, start in recording_gaps(bag)], np.int64)
    fusion = fuse(
        replace(ego_map_data(ego), joins_ns=joins),
        grouping.groups,
        grouping.ungrouped,
        {t.name: CmcInput(t, backgrounds.get(t.name), t.name not in estimated) for t in tracks},
        config.fusion,
        fusion_upstream(config),
    )
    seconds["fusion"] = time.perf_counter() - t0
    return OfflineResult(ego, grouping, fusion, seconds, tracks, backgrounds)
