"""Declared keypoint skeletons: which joint, and which noise class, each id of a detector's
output is. A camera's agent keypoints carry the detector's own numbering offset by 2
(Keypoint2D.msg; ids 0 and 1 are YOWO's head top and ground point); with the skeleton
declared (cmc.keypoints), ids 0 and 1 are derived from the named joints when the detector
does not publish them, and the group SfM pools its noise estimate by the declared classes
instead of id ranges. The formats' tables follow each detector's documentation (OpenPose
output docs, Pose2Sim's skeletons, MediaPipe's landmark lists; the holistic numbering is
caliscope's: pose 0-32, left hand 100-120, right hand 200-220, face 500 + landmark)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from .keypoint_input import KeypointFrame
from .params import PoseModelParams
from .pose_keypoints import BLAZEPOSE_JOINTS, GROUND, HEAD_TOP, ID_OFFSET, MOVENET_JOINTS, derive_top_and_ground

BODY, HAND, FACE = "body", "hand", "face"
CLASSES = (BODY, HAND, FACE)
# The derived ids' own classes (their errors are the derivation's, not a joint's).
TOP_CLASS, GROUND_CLASS = "head_top", "ground"

FEET = ("left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe", "right_heel")
COCO_17 = MOVENET_JOINTS
BODY_25 = (
    "nose",
    "neck",
    "right_shoulder",
    "right_elbow",
    "right_wrist",
    "left_shoulder",
    "left_elbow",
    "left_wrist",
    "mid_hip",
    "right_hip",
    "right_knee",
    "right_ankle",
    "left_hip",
    "left_knee",
    "left_ankle",
    "right_eye",
    "left_eye",
    "right_ear",
    "left_ear",
    *FEET,
)
COCO_18 = BODY_25[:8] + BODY_25[9:19]
BODY_25B = (*COCO_17, "neck", "head_top", *FEET)
HALPE_26 = (
    *COCO_17,
    "head_top",
    "neck",
    "mid_hip",
    "left_big_toe",
    "right_big_toe",
    "left_small_toe",
    "right_small_toe",
    "left_heel",
    "right_heel",
)
HAND_21 = (
    "wrist",
    *(f"{finger}_{joint}" for finger in ("thumb",) for joint in ("cmc", "mcp", "ip", "tip")),
    *(f"{finger}_{joint}" for finger in ("index", "middle", "ring", "pinky") for joint in ("mcp", "pip", "dip", "tip")),
)
FACE_LANDMARKS = 468


@dataclass(frozen=True, kw_only=True)
class Skeleton:
    """A detector's output: per detector id (its own numbering) the joint name and class."""

    name: str
    joints: dict[int, str]
    classes: dict[int, str]

    def noise_class(self, yowo_id: int) -> str:
        """The noise class of a keypoint id as YOWO numbers it (detector id + 2)."""
        if yowo_id in (HEAD_TOP, GROUND):
            return TOP_CLASS if yowo_id == HEAD_TOP else GROUND_CLASS
        return self.classes.get(yowo_id - ID_OFFSET, BODY)

    def complete(self, frame: KeypointFrame, params: PoseModelParams) -> KeypointFrame:
        """The frame with ids 0 and 1 derived from its named joints where the detector did not
        publish them (pose_keypoints.derive_top_and_ground, the pose model's own rules), and
        ids the skeleton does not know left out."""
        known = np.array([i == HEAD_TOP or i == GROUND or (i - ID_OFFSET) in self.joints for i in frame.ids], bool)
        ids, uv, conf = frame.ids[known], frame.uv[known], frame.confidence[known]
        joints = {self.joints[int(i) - ID_OFFSET]: (p, float(c)) for i, p, c in zip(ids, uv, conf) if i >= ID_OFFSET}
        top, ground = derive_top_and_ground(joints, params)
        extra = [
            (k, p) for k, p in ((HEAD_TOP, top), (GROUND, ground)) if k not in ids and p[2] > 0 and math.isfinite(p[0])
        ]
        if not extra:
            return KeypointFrame(frame.stamp_ns, ids, uv, conf)
        return KeypointFrame(
            frame.stamp_ns,
            np.concatenate([[k for k, _ in extra], ids]).astype(ids.dtype),
            np.vstack([[p[:2] for _, p in extra], uv.reshape(-1, 2)]),
            np.concatenate([[p[2] for _, p in extra], conf]).astype(conf.dtype),
        )


def _body(name: str, names: tuple[str, ...]) -> Skeleton:
    return Skeleton(name=name, joints=dict(enumerate(names)), classes={i: _class_of(n) for i, n in enumerate(names)})


def _class_of(joint: str) -> str:
    return HAND if joint.endswith(("pinky", "index", "thumb")) and "foot" not in joint else BODY


def _holistic() -> Skeleton:
    joints = dict(enumerate(BLAZEPOSE_JOINTS))
    classes = {i: BODY for i in joints}
    for base, side in ((100, "left"), (200, "right")):
        for j, n in enumerate(HAND_21):
            joints[base + j], classes[base + j] = f"{side}_hand_{n}", HAND
    for j in range(FACE_LANDMARKS):
        joints[500 + j], classes[500 + j] = f"face_{j}", FACE
    return Skeleton(name="holistic", joints=joints, classes=classes)


FORMATS = {
    "coco17": _body("coco17", COCO_17),
    "coco18": _body("coco18", COCO_18),
    "body25": _body("body25", BODY_25),
    "body25b": _body("body25b", BODY_25B),
    "halpe26": _body("halpe26", HALPE_26),
    "blazepose33": _body("blazepose33", BLAZEPOSE_JOINTS),
    "holistic": _holistic(),
}
ALIASES = {"movenet": "coco17", "blazepose": "blazepose33", "mediapipe_holistic": "holistic", "openpose": "body25"}


def _key(name: str) -> str:
    return name.strip().lower().replace("-", "").replace("_", "")


_BY_KEY = {_key(k): k for k in FORMATS} | {_key(k): v for k, v in ALIASES.items()}


def load_skeleton(spec: str, where: str) -> Skeleton:
    """A named format (coco17, coco18, body25, body25b, halpe26, blazepose33, holistic; or
    movenet, blazepose, openpose) or a YAML table file `{id: {name: NAME, class: body|hand|face}}`
    (ids as the detector numbers them). ValueError naming `where` on anything else."""
    if _key(spec) in _BY_KEY:
        return FORMATS[_BY_KEY[_key(spec)]]
    path = Path(spec)
    if path.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(
            f"{where}: unknown keypoint skeleton '{spec}' (a format: {', '.join(FORMATS)}; "
            "or a YAML file {id: {name: ..., class: body|hand|face}})"
        )
    try:
        table = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{where}: skeleton file {path}: {exc}") from None
    if not isinstance(table, dict) or not table:
        raise ValueError(f"{where}: skeleton file {path}: expected a mapping of ids to {{name, class}}")
    joints, classes = {}, {}
    for key, entry in table.items():
        if not isinstance(key, int) or key < 0 or not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
            raise ValueError(f"{where}: skeleton file {path}: entry {key!r}: expected id: {{name: ..., class: ...}}")
        kind = entry.get("class", BODY)
        if kind not in CLASSES:
            raise ValueError(
                f"{where}: skeleton file {path}: id {key}: class '{kind}' is not one of {', '.join(CLASSES)}"
            )
        joints[key], classes[key] = entry["name"], kind
    return Skeleton(name=str(path), joints=joints, classes=classes)


def camera_skeleton(params, camera: str) -> Skeleton | None:
    """One camera's declared skeleton (cmc.keypoints: KeypointFormatParams), None undeclared."""
    spec = params.skeleton
    for entry in params.cameras:
        name, eq, value = entry.partition("=")
        if not eq or not name or not value:
            raise ValueError(f"cmc.keypoints.cameras: '{entry}': expected CAMERA=SKELETON")
        spec = value if name == camera else spec
    return load_skeleton(spec, f"camera '{camera}'") if spec else None


def declared_skeletons(params, cameras: list[str]) -> dict[str, Skeleton]:
    """{camera: its skeleton} of the cameras with one declared (cmc.keypoints). ValueError
    when an entry is malformed, names an unknown camera or skeleton, or two cameras declare
    different skeletons (their ids are matched across cameras, so a run takes one)."""
    for entry in params.cameras:
        camera, eq, spec = entry.partition("=")
        if not eq or not camera or not spec:
            raise ValueError(f"cmc.keypoints.cameras: '{entry}': expected CAMERA=SKELETON")
        if camera not in cameras:
            raise ValueError(f"cmc.keypoints.cameras: '{entry}': no camera '{camera}' (cameras: {', '.join(cameras)})")
    loaded = {c: s for c in cameras if (s := camera_skeleton(params, c)) is not None}
    if len({s.name for s in loaded.values()}) > 1:
        raise ValueError(
            "cameras declare different keypoint skeletons ("
            + ", ".join(f"{c}: {s.name}" for c, s in sorted(loaded.items()))
            + "): keypoint ids are matched across cameras, so every camera of a run uses one"
        )
    return loaded
