"""Plan a run from a recording or live topics: which nodes, with which parameters, topics
and outputs (the one description of the graph). No rclpy here: graph_runner.py executes
the plan, run_results.py writes what it produced."""

from __future__ import annotations

import fnmatch
import os
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from yowo_cmc.skeletons import declared_skeletons
from yowo_common import topics
from yowo_common.ros.bag import recording_gaps, recording_label, recording_paths

from .config import YowoConfig, node_config
from .contract import (
    EGO_COLOR,
    EGO_DEPTH,
    EGO_INFO,
    cmc_image_topics,
    cmc_info_topic,
    cmc_keypoints_topic,
    discover_inputs,
)
from .imu_source import resolve_imu
from .supervisor import NodeSpec

STAGE_MODULES = {
    topics.REPLAY_STAGE: "yowo_bringup.replay_node",
    topics.TRACKER_STAGE: "yowo_cmc.keypoint_tracker_node",
    topics.GROUP_SFM_STAGE: "yowo_cmc.group_sfm_node",
    topics.EGO_STAGE: "yowo_ego.ego_mapper_node",
    topics.FUSION_STAGE: "yowo_fusion.fusion_node",
}
# Stages that read only other stages' outputs: they accumulate while the recording plays
# and compute at its end, so they are off the start-up's critical path (see _stamp_run).
DOWNSTREAM = (STAGE_MODULES[topics.GROUP_SFM_STAGE], STAGE_MODULES[topics.FUSION_STAGE])
CMC, FULL, EGO = "cmc", "full", "ego"
# A group needs two cameras; the CMC-only calibration has nothing to do with fewer.
MIN_GROUP_CMCS = 2


@dataclass(kw_only=True)
class RunPlan:
    bag: list[Path] | None  # the recording's files, read as one in time order; None: live operation
    out_dir: Path
    mode: str  # "cmc": relative calibration only; "full": registered in the map;
    # "ego": the map alone (a recording without usable CMCs)
    cameras: list[str]
    nodes: list[NodeSpec]
    final_stage: str
    outputs: dict[str, str] = field(default_factory=dict)  # latched topic -> type the runner collects
    # Stage streams the runner records whole into result.mcap (each camera's agent keypoints,
    # the walk guidance).
    streams: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    run_id: str = ""  # in every status: nodes ignore other runs' (see ros_domain.py)
    local: list[str] = field(default_factory=lambda: ["*"])  # patterns of the nodes this host starts
    config: YowoConfig = field(default_factory=YowoConfig)
    replay_messages: int = 0  # what the replay will publish (0: live)
    mode_reason: str = ""  # why the run is in its mode when the user did not choose it
    cmc_problems: list[str] = field(default_factory=list)  # why each CMC of the recording is not used
    inputs: dict = field(default_factory=dict)  # which recorded topics fill which role, the IMU's source

    @property
    def source(self) -> str:
        """What the run reads: the recording's path(s), or "live"."""
        return recording_label(self.bag) if self.bag else "live"

    @property
    def stages(self) -> list[str]:
        """The names of the nodes that report a stage status (every node but the replay)."""
        return [n.name for n in self.nodes if n.name != topics.REPLAY_STAGE]

    @property
    def local_nodes(self) -> list[NodeSpec]:
        return [n for n in self.nodes if any(fnmatch.fnmatchcase(n.name, p) for p in self.local)]

    @property
    def local_processes(self) -> list[NodeSpec]:
        """The processes this host starts, in the order of its nodes: the trackers spread
        over at most `supervisor.tracker_processes` processes, each other node alone."""
        nodes = self.local_nodes
        trackers = [n for n in nodes if n.module == STAGE_MODULES[topics.TRACKER_STAGE]]
        count = self.config.supervisor.tracker_processes
        if not count or len(trackers) <= count:
            return nodes
        hosts = [
            NodeSpec(
                name=f"{topics.TRACKER_STAGE}s_{i}",
                module=trackers[0].module,
                niceness=trackers[0].niceness,
                hosted=[t.name for t in trackers[i::count]],
            )
            for i in range(count)
        ]
        first = nodes.index(trackers[0])
        others = [n for n in nodes if n not in trackers]
        return others[:first] + hosts + others[first:]

    def select(self, patterns: list[str] | None) -> None:
        """Start only the nodes matching `patterns` here (a graph split across hosts)."""
        if not patterns:
            return
        unknown = [p for p in patterns if not any(fnmatch.fnmatchcase(n.name, p) for n in self.nodes)]
        if unknown:
            raise ValueError(
                f"--nodes {' '.join(unknown)}: no such node in this run ({', '.join(n.name for n in self.nodes)})"
            )
        self.local = list(patterns)


def launch_nodes(plan: RunPlan) -> list[dict]:
    """launch_ros.actions.Node keyword arguments of every node of the plan (the launch
    file's graph is the one `yowo run` starts: a process per node, its entry point named
    after its module)."""
    return [
        {
            "package": spec.module.split(".")[0],
            "executable": spec.module.split(".")[1],
            "name": spec.name,
            "parameters": [dict(spec.parameters)],
            "output": "screen",
        }
        for spec in plan.nodes
    ]


def _stage(name: str, parameters: dict) -> NodeSpec:
    """A stage's node (not a tracker: those are named per camera)."""
    return NodeSpec(name=name, module=STAGE_MODULES[name], parameters=parameters)


def new_run_id() -> str:
    return uuid.uuid4().hex[:12]


def _stamp_run(nodes: list[NodeSpec], run_id: str, replayed: bool, config: YowoConfig) -> None:
    """Every node's run id and section of the configuration tree; `replayed`: the stages'
    inputs come from a replay, which re-sends them to a restarted stage (live, nobody can).
    The downstream stages may run at a lower priority (supervisor.downstream_niceness): their
    imports at start-up then leave the cores to the replay and its readers, whose start the
    replay waits for, and at the end the ego mapper (the longest stage) goes first."""
    for spec in nodes:
        if spec.module in DOWNSTREAM:
            spec.niceness = config.supervisor.downstream_niceness
        spec.parameters["run_id"] = run_id
        spec.parameters.update(node_config(config, spec.name))
        if spec.name != topics.REPLAY_STAGE:
            spec.parameters["replayed"] = replayed


def _first_present(candidates, present: set[str]) -> str:
    return next((t for t in candidates if t in present), "")


CMC_SOURCES = ("auto", "keypoints", "pose", "images")


def cmc_source(name: str, present: set[str], preference: str = "auto") -> tuple[str, str, str]:
    """(source, keypoint topic, image topic) of a CMC. `auto` prefers an external
    detector's keypoints when recorded, else the pose model on the images (which falls
    back to the model-free detector for a camera where it never finds the agent)."""
    keypoints = cmc_keypoints_topic(name) if cmc_keypoints_topic(name) in present else ""
    image = _first_present(cmc_image_topics(name), present)
    if preference not in CMC_SOURCES:
        raise ValueError(f"unknown CMC keypoint source '{preference}' ({', '.join(CMC_SOURCES)})")
    if preference in ("images", "pose") or (preference == "auto" and not keypoints):
        kind = "pose" if preference == "auto" else preference
        return (kind, "", image) if image else ("", "", "")
    return ("keypoints", keypoints, image) if keypoints else ("", "", "")


def plan_run(
    bag, out_dir, mode: str = FULL, config: YowoConfig | None = None, source: str = "auto", run_id: str | None = None
) -> RunPlan:
    """Nodes for a recording. `config`: the configuration tree (defaults when None);
    `source`: where CMC agent keypoints come from (auto, keypoints or images); `run_id`:
    the same on every host of a split run (a new one by default)."""
    config = config or YowoConfig()
    inputs = discover_inputs(bag, config.inputs)
    label = recording_label(bag)
    imap = inputs.map
    present = set(imap.roles)
    problems = list(inputs.problems)
    if not present:
        raise ValueError(
            f"{label}: the recording holds no messages YOWO reads" + (f" ({'; '.join(problems)})" if problems else "")
        )
    if mode == FULL and not inputs.has_ego:
        raise ValueError(
            f"{label}: no complete ego camera ({'; '.join(p for p in problems if 'ego' in p)}); "
            "use 'yowo calibrate-cmc' for the CMC-only relative calibration"
        )
    trackers, played, cameras = [], [], []
    for c in inputs.cmc_names:
        kind, keypoints, image = cmc_source(c, present, source)
        if not kind:
            wanted = {"keypoints": cmc_keypoints_topic(c), "images": " or ".join(cmc_image_topics(c))}
            wanted["pose"] = wanted["images"]
            problems.append(
                f"CMC '{c}': no {wanted.get(source, wanted['keypoints'] + ' or images')}; the camera is skipped"
            )
            continue
        # External keypoints use images only for the background (scene keypoints: full runs) and the
        # image size of a camera whose intrinsics are estimated.
        image = image if kind in ("images", "pose") or mode == FULL or c in inputs.estimated_intrinsics else ""
        cameras.append(c)
        # info_topic "": no CameraInfo (intrinsics from `camera_info`, a file's, or estimated).
        roles = {
            "image_topic": imap.recorded(image),
            "info_topic": imap.recorded(cmc_info_topic(c)),
            "keypoints_topic": imap.recorded(keypoints),
        }
        played += [t for t in roles.values() if t]
        if c in inputs.intrinsics_files:
            roles["info_topic"], roles["camera_info"] = "", intrinsics_text(inputs.intrinsics_files[c], c)
        trackers.append((c, kind, roles))
    cmc_problems = [p for p in problems if p.startswith("CMC ")]
    declared_skeletons(config.cmc.keypoints, inputs.cmc_names)  # a malformed declaration stops here
    mode, reason = _mode_for(mode, cameras, inputs.cmc_names, cmc_problems)
    if mode == CMC and len(cameras) < MIN_GROUP_CMCS:
        raise ValueError(
            f"{label}: {len(cameras)} usable CMC(s) with agent keypoints or images; needs at least "
            f"{MIN_GROUP_CMCS}" + (f" ({'; '.join(cmc_problems)})" if cmc_problems else "")
        )
    if mode == FULL and len(cameras) < MIN_GROUP_CMCS:
        problems.append(
            f"only one usable CMC ({cameras[0]}): a single camera forms no group; it is registered "
            "as an isolated camera from the agent track the ego trajectory implies"
        )
    ego = tuple(
        imap.recorded(n) for n in (_first_present(EGO_COLOR, present), _first_present(EGO_DEPTH, present), EGO_INFO)
    )
    summary = {"layout": list(imap.notes), "mapping": {n: t for n, t in sorted(imap.roles.items()) if n != t}}
    imu_params: dict[str, str] = {}
    if mode in (FULL, EGO):
        imu_params, summary["imu"] = plan_ego_imu(bag, imap, config, ego[0])
        played += list(ego) + [t for k, t in imu_params.items() if k.endswith("_topic") and t]
    estimated = [c for c in inputs.estimated_intrinsics if c in cameras]
    nodes, final, outputs = _stage_nodes(
        mode, trackers, ego, imu_params, estimated, people=config.cmc.people.others_as_evidence
    )
    joins = [start for _, start in recording_gaps(bag)]
    for n in nodes:  # recordings read as one: where they meet, for the ego map's breaks
        if n.name == topics.FUSION_STAGE and joins:
            n.parameters["recording_joins_ns"] = joins
    if inputs.videos:
        config = _video_clock_search(config)
        summary["videos"] = {
            v.camera: {"file": str(v.path), "start_s": round(v.start_ns / 1e9, 9), "start_from": v.start_from}
            for v in inputs.videos
        }
    # The replay waits for the stages that read its topics (the others match late: their
    # inputs are durable), not for the slowest process of the graph to start.
    readers = [n.name for n in nodes if n.module not in DOWNSTREAM]
    nodes.append(
        _stage(
            topics.REPLAY_STAGE,
            {  # last: it waits for the stages' subscriptions
                "bag": os.pathsep.join(str(p) for p in recording_paths(bag)),
                "topics": played,
                "wait_for_topics": played,
                "stages": readers,
                **({"videos": [v.rule for v in inputs.videos]} if inputs.videos else {}),
            },
        )
    )
    run_id = run_id or new_run_id()
    _stamp_run(nodes, run_id, True, config)
    total = sum(t.count for t in inputs.topics if t.name in played)
    return RunPlan(
        bag=recording_paths(bag),
        out_dir=Path(out_dir),
        mode=mode,
        cameras=cameras,
        nodes=nodes,
        final_stage=final,
        outputs=outputs,
        streams=stage_streams(mode, cameras),
        warnings=problems,
        run_id=run_id,
        config=config,
        replay_messages=total,
        mode_reason=reason,
        cmc_problems=cmc_problems,
        inputs=summary,
    )


def intrinsics_text(path: str, camera: str) -> str:
    """A camera's intrinsics file as camera_calibration_parsers YAML (what the tracker reads);
    ValueError naming the file when it cannot be used."""
    from yowo_common.intrinsics_io import camera_info_yaml, read_intrinsics

    return camera_info_yaml(read_intrinsics(path, camera), camera)


def _video_clock_search(config: YowoConfig) -> YowoConfig:
    """The ego-clock fits (a group's, an isolated camera's) widened to cover a video's start
    inputs.video_clock_error_s off. The
    videos of one NVR share its clock, so the search between cameras keeps its range: widened to
    twice that, walks through rooms seconds apart matched cameras of different rooms (small
    seed 0: a group of four across two rooms, 96 px RMSE)."""
    err = config.inputs.video_clock_error_s
    align = replace(config.fusion.align, max_clock_offset_s=max(config.fusion.align.max_clock_offset_s, err + 0.5))
    isolated = replace(config.fusion.isolated, clock_search_s=max(config.fusion.isolated.clock_search_s, err + 0.5))
    return replace(config, fusion=replace(config.fusion, align=align, isolated=isolated))


def plan_ego_imu(bag, imap, config: YowoConfig, color_topic: str) -> tuple[dict[str, str], dict]:
    """The ego mapper's IMU parameters (topics, and the calibration text where the recording
    carries none on /ego/imu/calibration) and what the run log says of the IMU."""
    united, gyro, accel = (imap.recorded(n) for n in (topics.EGO_IMU, topics.EGO_GYRO, topics.EGO_ACCEL))
    if not united and not (gyro and accel):
        what = "no IMU topic" if not (gyro or accel) else f"only {gyro or accel} (gyro and accelerometer both needed)"
        return {}, {"used": False, "reason": what}
    if not config.ego.odometry.use_imu:
        return {}, {"used": False, "reason": "ego.odometry.use_imu is false"}
    stream = {"imu_topic": united} if united else {"gyro_topic": gyro, "accel_topic": accel}
    where = {"topics": [t for t in (united, gyro, accel) if t]}
    recorded_cal = imap.recorded(topics.EGO_IMU_CALIBRATION)
    cfg = config.inputs
    if recorded_cal and not cfg.imu_camchain and not cfg.imu_noise:
        return (
            {**stream, "imu_calibration_topic": recorded_cal},
            {"used": True, **where, "extrinsics": recorded_cal, "noise": recorded_cal},
        )
    camera_frame, imu_frame, rate_hz, tf_edges = recorded_frames(bag, color_topic, united or gyro)
    found = resolve_imu(
        camchain=cfg.imu_camchain,
        imu_yaml=cfg.imu_noise,
        defaults=cfg.imu_noise_defaults,
        rate_hz=rate_hz,
        camera_frame=camera_frame,
        imu_frame=imu_frame,
        tf_edges=tf_edges,
        camera_topic=color_topic,
    )
    if not found.calibration_yaml:
        return {}, {**where, **found.describe()}
    return {**stream, "imu_calibration": found.calibration_yaml}, {**where, **found.describe()}


def recorded_frames(bag, color_topic: str, imu_topic: str, samples: int = 200):
    """(colour frame id, IMU frame id, IMU rate [Hz], /tf_static edges (parent, child,
    T_parent_child)) from the start of a recording."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import stamp_to_ns, transform_to_matrix

    camera_frame, imu_frame, stamps, edges, first_ns = "", "", [], [], None
    for topic, log_ns, msg in read_messages(bag, [color_topic, imu_topic, topics.TF_STATIC]):
        first_ns = log_ns if first_ns is None else first_ns
        if topic == topics.TF_STATIC:
            edges += [
                (tf.header.frame_id, tf.child_frame_id, transform_to_matrix(tf.transform)) for tf in msg.transforms
            ]
        elif topic == color_topic:
            camera_frame = camera_frame or msg.header.frame_id
        else:
            imu_frame = imu_frame or msg.header.frame_id
            stamps.append(stamp_to_ns(msg.header.stamp))
        if camera_frame and (len(stamps) >= samples or (stamps and log_ns - first_ns > 5e9)):
            break
    steps = np.diff(stamps)
    rate_hz = 1e9 / float(np.median(steps[steps > 0])) if np.any(steps > 0) else 0.0
    return camera_frame, imu_frame, rate_hz, edges


def _mode_for(mode: str, cameras: list[str], found: list[str], cmc_problems: list[str]) -> tuple[str, str]:
    """The mode a full run takes on its recording, and why when it is not the one asked for.
    Without a usable CMC the run maps the scene alone (mapping a building before its cameras
    are known is a normal first step). A single CMC forms no group, but the fusion registers
    it as an isolated camera from the agent track the ego trajectory implies, so it stays full."""
    if mode != FULL or cameras:
        return mode, ""
    if not found and not cmc_problems:
        return EGO, "the recording has no CMC topics (/cmc/<name>/...)"
    return EGO, "no usable CMC: " + "; ".join(cmc_problems or ["none of the recording's CMCs can be used"])


def plan_live(
    cameras: list[str],
    out_dir,
    mode: str = FULL,
    source: str = "keypoints",
    image_topic: str = "image_raw/compressed",
    ego_topics: tuple[str, str, str] = (EGO_COLOR[1], EGO_DEPTH[0], EGO_INFO),
    config: YowoConfig | None = None,
    run_id: str | None = None,
) -> RunPlan:
    """Nodes for live operation on camera topics (no recording): the same graph without
    the replay; the stages finalise when `yowo end-walk` announces the end of the walk."""
    if len(cameras) < 2:
        raise ValueError(f"live run: {len(cameras)} CMC(s) given; needs at least 2")
    if source not in CMC_SOURCES[1:]:
        raise ValueError(f"live run: CMC keypoint source '{source}' ({', '.join(CMC_SOURCES[1:])})")
    trackers = [
        (c, source, {"image_topic": topics.cmc_topic(c, image_topic) if source != "keypoints" or mode == FULL else ""})
        for c in cameras
    ]
    config = config or YowoConfig()
    nodes, final, outputs = _stage_nodes(mode, trackers, ego_topics, people=config.cmc.people.others_as_evidence)
    run_id = run_id or new_run_id()
    _stamp_run(nodes, run_id, False, config)
    return RunPlan(
        bag=None,
        out_dir=Path(out_dir),
        mode=mode,
        cameras=list(cameras),
        nodes=nodes,
        final_stage=final,
        outputs=outputs,
        streams=stage_streams(mode, cameras),
        run_id=run_id,
        config=config,
    )


def stage_streams(mode: str, cameras: list[str]) -> dict[str, str]:
    """The stage streams recorded into result.mcap: every camera's agent keypoints and the walk
    guidance the group SfM published during the walk."""
    if mode == EGO:
        return {}
    return {**keypoint_streams(mode, cameras), topics.GUIDANCE: "yowo_msgs/msg/WalkGuidance"}


def keypoint_streams(mode: str, cameras: list[str]) -> dict[str, str]:
    """The agent keypoints each camera's tracker handed on (which person it took for the
    walker, frame by frame): recorded into result.mcap."""
    if mode == EGO:
        return {}
    return {topics.tracker_keypoints(c): "yowo_msgs/msg/AgentKeypoints" for c in cameras}


# What the ego mapper publishes at the end of the walk (latched), collected by every run with a map.
EGO_OUTPUTS = {
    topics.EGO_MAP: "yowo_msgs/msg/EgoMap",
    topics.EGO_PATH: "nav_msgs/msg/Path",
    topics.LAYOUT: "yowo_msgs/msg/SceneLayout",
    topics.MAP_POINTS: "sensor_msgs/msg/PointCloud2",
}


def _stage_nodes(
    mode: str,
    trackers: list[tuple[str, str, dict[str, str]]],
    ego: tuple[str, str, str],
    imu: dict[str, str] | None = None,
    estimated: list[str] | None = None,
    people: bool = False,
) -> tuple[list[NodeSpec], str, dict[str, str]]:
    """The stage processes (trackers: (camera, source, its topic parameters)), the final stage
    and the latched outputs the runner collects. `imu`: the ego mapper's IMU parameters (none:
    no IMU); `estimated`: the cameras whose intrinsics the group SfM estimates (the fusion
    registers them only in a group); `people`: a CMC-only run's pose-model trackers hand on
    everyone they saw and the group SfM matches them across cameras (cmc.people.others_as_evidence)."""
    unknown = {"estimate_intrinsics": list(estimated)} if estimated else {}
    ego_params = {"color_topic": ego[0], "depth_topic": ego[1], "info_topic": ego[2], **(imu or {})}
    if mode == EGO:  # the map alone: its stage publishes the map, path, cloud and layout
        return (
            [_stage(topics.EGO_STAGE, ego_params)],
            topics.EGO_STAGE,
            dict(EGO_OUTPUTS),
        )
    cameras = [c for c, _, _ in trackers]
    # With an ego camera, the pose model's trackers tell the walker among the people in view
    # by the ego camera's motion: they finish once its odometry is complete.
    walker = {"ego_odometry_topic": topics.EGO_ODOMETRY} if mode == FULL else {}
    # Without an ego camera nobody is the walker for sure: everyone is evidence.
    everyone = [c for c, kind, _ in trackers if kind == "pose"] if mode == CMC and people else []
    nodes = [
        NodeSpec(
            name=topics.tracker_stage(c),
            module=STAGE_MODULES[topics.TRACKER_STAGE],
            parameters={
                "camera": c,
                "source": kind,
                **roles,
                **(walker if kind == "pose" else {}),
                **({"publish_people": True} if c in everyone else {}),
            },
        )
        for c, kind, roles in trackers
    ]
    nodes.append(
        _stage(
            topics.GROUP_SFM_STAGE,
            {"cameras": cameras, **unknown, **({"people_cameras": everyone} if everyone else {})},
        )
    )
    final = topics.GROUP_SFM_STAGE
    outputs = {topics.GROUPS: "yowo_msgs/msg/CameraGroupArray"}
    if everyone:
        outputs[topics.PEOPLE] = "std_msgs/msg/String"
    # Which person each pose-model tracker took for the walker, and why (cameras.yaml, the report).
    outputs.update({topics.tracker_walker(c): "std_msgs/msg/String" for c, kind, _ in trackers if kind == "pose"})
    if mode == FULL:
        nodes.append(_stage(topics.EGO_STAGE, ego_params))
        nodes.append(_stage(topics.FUSION_STAGE, {"cameras": cameras, **unknown}))
        final = topics.FUSION_STAGE
        outputs.update(
            {
                topics.CMC_POSES: "yowo_msgs/msg/RegisteredCameraArray",
                topics.TF_STATIC: "tf2_msgs/msg/TFMessage",
                topics.LAYOUT_MARKERS: "visualization_msgs/msg/MarkerArray",
                **EGO_OUTPUTS,
                topics.REFINED_LAYOUT: "yowo_msgs/msg/SceneLayout",
                topics.WEAK_PLACES: "std_msgs/msg/String",
                topics.REFINED_MAP_POINTS: "sensor_msgs/msg/PointCloud2",
                topics.REFINED_EGO_PATH: "nav_msgs/msg/Path",
                topics.AGENT_FIT: "yowo_msgs/msg/CameraAgentFitArray",
            }
        )
    return nodes, final, outputs
