"""The keypoints of a person seen by a human-pose model (pose_model): the models' joint
tables, their ids, and the two keypoints every YOWO detector shares, 0 (head top) and 1
(ground point under the agent), derived from the skeleton.

Ids: body joint j of the model gets id j + 2 (tables below and in
docs/pose_model.md). Every camera of one run must use the same model, since ids
are matched across cameras.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .keypoint_input import KeypointFrame
from .params import PoseModelParams

HEAD_TOP, GROUND = 0, 1  # as in Keypoint2D.msg and image_detector
ID_OFFSET = 2  # id = model joint index + 2

MOVENET_JOINTS = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
BLAZEPOSE_JOINTS = (
    "nose",
    "left_eye_inner",
    "left_eye",
    "left_eye_outer",
    "right_eye_inner",
    "right_eye",
    "right_eye_outer",
    "left_ear",
    "right_ear",
    "mouth_left",
    "mouth_right",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_pinky",
    "right_pinky",
    "left_index",
    "right_index",
    "left_thumb",
    "right_thumb",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
    "left_heel",
    "right_heel",
    "left_foot_index",
    "right_foot_index",
)
JOINTS = {"movenet": MOVENET_JOINTS, "blazepose": BLAZEPOSE_JOINTS}


# Head top above a head point, as a multiple of that point's distance from the
# shoulders' midpoint (ears, eyes, nose; the first pair/point seen is used).
# Anthropometric: vertex 13 / 12 / 16 cm above tragion / eyes / nose tip, those
# 21 / 23 / 18 cm above the shoulder joints; hair and a head-mounted camera add
# a little (checked on the bus.jpg persons, docs/pose_model.md).
HEAD_TOP_RATIOS = {"ears": 0.70, "eyes": 0.60, "nose": 0.95}


@dataclass(kw_only=True)
class PersonPose:
    """One person in one image. ids / uv / confidence are parallel arrays holding
    every id of the model (0, 1, then the joints); a keypoint that was not seen
    or not derivable has confidence 0 (uv NaN when not derivable)."""

    score: float
    box: np.ndarray  # (4,) x_min, y_min, x_max, y_max [px]
    ids: np.ndarray  # (K,) int
    uv: np.ndarray  # (K, 2) raw pixels
    confidence: np.ndarray  # (K,) in [0, 1]

    @property
    def keypoints(self) -> np.ndarray:
        """(K, 4) rows of id, u, v, confidence."""
        return np.column_stack([self.ids, self.uv, self.confidence])

    def keypoint(self, kid: int) -> tuple[float, float, float]:
        i = int(np.flatnonzero(self.ids == kid)[0])
        return float(self.uv[i, 0]), float(self.uv[i, 1]), float(self.confidence[i])

    def frame(self, stamp_ns: int, min_confidence: float = PoseModelParams.min_keypoint_score) -> KeypointFrame:
        """As keypoint_input's KeypointFrame (the type the trackers consume), with
        keypoints below min_confidence left out."""
        keep = (self.confidence >= min_confidence) & np.isfinite(self.uv).all(axis=1)
        return KeypointFrame(stamp_ns, self.ids[keep].copy(), self.uv[keep].copy(), self.confidence[keep].copy())


def _seen(joints: dict, names, thr: float):
    pts = [joints[n] for n in names if n in joints]
    if len(pts) != len(names) or any(c < thr for _, c in pts):
        return None
    return np.mean([uv for uv, _ in pts], axis=0), min(float(c) for _, c in pts)


def head_top(joints: dict, thr: float) -> tuple[float, float, float]:
    """Keypoint 0 from a skeleton {name: (uv, confidence)}: above the head point
    (ears' midpoint, else eyes', else the nose) along the shoulders-to-head axis,
    by HEAD_TOP_RATIOS of that axis (the neck and head scale alike under the
    camera's foreshortening). (nan, nan, 0) without both shoulders and a head
    point; the confidence is the lowest of the joints used, lowered for the less
    reliable head points."""
    shoulders = _seen(joints, ("left_shoulder", "right_shoulder"), thr)
    if shoulders is None:
        return math.nan, math.nan, 0.0
    for key, names, trust in (
        ("ears", ("left_ear", "right_ear"), 0.9),
        ("eyes", ("left_eye", "right_eye"), 0.8),
        ("nose", ("nose",), 0.6),
    ):
        head = _seen(joints, names, thr)
        if head is not None:
            top = head[0] + HEAD_TOP_RATIOS[key] * (head[0] - shoulders[0])
            return float(top[0]), float(top[1]), trust * min(head[1], shoulders[1])
    return math.nan, math.nan, 0.0


def ground_point(joints: dict, thr: float, ankle_to_ground: float) -> tuple[float, float, float]:
    """Keypoint 1 from a skeleton: the floor point between the feet. With feet
    landmarks (BlazePose heels and toe tips, which touch the floor in stance) the
    mean of the feet's contact points; else below the ankles' midpoint, along the
    hips-to-ankles axis by `ankle_to_ground` of it. (nan, nan, 0) without both
    feet, or both ankles and hips."""
    feet = _seen(joints, ("left_heel", "right_heel", "left_foot_index", "right_foot_index"), thr)
    if feet is not None:
        return float(feet[0][0]), float(feet[0][1]), float(feet[1])
    ankles = _seen(joints, ("left_ankle", "right_ankle"), thr)
    hips = _seen(joints, ("left_hip", "right_hip"), thr)
    if ankles is None or hips is None:
        return math.nan, math.nan, 0.0
    g = ankles[0] + ankle_to_ground * (ankles[0] - hips[0])
    # Derived over a longer lever than the feet's own contact: a little less trusted.
    return float(g[0]), float(g[1]), 0.8 * min(ankles[1], hips[1])


# A big toe (OpenPose, HALPE) stands for BlazePose's foot index: both touch the floor in stance.
FOOT_INDEX_ALIASES = {"left_big_toe": "left_foot_index", "right_big_toe": "right_foot_index"}


def derive_top_and_ground(joints: dict, params: PoseModelParams) -> tuple[tuple, tuple]:
    """Keypoints 0 and 1 (head_top, ground_point) from a skeleton's named joints {name: (uv,
    confidence)}: the one derivation the pose model, declared skeletons and the importer share."""
    joints = dict(joints)
    joints.update({a: joints[t] for t, a in FOOT_INDEX_ALIASES.items() if t in joints and a not in joints})
    return head_top(joints, params.joint_score), ground_point(joints, params.joint_score, params.ankle_to_ground)
