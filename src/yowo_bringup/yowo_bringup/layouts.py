"""Which recorded topic plays which input role: YOWO's own layout (docs/design.md §3), the
common RGB-D drivers' layouts, image_transport camera namespaces, and the user's explicit
mapping. The result names every role by YOWO's input name (`/ego/color/image_raw`,
`/cmc/<name>/camera_info`, ...) and says which recorded topic fills it; the nodes are then
given the recorded names as their topic parameters, so a live graph maps the same way."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from yowo_common import topics

from .imu_source import ImuNoiseDefaults


# A driver's ego streams relative to its camera namespace: (colour, depth, camera info,
# united IMU, gyro, accelerometer). Colour and depth also as image_transport's compressed
# sub-topics. Names are the drivers' defaults.
@dataclass(frozen=True, kw_only=True)
class DriverLayout:
    driver: str
    color: str
    depth: str
    info: str
    imu: str = ""
    gyro: str = ""
    accel: str = ""
    # Sibling streams of the same device under its namespace (never a ceiling camera).
    streams: tuple[str, ...] = ()


DRIVER_LAYOUTS = (
    DriverLayout(
        driver="realsense2_camera",
        color="color/image_raw",
        depth="aligned_depth_to_color/image_raw",
        info="color/camera_info",
        imu="imu",
        gyro="gyro/sample",
        accel="accel/sample",
        streams=(
            "color",
            "depth",
            "infra1",
            "infra2",
            "aligned_depth_to_color",
            "aligned_depth_to_infra1",
            "fisheye",
            "fisheye1",
            "fisheye2",
        ),
    ),
    DriverLayout(
        driver="Azure Kinect / Orbbec Femto",
        color="rgb/image_raw",
        depth="depth_to_rgb/image_raw",
        info="rgb/camera_info",
        imu="imu",
        streams=("rgb", "depth", "ir", "depth_to_rgb", "rgb_to_depth"),
    ),
    DriverLayout(
        driver="ZED",
        color="rgb/image_rect_color",
        depth="depth/depth_registered",
        info="rgb/camera_info",
        imu="imu/data",
        streams=(
            "rgb",
            "rgb_raw",
            "left",
            "left_raw",
            "right",
            "right_raw",
            "depth",
            "confidence",
            "disparity",
            "stereo",
            "stereo_raw",
        ),
    ),
)
_COMPRESSED = {"color": "/compressed", "depth": "/compressedDepth"}
# Recorded namespaces that are never a ceiling camera of their own.
_RESERVED = ("/ego/", "/cmc/", "/gt/", "/yowo/")
_CMC_IMAGE = re.compile(r"^(?P<ns>/.+)/image_raw(?P<compressed>/compressed)?$")
_CMC_SIBLINGS = ("camera_info", "agent_keypoints")


@dataclass(frozen=True)
class InputParams:
    """The `inputs` section: which recorded topics are YOWO's inputs, and the ego IMU's
    calibration where the recording does not carry it."""

    # YOWO input name:=recorded topic, ROS remapping order (e.g. /ego/color/image_raw:=/cam/rgb);
    # also `yowo run -r RULE`.
    remap: tuple[str, ...] = ()
    ego_namespace: str = ""  # the ego camera's driver namespace where several devices are found
    imu_camchain: str = ""  # Kalibr camchain-imucam.yaml: the ego IMU's T_cam_imu, timeshift_cam_imu
    imu_noise: str = ""  # Kalibr imu.yaml: the ego IMU's noise densities and random walks
    imu_noise_defaults: ImuNoiseDefaults = field(default_factory=ImuNoiseDefaults)  # without imu_noise
    # NAME=FILE: a ceiling camera's intrinsics from a calibration file (camera_calibration_parsers
    # YAML, Kalibr camchain, COLMAP cameras.txt, OpenCV YAML/XML), over its CameraInfo if any;
    # also yowo run --intrinsics. A camera with neither has its intrinsics estimated.
    intrinsics: tuple[str, ...] = ()
    # NAME=FILE[@START]: a ceiling camera's footage as a video file; START in seconds since the
    # epoch or ISO 8601, else the file's creation_time; also yowo run --cmc-video.
    videos: tuple[str, ...] = ()
    video_list: str = ""  # a YAML list of {name, file, start} (start optional) beside `videos`
    # How far a video's start may be off the recording's clock. With videos, the ego-clock fit
    # (fusion.align.max_clock_offset_s) covers it. Videos of one NVR share its clock; videos from
    # recorders with clocks of their own also need cmc.clock.max_offset_s to cover their differences.
    video_clock_error_s: float = 10.0


class InputMapError(ValueError):
    """A mapping that cannot be used; the message names the topic and the option to pass."""


@dataclass
class InputMap:
    """YOWO input name -> recorded topic, for every role the recording fills, with how it was
    found (`notes`, one line per device) and what could not be decided (`problems`)."""

    roles: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def recorded(self, name: str) -> str:
        """The recorded topic behind a YOWO input name ('' when none fills it)."""
        return self.roles.get(name, "")

    @property
    def renamed(self) -> dict[str, str]:
        """Recorded topic -> YOWO input name, for the roles a recorded topic of another name fills."""
        return {rec: name for name, rec in self.roles.items() if rec != name}


def is_input_name(topic: str) -> bool:
    """Whether `topic` is one of YOWO's own input names."""
    return (
        topic
        in (
            *topics.EGO_COLOR,
            *topics.EGO_DEPTH,
            topics.EGO_INFO,
            topics.EGO_IMU,
            topics.EGO_GYRO,
            topics.EGO_ACCEL,
            topics.EGO_IMU_CALIBRATION,
        )
        or topics.parse_cmc_topic(topic) is not None
    )


def parse_remaps(remaps, recorded: set[str]) -> dict[str, str]:
    """YOWO input name -> recorded topic from ROS-style `from:=to` rules (`from` the input name,
    as `ros2 run ... -r` maps a node's topic); a rule written the other way round is read the
    same when exactly one side is an input name."""
    mapping = {}
    for rule in remaps:
        left, sep, right = str(rule).partition(":=")
        left, right = left.strip(), right.strip()
        if not sep or not left.startswith("/") or not right.startswith("/"):
            raise InputMapError(f"remap '{rule}': expected /yowo/input/name:=/recorded/topic (absolute names)")
        if is_input_name(left) and not is_input_name(right):
            name, topic = left, right
        elif is_input_name(right) and not is_input_name(left):
            name, topic = right, left
        else:
            raise InputMapError(
                f"remap '{rule}': exactly one side must be a YOWO input name (/ego/color/image_raw, "
                "/ego/depth/image_raw, /ego/color/camera_info, /ego/imu, /ego/gyro/sample, "
                "/ego/accel/sample, /cmc/<name>/image_raw[/compressed], /cmc/<name>/camera_info, "
                "/cmc/<name>/agent_keypoints)"
            )
        if topic not in recorded:
            raise InputMapError(f"remap '{rule}': the recording has no topic {topic} (see 'yowo info')")
        mapping[name] = topic
    return mapping


def _under(ns: str, rel: str) -> str:
    return f"{ns}/{rel}" if ns != "/" else f"/{rel}"


def _ego_candidates(recorded: set[str]) -> list[tuple[DriverLayout, str, dict[str, str]]]:
    """(driver, namespace, roles) of every complete ego camera a driver's names form."""
    found = []
    for layout in DRIVER_LAYOUTS:
        for topic in sorted(recorded):
            for suffix in ("", _COMPRESSED["color"]):
                tail = f"/{layout.color}{suffix}"
                if not topic.endswith(tail):
                    continue
                ns = topic[: -len(tail)] or "/"
                depth = [
                    t
                    for t in (_under(ns, layout.depth), _under(ns, layout.depth) + _COMPRESSED["depth"])
                    if t in recorded
                ]
                info = _under(ns, layout.info)
                if not depth or info not in recorded:
                    continue
                roles = {
                    topics.EGO_COLOR[1 if suffix else 0]: topic,
                    topics.EGO_INFO: info,
                    topics.EGO_DEPTH[0 if depth[0] == _under(ns, layout.depth) else 1]: depth[0],
                }
                for name, rel in (
                    (topics.EGO_IMU, layout.imu),
                    (topics.EGO_GYRO, layout.gyro),
                    (topics.EGO_ACCEL, layout.accel),
                ):
                    if rel and _under(ns, rel) in recorded:
                        roles[name] = _under(ns, rel)
                found.append((layout, ns, roles))
    # Raw and compressed colour of one device are one candidate.
    unique = {}
    for layout, ns, roles in found:
        unique.setdefault((layout.driver, ns), (layout, ns, {}))[2].update(roles)
    return list(unique.values())


def _camera_name(ns: str, taken: set[str]) -> str:
    """A CMC name from an image namespace: its last part (the whole path where that is taken),
    made a usable camera name (topics.usable_camera_name)."""
    parts = [p for p in ns.strip("/").split("/") if p]
    last = topics.usable_camera_name(parts[-1])
    for name in (last, topics.usable_camera_name("_".join(parts))):
        if name not in taken:
            return name
    n = 2
    while f"{last}_{n}" in taken:
        n += 1
    return f"{last}_{n}"


def map_inputs(recorded_topics, remaps=(), ego_namespace: str = "") -> InputMap:
    """The roles of a recording's topics (names of topics holding messages): the user's
    `remaps` first, then YOWO's own names, then the drivers' layouts and image namespaces."""
    recorded = set(recorded_topics)
    explicit = parse_remaps(remaps, recorded)
    out = InputMap()
    own = {t: t for t in recorded if is_input_name(t)}
    out.roles.update(own)
    claimed = set(explicit.values())
    if explicit:
        out.notes.append("mapped on request: " + ", ".join(f"{n} <- {t}" for n, t in sorted(explicit.items())))

    ego_names = (*topics.EGO_COLOR, *topics.EGO_DEPTH, topics.EGO_INFO)
    device_namespaces = []
    if not any(n in own or n in explicit for n in ego_names):
        candidates = _ego_candidates(recorded - claimed)
        if ego_namespace:
            chosen = [c for c in candidates if c[1] == ego_namespace.rstrip("/") or c[1] == ego_namespace]
            if not chosen:
                out.problems.append(
                    f"inputs.ego_namespace={ego_namespace}: no ego camera under it (found: "
                    f"{', '.join(ns for _, ns, _ in candidates) or 'none'})"
                )
        else:
            chosen = candidates
        if len(chosen) == 1:
            layout, ns, roles = chosen[0]
            out.roles.update(roles)
            claimed |= set(roles.values())
            out.notes.append(f"ego camera: {layout.driver} under {ns}")
        elif len(chosen) > 1:
            out.problems.append(
                "ego camera: several candidates; pick one with --set inputs.ego_namespace=NS: "
                + "; ".join(f"{layout.driver} under {ns} (--set inputs.ego_namespace={ns})" for layout, ns, _ in chosen)
            )
        device_namespaces = [(layout, ns) for layout, ns, _ in candidates]

    taken = {topics.parse_cmc_topic(t)[0] for t in own if topics.parse_cmc_topic(t)}
    taken |= {topics.parse_cmc_topic(n)[0] for n in explicit if topics.parse_cmc_topic(n)}
    images: dict[str, list[str]] = {}
    for t in sorted(recorded - claimed):
        m = _CMC_IMAGE.match(t)
        if m is None or t.startswith(_RESERVED) or _is_device_stream(m["ns"], device_namespaces):
            continue
        images.setdefault(m["ns"], []).append(t)
    for ns, image_topics in sorted(images.items()):
        name = _camera_name(ns, taken)
        taken.add(name)
        roles = {topics.cmc_topic(name, t[len(ns) + 1 :]): t for t in image_topics}
        roles.update(
            {
                topics.cmc_topic(name, rel): _under(ns, rel)
                for rel in _CMC_SIBLINGS
                if _under(ns, rel) in recorded - claimed
            }
        )
        out.roles.update(roles)
        info = "" if topics.cmc_info_topic(name) in roles else ", no camera_info"
        out.notes.append(f"CMC {name}: image namespace {ns}{info}")
    out.roles.update(explicit)
    return out


def _is_device_stream(ns: str, devices: list[tuple[DriverLayout, str]]) -> bool:
    """Whether an image namespace is a stream of a detected RGB-D device (its depth, infrared,
    ...), not a camera of its own."""
    for layout, dev_ns in devices:
        inside = ns.startswith(dev_ns.rstrip("/") + "/")
        if inside and (dev_ns != "/" or ns[1:].split("/")[0] in layout.streams):
            return True
    return False
