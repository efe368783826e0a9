"""The input data contract of docs/design.md §3: which topics a recording
must/may hold, and discovery of the ego camera and the CMCs from topic names."""

from __future__ import annotations

from dataclasses import dataclass, field

from yowo_common.ros.bag import BagTopic, list_topics, recording_damage, recording_span, unknown_type_reason
from yowo_common.topics import (  # noqa: F401
    EGO_ACCEL,
    EGO_COLOR,
    EGO_DEPTH,
    EGO_GYRO,
    EGO_IMU,
    EGO_IMU_CALIBRATION,
    EGO_INFO,
    GT_PREFIX,
    cmc_image_topics,
    cmc_info_topic,
    cmc_keypoints_topic,
    parse_cmc_topic,
    unusable_cmc_topic,
)

from .layouts import InputMap, InputMapError, InputParams, map_inputs
from .video import VideoError, VideoInput, probe_video, video_rules


@dataclass
class RecordingInputs:
    """What a recording offers YOWO, and what is wrong with it. `map` says which recorded
    topic fills each of YOWO's input names; the other fields speak of input names."""

    topics: list[BagTopic]
    has_ego: bool
    cmc_names: list[str]
    has_ground_truth: bool
    problems: list[str] = field(default_factory=list)
    map: InputMap = field(default_factory=InputMap)
    videos: list[VideoInput] = field(default_factory=list)
    # camera -> intrinsics file ('' where they come from CameraInfo), and the cameras whose
    # intrinsics are estimated (no CameraInfo, no file).
    intrinsics_files: dict[str, str] = field(default_factory=dict)
    estimated_intrinsics: list[str] = field(default_factory=list)

    def count(self, name: str) -> int:
        """Messages recorded for an input name."""
        recorded = self.map.recorded(name)
        return next((t.count for t in self.topics if t.name == recorded), 0)


IMAGE, COMPRESSED, INFO, IMU = (
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/CompressedImage",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/Imu",
)
# The message type each input role takes (CMC roles by their kind under /cmc/<name>/).
ROLE_TYPES = {
    EGO_COLOR[0]: IMAGE,
    EGO_COLOR[1]: COMPRESSED,
    EGO_DEPTH[0]: IMAGE,
    EGO_DEPTH[1]: COMPRESSED,
    EGO_INFO: INFO,
    EGO_IMU: IMU,
    EGO_GYRO: IMU,
    EGO_ACCEL: IMU,
    EGO_IMU_CALIBRATION: "std_msgs/msg/String",
}
CMC_KIND_TYPES = {
    "image_raw": IMAGE,
    "image_raw/compressed": COMPRESSED,
    "camera_info": INFO,
    "agent_keypoints": "yowo_msgs/msg/AgentKeypoints",
}


def _wrong_types(imap: InputMap, types: dict[str, str]) -> list[str]:
    """Roles filled by a topic of another type: removed from the map, each named."""
    problems = []
    for name, recorded in sorted(imap.roles.items()):
        cmc = parse_cmc_topic(name)
        expected = CMC_KIND_TYPES[cmc[1]] if cmc else ROLE_TYPES.get(name)
        if expected and types.get(recorded, expected) != expected:
            problems.append(f"{recorded}: type {types[recorded]}, but as {name} it must be {expected}; not used")
            del imap.roles[name]
    return problems


def discover_inputs(bag, params: InputParams | None = None) -> RecordingInputs:
    """The recording's inputs, found by YOWO's own names, the drivers' layouts and the
    mapping in `params`; InputMapError for a mapping that names a missing topic."""
    params = params or InputParams()
    topics = list_topics(bag)
    problems = [d for d in [recording_damage(bag)] if d]
    if not topics or all(t.count == 0 for t in topics):
        problems.append(f"{bag}: the recording holds no messages")
    problems += [f"{t.name}: skipped, {why}" for t in topics if (why := unknown_type_reason(t.msgtype))]
    problems += [why for t in topics if (why := unusable_cmc_topic(t.name))]
    readable = [t.name for t in topics if t.count > 0 and not unknown_type_reason(t.msgtype)]
    imap = map_inputs(readable, params.remap, params.ego_namespace)
    problems += imap.problems + _wrong_types(imap, {t.name: t.msgtype for t in topics})
    videos = [probe_video(rule) for rule in video_rules(params.videos, params.video_list)]
    problems += _add_videos(videos, imap, topics, recording_span(bag), params.video_clock_error_s)

    def present(name):
        return name in imap.roles

    ego_color = any(present(t) for t in EGO_COLOR)
    ego_depth = any(present(t) for t in EGO_DEPTH)
    has_ego = ego_color and ego_depth and present(EGO_INFO)
    if not has_ego and not any("ego camera:" in p for p in imap.problems):
        missing = [
            what
            for what, ok in (
                ("colour " + " or ".join(EGO_COLOR), ego_color),
                ("depth " + " or ".join(EGO_DEPTH), ego_depth),
                (EGO_INFO, present(EGO_INFO)),
            )
            if not ok
        ]
        problems.append(
            f"ego camera incomplete: missing {'; '.join(missing)} (no driver layout found either: "
            "map the topics with -r /ego/color/image_raw:=TOPIC, see 'yowo info')"
        )

    kinds: dict[str, set[str]] = {}
    for name in imap.roles:
        cmc = parse_cmc_topic(name)
        if cmc:
            kinds.setdefault(cmc[0], set()).add(cmc[1].split("/")[0])
    files = _intrinsics_files(params.intrinsics, set(kinds))
    cmc_names, estimated = [], []
    for name in sorted(kinds):
        if not kinds[name] & {"image_raw", "agent_keypoints"}:
            problems.append(f"CMC '{name}': neither images nor agent keypoints; the camera is skipped")
        elif "camera_info" not in kinds[name] and name not in files and "image_raw" not in kinds[name]:
            problems.append(
                f"CMC '{name}': no {cmc_info_topic(name)} and no images to estimate its intrinsics "
                f"from; give them with --intrinsics {name}=FILE; the camera is skipped"
            )
        else:
            cmc_names.append(name)
            if "camera_info" not in kinds[name] and name not in files:
                estimated.append(name)
                imap.notes.append(
                    f"CMC {name}: no CameraInfo, its intrinsics are estimated (or give them with "
                    f"--intrinsics {name}=FILE)"
                )
    has_gt = any(t.name.startswith(GT_PREFIX) for t in topics)
    return RecordingInputs(topics, has_ego, cmc_names, has_gt, problems, imap, videos, files, estimated)


def _intrinsics_files(rules, cameras: set[str]) -> dict[str, str]:
    """camera -> file of the NAME=FILE rules; InputMapError for a rule that names no camera."""
    files = {}
    for rule in rules:
        name, sep, path = str(rule).partition("=")
        if not sep or not path:
            raise InputMapError(f"--intrinsics {rule} (inputs.intrinsics): expected CAMERA=FILE")
        if name not in cameras:
            raise InputMapError(
                f"intrinsics '{rule}': no camera '{name}' in this recording ({', '.join(sorted(cameras)) or 'none'})"
            )
        files[name] = path
    return files


def _add_videos(
    videos: list[VideoInput], imap: InputMap, topics: list[BagTopic], span: tuple[int, int], clock_error_s: float
) -> list[str]:
    """Each video as its camera's image topic; what is wrong with their timing."""
    problems = []
    for v in videos:
        if v.topic in imap.roles or cmc_image_topics(v.camera)[1] in imap.roles:
            raise VideoError(
                f"video {v.path}: camera '{v.camera}' already has images in the recording "
                f"({imap.recorded(v.topic) or imap.recorded(cmc_image_topics(v.camera)[1])}); "
                "give the video another name"
            )
        topics.append(BagTopic(v.topic, "sensor_msgs/msg/Image", v.frames))
        imap.roles[v.topic] = v.topic
        imap.notes.append(
            f"CMC {v.camera}: video {v.path} ({v.frames} frames, {v.width}x{v.height}, {v.duration_s:.1f} s; "
            f"start from {v.start_from})"
        )
        if span == (0, 0):
            continue
        walk_s, margin = (span[1] - span[0]) / 1e9, int(clock_error_s * 1e9)
        if v.start_ns > span[1] + margin or v.start_ns + v.duration_s * 1e9 < span[0] - margin:
            raise VideoError(
                f"video {v.path}: {v.duration_s:.1f} s from {v.start_ns / 1e9:.3f} s never overlaps the "
                f"recording ({span[0] / 1e9:.3f}..{span[1] / 1e9:.3f} s), even {clock_error_s:g} s off; "
                f"give its start as {v.camera}={v.path}@START"
            )
        if v.duration_s < 0.9 * walk_s:
            problems.append(
                f"CMC '{v.camera}': video {v.path} lasts {v.duration_s:.1f} s of the {walk_s:.1f} s "
                "recording; the camera sees only that part of the walk"
            )
    return problems
