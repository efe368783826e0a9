"""The inputs of `yowo import-multiview` (see multiview_import), read and checked: the
detectors' joint formats, the reference calibrations (Pose2Sim's Calib*.toml, caliscope's
config.toml / camera_array.toml), the keypoints (OpenPose JSON folders, caliscope's
xy_<TRACKER>.csv), the Pose2Sim session folder and its videos. Bad input raises
MultiviewImportError naming the file."""

from __future__ import annotations

import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from yowo_cmc.skeletons import BODY_25, BODY_25B, COCO_17, COCO_18, FEET, HALPE_26

# Each detector's joints in its own output order (yowo_cmc.skeletons, the declared formats).
FORMATS = {"BODY_25B": BODY_25B, "BODY_25": BODY_25, "COCO_18": COCO_18, "COCO_17": COCO_17, "HALPE_26": HALPE_26}
# Joints beyond COCO's 17, after them (the COCO 17 take MoveNet's ids 2-18, so a recording's
# ids mean what the pose model's do).
EXTRA_JOINTS = ("neck", "head_top", "mid_hip", *FEET)
BLAZEPOSE = "BLAZEPOSE"  # mediapipe's 33 landmarks: the pose model's own BlazePose ids


def joint_ids(fmt: str) -> dict[str, int]:
    """Keypoint id of every joint name of a format (the table in docs/usage.md's importer section)."""
    from yowo_cmc.pose_keypoints import BLAZEPOSE_JOINTS, ID_OFFSET

    names = BLAZEPOSE_JOINTS if fmt == BLAZEPOSE else COCO_17 + EXTRA_JOINTS
    return {n: i + ID_OFFSET for i, n in enumerate(names)}


def format_joints(fmt: str) -> tuple[str, ...]:
    from yowo_cmc.pose_keypoints import BLAZEPOSE_JOINTS

    return BLAZEPOSE_JOINTS if fmt == BLAZEPOSE else FORMATS[fmt]


def all_formats() -> tuple[str, ...]:
    return (*FORMATS, BLAZEPOSE)


class MultiviewImportError(ValueError):
    """Bad input, with the file named; the CLI prints it without a traceback."""


# --- reference calibration ----------------------------------------------------------------
@dataclass
class ReferenceCamera:
    name: str
    camera: object  # yowo_common.camera.CameraModel
    T_world_cam: np.ndarray


def _matrix(value, shape, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise MultiviewImportError(f"{where}: not numbers: {value!r}") from None
    if a.size != math.prod(shape) or not np.isfinite(a).all():
        raise MultiviewImportError(f"{where}: expected {math.prod(shape)} finite numbers, got {value!r}")
    return a.reshape(shape)


def read_pose2sim_calibration(path) -> list[ReferenceCamera]:
    """Pose2Sim's calibration TOML: one table per camera with size [w, h], matrix (K),
    distortions (k1 k2 p1 p2; fisheye: k1..k4), rotation (Rodrigues vector, world ->
    camera), translation (m, world -> camera), fisheye; other tables (metadata) ignored.
    Cameras in sorted table order."""
    import cv2

    from yowo_common.camera import EQUIDISTANT, PLUMB_BOB, CameraModel
    from yowo_common.geometry import inv_se3, se3

    path = Path(path)
    doc = _read_toml(path)
    out = []
    for key in sorted(doc):
        table = doc[key]
        if not isinstance(table, dict) or "matrix" not in table:
            continue
        where = f"{path} [{key}]"
        missing = [k for k in ("size", "matrix", "distortions", "rotation", "translation") if k not in table]
        if missing:
            raise MultiviewImportError(f"{where}: missing {', '.join(missing)}")
        w, h = _matrix(table["size"], (2,), f"{where} size")
        K = _matrix(table["matrix"], (3, 3), f"{where} matrix")
        D = np.asarray(_matrix(table["distortions"], (len(table["distortions"]),), f"{where} distortions"))
        rvec = _matrix(table["rotation"], (3,), f"{where} rotation")
        tvec = _matrix(table["translation"], (3,), f"{where} translation")
        fisheye = bool(table.get("fisheye", False))
        cam = CameraModel(int(round(w)), int(round(h)), K, D, EQUIDISTANT if fisheye else PLUMB_BOB)
        problems = cam.problems()
        if problems:
            raise MultiviewImportError(f"{where}: {'; '.join(problems)}")
        name = re.sub(r"[^A-Za-z0-9_]", "_", str(table.get("name", key)))
        out.append(ReferenceCamera(name, cam, inv_se3(se3(cv2.Rodrigues(rvec)[0], tvec))))
    if len(out) < 2:
        raise MultiviewImportError(
            f"{path}: holds {len(out)} camera table(s) (name, size, matrix, distortions, "
            "rotation, translation); a multi-camera calibration needs two or more"
        )
    return out


def _read_toml(path: Path) -> dict:
    if not path.is_file():
        raise MultiviewImportError(f"{path}: no such calibration file")
    try:
        return tomllib.loads(path.read_text(errors="replace"))
    except tomllib.TOMLDecodeError as exc:
        raise MultiviewImportError(f"{path}: not a TOML file ({exc})") from None


def read_caliscope_calibration(path) -> dict[int, ReferenceCamera]:
    """caliscope's calibration: {camera id: camera named cam_<id>}. Tables [cam_N] (config.toml,
    id in `port`) or [cameras.N] (camera_array.toml, id in `cam_id`) with size, matrix,
    distortions (k1 k2 p1 p2 k3), rotation (3x3, world -> camera), translation (m); cameras
    marked `ignore = true` or not yet posed (no rotation) are left out."""
    from yowo_common.camera import PLUMB_BOB, CameraModel
    from yowo_common.geometry import inv_se3, se3

    path = Path(path)
    doc = _read_toml(path)
    tables = (
        [(f"cameras.{k}", t) for k, t in doc.get("cameras", {}).items()]
        if isinstance(doc.get("cameras"), dict)
        else [(k, t) for k, t in doc.items() if k.startswith("cam_")]
    )
    out = {}
    for key, table in tables:
        if not isinstance(table, dict) or table.get("ignore") is True or "rotation" not in table:
            continue
        where = f"{path} [{key}]"
        missing = [k for k in ("size", "matrix", "distortions", "translation") if k not in table]
        cam_id = table.get("port", table.get("cam_id"))
        if missing or not isinstance(cam_id, int):
            raise MultiviewImportError(f"{where}: missing {', '.join(missing) or 'port / cam_id'}")
        w, h = _matrix(table["size"], (2,), f"{where} size")
        D = _matrix(table["distortions"], (len(table["distortions"]),), f"{where} distortions")
        cam = CameraModel(
            int(round(w)), int(round(h)), _matrix(table["matrix"], (3, 3), f"{where} matrix"), D, PLUMB_BOB
        )
        R = _matrix(table["rotation"], (3, 3), f"{where} rotation (a 3x3 matrix)")
        if abs(np.linalg.det(R) - 1.0) > 1e-3 or not np.allclose(R @ R.T, np.eye(3), atol=1e-3):
            raise MultiviewImportError(f"{where}: rotation is not a rotation matrix")
        problems = cam.problems()
        if problems:
            raise MultiviewImportError(f"{where}: {'; '.join(problems)}")
        T = inv_se3(se3(R, _matrix(table["translation"], (3,), f"{where} translation")))
        out[cam_id] = ReferenceCamera(f"cam_{cam_id}", cam, T)
    if len(out) < 2:
        raise MultiviewImportError(
            f"{path}: holds {len(out)} posed camera table(s) ([cam_N] or [cameras.N] with "
            "size, matrix, distortions, rotation, translation); a multi-camera calibration "
            "needs two or more"
        )
    return out


# --- keypoints ----------------------------------------------------------------------------
_FRAME_NUMBER = re.compile(r"(\d+)(?:_keypoints)?\.json$")


def frame_files(folder: Path) -> list[tuple[int, Path]]:
    """(frame index, file) of an OpenPose JSON folder: the index is the last number of the
    file name (cam01.0007.json, cam01_000000000007_keypoints.json)."""
    out = []
    for f in sorted(folder.glob("*.json")):
        m = _FRAME_NUMBER.search(f.name)
        if not m:
            raise MultiviewImportError(f"{f}: no frame number in the file name")
        out.append((int(m.group(1)), f))
    if not out:
        raise MultiviewImportError(f"{folder}: holds no .json keypoint files")
    if len({i for i, _ in out}) != len(out):
        raise MultiviewImportError(f"{folder}: two files carry the same frame number")
    return sorted(out)


def read_people(path: Path, fmt: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every person of an OpenPose JSON frame: (uv (J, 2), confidence (J,)) in the format's
    joint order; a joint OpenPose did not find (confidence 0) has confidence 0."""
    try:
        doc = json.loads(path.read_text(errors="replace"))
    except json.JSONDecodeError as exc:
        raise MultiviewImportError(f"{path}: not JSON ({exc})") from None
    people = doc.get("people") if isinstance(doc, dict) else None
    if not isinstance(people, list):
        raise MultiviewImportError(f"{path}: no 'people' list (not an OpenPose keypoint file)")
    n = len(format_joints(fmt))
    out = []
    for k, p in enumerate(people):
        flat = p.get("pose_keypoints_2d") if isinstance(p, dict) else None
        try:
            a = np.asarray(flat, dtype=float).reshape(-1, 3)
        except (TypeError, ValueError):
            raise MultiviewImportError(f"{path}: person {k}: pose_keypoints_2d is not a list of x, y, c") from None
        if len(a) == 0:  # OpenPose writes a person whose body was not estimated with no joints
            continue
        if len(a) != n:
            raise MultiviewImportError(
                f"{path}: person {k} has {len(a)} joints; {fmt} has {n} "
                f"(choose the format with --keypoint-format: {', '.join(all_formats())})"
            )
        conf = np.where(np.isfinite(a).all(axis=1), np.clip(a[:, 2], 0.0, 1.0), 0.0)
        out.append((a[:, :2], conf))
    return out


def read_caliscope_keypoints(path) -> dict[int, list[tuple[float, np.ndarray, np.ndarray]]]:
    """caliscope's xy_<TRACKER>.csv: {camera id: [(frame_time s, point ids, uv (N, 2)) per
    frame, in time order]}."""
    import csv

    path = Path(path)
    if not path.is_file():
        raise MultiviewImportError(f"{path}: no such keypoint table")
    with path.open(newline="", errors="replace") as f:
        rows = csv.reader(f)
        head = next(rows, [])
        cam_col = "cam_id" if "cam_id" in head else "port"
        need = [cam_col, "frame_index", "frame_time", "point_id", "img_loc_x", "img_loc_y"]
        missing = [c for c in need if c not in head]
        if missing:
            raise MultiviewImportError(
                f"{path}: no column {', '.join(missing)} (not a caliscope xy_*.csv table; "
                f"its header: {', '.join(head) or 'empty'})"
            )
        col = [head.index(c) for c in need]
        try:
            table = np.array([[float(r[c]) for c in col] for r in rows if r], dtype=float).reshape(-1, len(need))
        except (ValueError, IndexError) as exc:
            raise MultiviewImportError(f"{path}: a row that is not numbers ({exc})") from None
    if not np.isfinite(table).all():
        raise MultiviewImportError(f"{path}: a row with a missing or non-finite value")
    out: dict[int, list] = {}
    table = table[np.lexsort((table[:, 1], table[:, 0]))]  # by camera, then frame
    starts = np.flatnonzero(np.r_[True, np.any(np.diff(table[:, :2], axis=0) != 0, axis=1)])
    for rows in np.split(table, starts[1:]):
        out.setdefault(int(rows[0, 0]), []).append((float(rows[0, 2]), rows[:, 3].astype(int), rows[:, 4:6]))
    return {cam_id: sorted(frames, key=lambda fr: fr[0]) for cam_id, frames in out.items()}


def find_caliscope_calibration(xy_csv: Path) -> Path:
    """The session's config.toml or camera_array.toml, in the table's folder or above it."""
    for folder in xy_csv.resolve().parents:
        for name in ("camera_array.toml", "config.toml"):
            if (folder / name).is_file():
                return folder / name
    raise MultiviewImportError(
        f"{xy_csv}: no config.toml or camera_array.toml in its folder or above (give --calibration)"
    )


# --- the session folder -------------------------------------------------------------------
@dataclass(kw_only=True)
class Session:
    calibration: Path
    cameras: list[ReferenceCamera]
    keypoint_dirs: list[Path]
    videos: list[Path]
    fps: float | None


def _find_calibration(folder: Path) -> Path:
    found = sorted(folder.glob("Calib*.toml")) + sorted(folder.glob("calibration/Calib*.toml"))
    if not found:
        raise MultiviewImportError(f"{folder}: no Calib*.toml in it or in calibration/ (give --calibration)")
    return found[0]


def _frame_rate(folder: Path) -> float | None:
    """Pose2Sim's Config.toml [project] frame_rate when it is a number."""
    cfg = folder / "Config.toml"
    if not cfg.is_file():
        return None
    try:
        rate = tomllib.loads(cfg.read_text(errors="replace")).get("project", {}).get("frame_rate")
    except tomllib.TOMLDecodeError:
        return None
    return float(rate) if isinstance(rate, (int, float)) and rate > 0 else None


def read_session(folder, calibration=None, videos: bool = False, fps: float | None = None) -> Session:
    folder = Path(folder)
    if not folder.is_dir():
        raise MultiviewImportError(f"{folder}: no such folder")
    calib = Path(calibration) if calibration else _find_calibration(folder)
    cams = read_pose2sim_calibration(calib)
    kp_dirs = sorted(d for d in (folder / "pose").glob("*_json") if d.is_dir()) if (folder / "pose").is_dir() else []
    vids = (
        sorted(p for p in (folder / "videos").iterdir() if p.suffix.lower() in (".mp4", ".avi", ".mov", ".mkv"))
        if (folder / "videos").is_dir()
        else []
    )
    rate = fps or _frame_rate(folder) or (Video(vids[0]).fps if vids else None)
    vids = vids if videos else []
    if not kp_dirs and not vids:
        raise MultiviewImportError(
            f"{folder}: no keypoints (pose/<camera>_json/ folders)"
            + (" and no videos (videos/*.mp4)" if videos else "; add --videos to import the videos/ instead")
        )
    for what, items in (("keypoint folders in pose/", kp_dirs), ("videos in videos/", vids)):
        if items and len(items) != len(cams):
            raise MultiviewImportError(
                f"{folder}: {len(items)} {what} but {len(cams)} cameras in {calib} (they are paired in sorted order)"
            )
    if videos and not vids:
        raise MultiviewImportError(f"{folder}: --videos, but no videos/*.mp4 (or .avi, .mov, .mkv)")
    return Session(calibration=calib, cameras=cams, keypoint_dirs=kp_dirs, videos=vids, fps=rate)


class Video:
    """Frames of one video (RGB), by index, read in order."""

    def __init__(self, path: Path):
        import cv2

        self.path, self.cap = path, cv2.VideoCapture(str(path))
        if not self.cap.isOpened():
            raise MultiviewImportError(f"{path}: not a video OpenCV can read")
        self.fps = float(self.cap.get(cv2.CAP_PROP_FPS)) or None
        self.count = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.next = 0

    def frame(self, index: int) -> np.ndarray | None:
        import cv2

        while self.next <= index:
            ok, bgr = self.cap.read()
            self.next += 1
            if not ok:
                return None
            if self.next - 1 == index:
                return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        return None

    def close(self) -> None:
        self.cap.release()
