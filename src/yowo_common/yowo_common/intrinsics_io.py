"""Camera intrinsics from calibration files, for cameras (CCTV) whose recording has no CameraInfo.

Formats, told apart by content: camera_calibration_parsers YAML (what cameracalibrator writes
and camera_info_manager reads), Kalibr camchain(-imucam).yaml, COLMAP cameras.txt, and OpenCV
FileStorage YAML/XML as cv2.calibrateCamera users save it.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from .camera import EQUIDISTANT, PLUMB_BOB, RATIONAL_POLYNOMIAL, CameraModel

_K_KEYS = ("camera_matrix", "cameraMatrix", "K")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D")
_SIZE_KEYS = ("imageSize", "image_size")
# OpenCV's distortion vector, in order; its lengths are the prefixes that end at these sizes.
_OPENCV_COEFFS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tauX", "tauY")
_OPENCV_LENGTHS = (0, 4, 5, 8, 12, 14)
_D_SIZE = {PLUMB_BOB: 5, RATIONAL_POLYNOMIAL: 8, EQUIDISTANT: 4}
# COLMAP model: (one focal length f for fx and fy, distortion parameter count, CameraInfo model).
# These models list their distortion parameters in OpenCV order, so padding gives D.
_COLMAP_MODELS = {
    "SIMPLE_PINHOLE": (True, 0, PLUMB_BOB),
    "PINHOLE": (False, 0, PLUMB_BOB),
    "SIMPLE_RADIAL": (True, 1, PLUMB_BOB),
    "RADIAL": (True, 2, PLUMB_BOB),
    "OPENCV": (False, 4, PLUMB_BOB),
    "FULL_OPENCV": (False, 8, RATIONAL_POLYNOMIAL),
    "OPENCV_FISHEYE": (False, 4, EQUIDISTANT),
}
_COLMAP_LINE = re.compile(r"\s*\d+\s+[A-Z][A-Z_]*\s+\d+\s+\d+(\s|$)")
_KALIBR_DISTORTIONS = ("radtan", "equidistant", "none")


class IntrinsicsError(ValueError):
    """A calibration file that gives no usable intrinsics; the message names the file and the fault."""


def read_intrinsics(path: str | Path, camera: str = "") -> CameraModel:
    """The intrinsics in a calibration file. ``camera`` selects one camera of a file that holds
    several (Kalibr camN, or a segment or part of its rostopic; COLMAP camera id); a file with one camera
    gives that camera whatever ``camera`` says, as a per-camera file's stored name is often a
    tool's default. Raises IntrinsicsError for anything unreadable or unusable."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise IntrinsicsError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise IntrinsicsError(
            f"{path}: not a text file (COLMAP's cameras.bin: convert the model with "
            "`colmap model_converter --output_type TXT`)"
        ) from None
    return intrinsics_from_text(text, str(path), camera, path.suffix.lower())


def intrinsics_from_text(text: str, where: str, camera: str = "", suffix: str = "") -> CameraModel:
    """The intrinsics in a calibration file's text (see read_intrinsics; `where` names it in
    messages, `suffix` is its file extension if any)."""
    first = _first_data_line(text)
    if text.lstrip().startswith(("<", "%YAML:")) or "!!opencv-" in text:
        model = _from_mapping(_filestorage(text, where), where)
    elif _COLMAP_LINE.match(first) or (suffix == ".txt" and ":" not in first):
        model, where = _colmap(text, camera, where)
    else:
        data = _yaml(text, where)
        if any(_is_kalibr_camera(v) for v in data.values()):
            model, where = _kalibr(data, camera, where)
        else:
            model = _from_mapping(data, where)
    problems = model.problems()
    if problems:
        raise IntrinsicsError(f"{where}: " + "; ".join(problems))
    return model


def camera_info_yaml(model: CameraModel, camera_name: str) -> str:
    """camera_calibration_parsers YAML of ``model`` (camera_info_manager reads it; so does read_intrinsics)."""

    def matrix(m: np.ndarray, rows: int) -> dict[str, Any]:
        return {"rows": rows, "cols": m.size // rows, "data": [float(x) for x in m.reshape(-1)]}

    doc = {
        "image_width": int(model.width),
        "image_height": int(model.height),
        "camera_name": camera_name,
        "camera_matrix": matrix(model.K, 3),
        "distortion_model": model.distortion_model,
        "distortion_coefficients": matrix(model.D, 1),
        "rectification_matrix": matrix(model.R, 3),
        "projection_matrix": matrix(model.P, 3),
    }
    # Flow style for the data lists only, on one line each: the layout cameracalibrator writes.
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=float("inf"))


def _first_data_line(text: str) -> str:
    return next((s for s in text.splitlines() if s.strip() and not s.lstrip().startswith("#")), "")


def _yaml(text: str, where: str) -> dict:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise IntrinsicsError(f"{where}: not YAML, OpenCV FileStorage or COLMAP cameras.txt ({problem}{at})") from None
    if not isinstance(data, dict):
        raise IntrinsicsError(
            f"{where}: not a calibration file (expected a YAML mapping of keys, got {type(data).__name__})"
        )
    return data


def _filestorage(text: str, where: str) -> dict:
    """OpenCV FileStorage YAML/XML -> plain values (matrices as arrays). PyYAML cannot read these:
    OpenCV's own YAML header and !!opencv-matrix tags are not standard YAML."""
    if text.lstrip().startswith("<") and not text.lstrip().startswith("<?xml"):
        text = '<?xml version="1.0"?>\n' + text  # OpenCV recognises XML by this declaration only
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        root = fs.root()
        if not root.isMap():
            raise IntrinsicsError(f"{where}: OpenCV FileStorage file without a mapping of keys")
        data = {key: _node(root.getNode(key)) for key in root.keys()}
        fs.release()
    except (cv2.error, SystemError) as e:
        # The binding may wrap OpenCV's parse error in a SystemError whose cause carries the text.
        message = str(e.__cause__ or e).strip().split("error: ", 1)[-1]
        raise IntrinsicsError(f"{where}: not a valid OpenCV FileStorage file ({message})") from None
    return data


def _node(node: cv2.FileNode) -> Any:
    if node.isMap():
        keys = node.keys()
        if "dt" in keys:  # !!opencv-matrix or !!opencv-nd-matrix
            return node.mat()
        return {key: _node(node.getNode(key)) for key in keys}
    if node.isSeq():
        return [_node(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


def _numbers(value: Any, what: str, count: int | None = None) -> np.ndarray:
    """Flat floats from a list, nested list, array or camera_calibration_parsers {rows, cols, data}."""
    if value is None:
        raise IntrinsicsError(f"{what} is missing")
    if isinstance(value, dict):
        if "data" not in value:
            raise IntrinsicsError(f"{what} has no 'data'")
        data = _floats(value["data"], what)
        if "rows" in value and "cols" in value:
            rows, cols = _floats([value["rows"], value["cols"]], what)
            if rows * cols != data.size:
                raise IntrinsicsError(f"{what}: rows x cols is {rows:g} x {cols:g} but data holds {data.size} numbers")
    else:
        data = _floats(value, what)
    if count is not None and data.size != count:
        raise IntrinsicsError(f"{what} holds {data.size} numbers, expected {count}")
    return data


def _floats(value: Any, what: str) -> np.ndarray:
    try:
        # Strings pass through float(): PyYAML reads exponents without a dot (5e-05) as text.
        out = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise IntrinsicsError(f"{what} is not a list of numbers: {str(value)[:80]}") from None
    if not np.isfinite(out).all():  # also YAML nulls, which become NaN
        raise IntrinsicsError(f"{what} has empty or non-finite entries: {str(value)[:80]}")
    return out


def _int(value: Any, what: str) -> int:
    number = _numbers(value, what, 1)[0]
    if not number.is_integer():
        raise IntrinsicsError(f"{what} is {number:g}, expected a whole number of pixels")
    return int(number)


def _either(keys: tuple[str, ...]) -> str:
    return ", ".join(keys[:-1]) + " or " + keys[-1]


def _pick(data: dict, keys: tuple[str, ...], where: str, missing: str) -> tuple[Any, str]:
    """(value, description) of the first of ``keys`` present in ``data``."""
    key = next((k for k in keys if k in data), None)
    if key is None:
        raise IntrinsicsError(f"{where}: {missing}")
    return data[key], f"{where}: key '{key}'"


def _from_mapping(data: dict, where: str) -> CameraModel:
    """camera_calibration_parsers YAML and OpenCV-style files: one camera, flat keys."""
    value, what = _pick(
        data,
        _K_KEYS,
        where,
        f"no camera matrix (keys {_either(_K_KEYS)}); expected a "
        "camera_calibration_parsers YAML, Kalibr camchain, COLMAP cameras.txt or OpenCV FileStorage file",
    )
    K = _numbers(value, what, 9).reshape(3, 3)
    if not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise IntrinsicsError(f"{what}: last row is {K[2].tolist()}, expected [0, 0, 1] (matrix transposed?)")
    if "image_width" in data or "image_height" in data:
        width = _int(data.get("image_width"), f"{where}: key 'image_width'")
        height = _int(data.get("image_height"), f"{where}: key 'image_height'")
    else:
        value, what = _pick(
            data,
            _SIZE_KEYS,
            where,
            "no image size (keys image_width and image_height, or "
            "imageSize / image_size as [w, h]); the size is needed: add the resolution "
            "the camera was calibrated at",
        )
        width, height = (_int(v, what) for v in _numbers(value, what, 2))
    value, what = _pick(
        data,
        _D_KEYS,
        where,
        f"no distortion coefficients (keys {_either(_D_KEYS)}; an empty list if the images are undistorted)",
    )
    distortion_model, D = _distortion(_numbers(value, what), _model_hint(data, where), what)
    R = (
        _numbers(data["rectification_matrix"], f"{where}: key 'rectification_matrix'", 9)
        if "rectification_matrix" in data
        else None
    )
    P = (
        _numbers(data["projection_matrix"], f"{where}: key 'projection_matrix'", 12)
        if "projection_matrix" in data
        else None
    )
    return CameraModel(width, height, K, D, distortion_model, R, P)


def _model_hint(data: dict, where: str) -> str | None:
    """Distortion model the file names, if any (None: infer it from the coefficient count)."""
    if "distortion_model" in data:
        name = str(data["distortion_model"]).lower()
        if name in ("fisheye", EQUIDISTANT):
            return EQUIDISTANT
        if name in (PLUMB_BOB, RATIONAL_POLYNOMIAL):
            return name
        raise IntrinsicsError(
            f"{where}: key 'distortion_model': '{data['distortion_model']}' is not supported "
            f"(use {PLUMB_BOB}, {RATIONAL_POLYNOMIAL} or {EQUIDISTANT})"
        )
    for key, value in data.items():
        # Flags such as fisheye: 1 or OpenCV's tutorial's fisheye_model: 1, or a name as in model: fisheye.
        if "fisheye" in str(key).lower() and str(value).lower() in ("1", "true"):
            return EQUIDISTANT
        if key in ("model", "camera_model") and "fisheye" in str(value).lower():
            return EQUIDISTANT
    return None


def _distortion(D: np.ndarray, hint: str | None, what: str) -> tuple[str, np.ndarray]:
    """(CameraInfo distortion model, D at that model's length) from OpenCV-ordered coefficients."""
    n = D.size
    if hint == EQUIDISTANT:
        if n != 4:
            raise IntrinsicsError(f"{what}: the fisheye (equidistant) model takes 4 coefficients k1..k4, got {n}")
        return EQUIDISTANT, D
    if n not in _OPENCV_LENGTHS:
        raise IntrinsicsError(f"{what}: {n} distortion coefficients; OpenCV's models take 4, 5, 8, 12 or 14")
    if hint is None:
        hint = PLUMB_BOB if n <= 5 else RATIONAL_POLYNOMIAL
    size = _D_SIZE[hint]
    extra = [_OPENCV_COEFFS[i] for i in range(size, n) if D[i] != 0.0]
    if extra:
        raise IntrinsicsError(
            f"{what}: {hint} takes {size} coefficients ({' '.join(_OPENCV_COEFFS[:size])}); "
            f"YOWO cannot use the nonzero {', '.join(extra)}"
        )
    return hint, np.concatenate([D[:size], np.zeros(max(0, size - n))])


def _select(labels: dict[str, str], camera: str, where: str, topics: dict[str, str] | None = None) -> str:
    """Key of the selected camera. ``labels``: key -> how to list it; ``topics``: key -> rostopic,
    matched by a whole path segment first, then as a substring."""
    if not labels:
        raise IntrinsicsError(f"{where}: holds no cameras")
    if len(labels) == 1:
        return next(iter(labels))
    listing = ", ".join(labels.values())
    if not camera:
        raise IntrinsicsError(f"{where}: holds {len(labels)} cameras, select one (camera=...): {listing}")
    if camera in labels:
        return camera
    for matches in (lambda topic: camera in topic.split("/"), lambda topic: camera in topic):
        hits = [key for key, topic in (topics or {}).items() if matches(topic)]
        if len(hits) == 1:
            return hits[0]
        if hits:
            raise IntrinsicsError(f"{where}: camera '{camera}' is ambiguous: {', '.join(labels[k] for k in hits)}")
    raise IntrinsicsError(f"{where}: no camera '{camera}'; candidates: {listing}")


def _is_kalibr_camera(value: Any) -> bool:
    return isinstance(value, dict) and ("intrinsics" in value or "camera_model" in value)


def _kalibr(data: dict, camera: str, where: str) -> tuple[CameraModel, str]:
    cams = {str(k): v for k, v in data.items() if _is_kalibr_camera(v)}
    topics = {k: str(v.get("rostopic", "")) for k, v in cams.items()}
    key = _select({k: f"{k} ({t})" if t else k for k, t in topics.items()}, camera, where, topics)
    cam, where = cams[key], f"{where}: camera '{key}'"
    kind = cam.get("camera_model", "pinhole")
    if kind != "pinhole":
        raise IntrinsicsError(
            f"{where}: Kalibr camera_model '{kind}' is not supported (only pinhole; "
            "omni, ds and eucm have no CameraInfo counterpart)"
        )
    fu, fv, pu, pv = _numbers(cam.get("intrinsics"), f"{where}: key 'intrinsics' [fu, fv, pu, pv]", 4)
    what = f"{where}: key 'resolution' [w, h]"
    width, height = (_int(v, what) for v in _numbers(cam.get("resolution"), what, 2))
    distortion = cam.get("distortion_model", "none")
    what = f"{where}: key 'distortion_coeffs'"
    if distortion == "radtan":  # k1 k2 p1 p2: OpenCV's plumb_bob without k3
        D, distortion_model = np.append(_numbers(cam.get("distortion_coeffs"), what, 4), 0.0), PLUMB_BOB
    elif distortion == "equidistant":
        D, distortion_model = _numbers(cam.get("distortion_coeffs"), what, 4), EQUIDISTANT
    elif distortion == "none":
        D, distortion_model = np.zeros(5), PLUMB_BOB
    else:
        raise IntrinsicsError(
            f"{where}: Kalibr distortion_model '{distortion}' is not supported (use {', '.join(_KALIBR_DISTORTIONS)})"
        )
    K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])
    return CameraModel(width, height, K, D, distortion_model), where


def _colmap(text: str, camera: str, where: str) -> tuple[CameraModel, str]:
    """COLMAP cameras.txt: one "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]" line per camera."""
    rows: dict[str, tuple[str, int, int, np.ndarray]] = {}
    for number, line in enumerate(text.splitlines(), 1):
        tokens = line.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        at = f"{where}: line {number}"
        if len(tokens) < 4 or not all(t.isdigit() for t in (tokens[0], tokens[2], tokens[3])):
            raise IntrinsicsError(f"{at}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]', got '{line.strip()}'")
        if tokens[0] in rows:
            raise IntrinsicsError(f"{at}: camera id {tokens[0]} appears twice")
        rows[tokens[0]] = (tokens[1], int(tokens[2]), int(tokens[3]), _numbers(tokens[4:], f"{at}: PARAMS"))
    key = _select({k: f"{k} ({r[0]} {r[1]}x{r[2]})" for k, r in rows.items()}, camera, where)
    name, width, height, params = rows[key]
    where = f"{where}: camera {key}"
    if name not in _COLMAP_MODELS:
        raise IntrinsicsError(f"{where}: COLMAP model {name} is not supported (use {', '.join(_COLMAP_MODELS)})")
    single_focal, n_dist, distortion_model = _COLMAP_MODELS[name]
    n_focal = 1 if single_focal else 2
    if params.size != n_focal + 2 + n_dist:
        raise IntrinsicsError(
            f"{where}: COLMAP model {name} takes {n_focal + 2 + n_dist} parameters, got {params.size}"
        )
    fx, fy = params[0], params[n_focal - 1]
    # COLMAP puts the centre of the top-left pixel at (0.5, 0.5), ROS and OpenCV at (0, 0).
    cx, cy = params[n_focal] - 0.5, params[n_focal + 1] - 0.5
    D = np.zeros(_D_SIZE[distortion_model])
    D[:n_dist] = params[n_focal + 2 :]
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return CameraModel(width, height, K, D, distortion_model), where
