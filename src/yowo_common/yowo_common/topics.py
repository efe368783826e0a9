"""Topic and stage names of YOWO in one place: the recorded inputs and ground
truth of docs/design.md §3, and YOWO's own outputs."""

import re

# --- inputs (recordings or live cameras) ---
EGO_COLOR = ("/ego/color/image_raw", "/ego/color/image_raw/compressed")
EGO_DEPTH = ("/ego/depth/image_raw", "/ego/depth/image_raw/compressedDepth")
EGO_INFO = "/ego/color/camera_info"
EGO_IMU = "/ego/imu"
# A driver's separate gyro and accelerometer streams (sensor_msgs/Imu each, their own rates),
# where it publishes no united /ego/imu.
EGO_GYRO = "/ego/gyro/sample"
EGO_ACCEL = "/ego/accel/sample"
# std_msgs/String, latched: the IMU's Kalibr-style calibration as YAML (imu.yaml's noise
# densities and random walks, rate, T_cam_imu, timeshift_cam_imu); T_cam_imu is on /tf_static too.
EGO_IMU_CALIBRATION = "/ego/imu/calibration"


def cmc_topic(name: str, relative: str) -> str:
    """A topic of CMC `name` under /cmc/<name>/ (e.g. a live camera's image topic)."""
    return f"/cmc/{name}/{relative.lstrip('/')}"


def cmc_image_topics(name: str) -> tuple[str, str]:
    return cmc_topic(name, "image_raw"), cmc_topic(name, "image_raw/compressed")


def cmc_info_topic(name: str) -> str:
    return f"/cmc/{name}/camera_info"


def cmc_keypoints_topic(name: str) -> str:
    return f"/cmc/{name}/agent_keypoints"


# A camera's name is one ROS name token (a letter first), short enough for its node and topic names.
CAMERA_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")
_CMC_KINDS = r"(?P<kind>image_raw(/compressed)?|camera_info|agent_keypoints)"
_CMC_TOPIC = re.compile(r"^/cmc/(?P<name>[A-Za-z][A-Za-z0-9_]{0,62})/" + _CMC_KINDS + "$")
_CMC_ANY = re.compile(r"^/cmc/(?P<name>.+)/" + _CMC_KINDS + "$")


def usable_camera_name(name: str) -> str:
    """A usable camera name close to `name` (letters, digits, '_'; a letter first; at most 63)."""
    cleaned = re.sub(r"[^A-Za-z0-9_]", "_", name).strip("_") or "camera"
    return (cleaned if cleaned[0].isalpha() else f"cam_{cleaned}")[:63]


def unusable_cmc_topic(topic: str) -> str:
    """Why a /cmc/<name>/<kind> topic's name cannot be a camera's, with the remapping that
    renames it ('' for a usable one and any other topic)."""
    m = _CMC_ANY.match(topic)
    if m is None or _CMC_TOPIC.match(topic):
        return ""
    good = usable_camera_name(m["name"])
    return (
        f"{topic}: '{m['name'][:80]}' cannot be a camera name (letters, digits and '_', a letter first, at most 63 "
        f"characters); rename it, e.g. -r {cmc_topic(good, m['kind'])}:={topic}"
    )


def parse_cmc_topic(topic: str) -> tuple[str, str] | None:
    """(camera name, kind) of a CMC input topic (kind: image_raw, image_raw/compressed,
    camera_info or agent_keypoints), None for any other topic."""
    m = _CMC_TOPIC.match(topic)
    return (m["name"], m["kind"]) if m else None


def gt_cmc_pose_topic(name: str) -> str:
    return f"/gt/cmc/{name}/pose"


def gt_cmc_clock_offset_topic(name: str) -> str:
    """std_msgs/Float64, latched: the CMC's clock minus the ego camera's [s] (its stamps are
    true time + this). Recorded only when the clocks are not synchronised (absent: 0)."""
    return f"/gt/cmc/{name}/clock_offset"


GT_PREFIX = "/gt/"  # ground truth: read by evaluation only, never played
GT_EGO_POSE = "/gt/ego/pose"
GT_FLOOR = "/gt/layout/floor"
GT_AGENT_KEYPOINTS = "/gt/agent/keypoints"  # geometry_msgs/PoseArray: poses[k].position = keypoint id k in map
# Bystanders (simulator, issue #46), recorded only when there are any: a PoseArray at each
# CMC frame's true stamp (as GT_AGENT_KEYPOINTS) with, per bystander i in order, poses[2 i]
# its head top and poses[2 i + 1] its ground point (keypoint ids 0 and 1) in map; and a
# latched std_msgs/String YAML with each one's height and clothes.
GT_BYSTANDER_KEYPOINTS = "/gt/bystanders/keypoints"
GT_BYSTANDER_INFO = "/gt/bystanders/info"
# A walk deficient on purpose (simulator, issue #48), recorded only then: a latched std_msgs/String
# YAML, `deficient:` a list of {kind: corner, camera, corner, ...} or {kind: doorway, door_x_m, ...}.
GT_DEFICIENT = "/gt/deficient"
# sensor_msgs/Imu, one per /ego/imu message (same stamp): angular_velocity / linear_acceleration
# hold the true gyro / accelerometer biases (measured = true + bias + white noise).
GT_EGO_IMU_BIAS = "/gt/ego/imu_bias"


def parse_gt_cmc_pose_topic(topic: str) -> str | None:
    """The camera name of a /gt/cmc/<name>/pose topic, else None."""
    parts = topic.split("/")
    return parts[3] if len(parts) == 5 and topic == gt_cmc_pose_topic(parts[3]) else None


# --- YOWO's own topics ---
CLOCK = "/clock"  # rosgraph_msgs/Clock: the recording's time while replaying
REPLAY_STATUS = "/yowo/replay/status"
GROUPS = "/yowo/cmc/groups"  # yowo_msgs/CameraGroupArray, latched
# std_msgs/String, latched: the people the group SfM matched across cameras, as YAML
# (yowo_cmc.people_identity.PeopleIdentity.as_dict); a CMC-only run's.
PEOPLE = "/yowo/cmc/people"
EGO_MAP = "/yowo/ego/map"  # yowo_msgs/EgoMap, latched
EGO_ODOMETRY = "/yowo/ego/odometry"  # nav_msgs/Odometry, online
EGO_PATH = "/yowo/ego/path"  # nav_msgs/Path, latched
MAP_POINTS = "/yowo/map/points"  # sensor_msgs/PointCloud2, latched
LAYOUT = "/yowo/layout"  # yowo_msgs/SceneLayout, latched
CMC_POSES = "/yowo/cmc_poses"  # yowo_msgs/RegisteredCameraArray, latched
TF_STATIC = "/tf_static"  # tf2_msgs/TFMessage, latched
LAYOUT_MARKERS = "/yowo/layout/markers"  # visualization_msgs/MarkerArray, latched
# The ego map's cloud and layout at the jointly optimised ego poses (the fusion's).
REFINED_MAP_POINTS = "/yowo/fusion/map/points"  # sensor_msgs/PointCloud2, latched
REFINED_LAYOUT = "/yowo/fusion/layout"  # yowo_msgs/SceneLayout, latched
REFINED_EGO_PATH = "/yowo/fusion/path"  # nav_msgs/Path, latched: the ego trajectory after JO
AGENT_FIT = "/yowo/fusion/agent_fit"  # yowo_msgs/CameraAgentFitArray, latched: the report's panels
# std_msgs/String, latched: the walk's weak places as a YAML list (yowo_fusion.weak_places).
WEAK_PLACES = "/yowo/fusion/weak_places"
# yowo_msgs/WalkGuidance, a durable stream: per ceiling camera "ok" or what is missing and where,
# published by the group SfM during the walk (every cmc.coverage.guidance_period_s) and at its end.
GUIDANCE = "/yowo/guidance"

# The graph's stages by node name (a tracker's is TRACKER_STAGE_<camera>).
REPLAY_STAGE, EGO_STAGE, GROUP_SFM_STAGE, FUSION_STAGE = "replay", "ego_mapper", "group_sfm", "fusion"
TRACKER_STAGE = "keypoint_tracker"


def status(stage: str) -> str:
    return f"/yowo/status/{stage}"


def tracker_stage(camera: str) -> str:
    return f"{TRACKER_STAGE}_{camera}"


def tracker_keypoints(camera: str) -> str:
    """Validated (or detected) agent keypoints of one CMC, raw pixels."""
    return f"/yowo/cmc/{camera}/agent_keypoints"


def tracker_people(camera: str) -> str:
    """Every other person the CMC's tracker saw beside the walker (yowo_msgs/PersonKeypoints,
    raw pixels), in a CMC-only run: the group SfM matches them across cameras."""
    return f"/yowo/cmc/{camera}/people_keypoints"


def tracker_walker(camera: str) -> str:
    """Which person in the CMC's view the pose model's tracker took for the walker, and the
    evidence (std_msgs/String YAML, yowo_cmc.walker.WalkerChoice.as_dict), latched."""
    return f"/yowo/cmc/{camera}/walker"


def tracker_camera_info(camera: str) -> str:
    """The CMC's first valid CameraInfo (or the invalid one, relayed: the stages downstream
    name its fault), latched: only the tracker reads the replayed /cmc/<name>/ topics, so a
    restarted tracker alone is sent them again."""
    return f"/yowo/cmc/{camera}/camera_info"


def tracker_background(camera: str) -> str:
    """The CMC's agent-free background image (sensor_msgs/Image rgb8), latched."""
    return f"/yowo/cmc/{camera}/background"
