"""Names of YOWO's own topics and stages (the output side of the contract in
shared/DESIGN.md §1-2), in one place for nodes, the runner and tests."""

REPLAY_STATUS = "/yowo/replay/status"
GROUPS = "/yowo/cmc/groups"                 # yowo_msgs/CameraGroupArray, latched
EGO_MAP = "/yowo/ego/map"                   # yowo_msgs/EgoMap, latched
EGO_ODOMETRY = "/yowo/ego/odometry"         # nav_msgs/Odometry, online
EGO_PATH = "/yowo/ego/path"                 # nav_msgs/Path, latched
MAP_POINTS = "/yowo/map/points"             # sensor_msgs/PointCloud2, latched
LAYOUT = "/yowo/layout"                     # yowo_msgs/SceneLayout, latched
CMC_POSES = "/yowo/cmc_poses"               # yowo_msgs/RegisteredCameraArray, latched
TF_STATIC = "/tf_static"                    # tf2_msgs/TFMessage, latched
LAYOUT_MARKERS = "/yowo/layout/markers"     # visualization_msgs/MarkerArray, latched

EGO_STAGE, GROUP_SFM_STAGE, FUSION_STAGE = "ego_mapper", "group_sfm", "fusion"


def status(stage: str) -> str:
    return f"/yowo/status/{stage}"


def tracker_stage(camera: str) -> str:
    return f"keypoint_tracker_{camera}"


def tracker_keypoints(camera: str) -> str:
    """Validated (or detected) agent keypoints of one CMC, raw pixels."""
    return f"/yowo/cmc/{camera}/agent_keypoints"


def tracker_background(camera: str) -> str:
    """The CMC's agent-free background image (sensor_msgs/Image rgb8), latched."""
    return f"/yowo/cmc/{camera}/background"
