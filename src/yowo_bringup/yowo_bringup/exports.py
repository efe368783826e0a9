"""Exports of a run's registered CMCs for other tools (results/<run>/export/):
camera_info YAML per camera (camera_calibration_parsers / camera_info_manager), a COLMAP
text model of the CMCs and the ego keyframes, static transforms (YAML and a ROS 2 launch
file of static_transform_publisher), and a kalibr camchain per CMC group."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from yowo_cmc.group_sfm import CameraGroupResult
from yowo_common import topics
from yowo_common.camera import EQUIDISTANT, PLUMB_BOB, RATIONAL_POLYNOMIAL, CameraModel
from yowo_common.geometry import inv_se3, quat_xyzw_from_rotation, transform_points
from yowo_fusion.messages import WORLD_FRAME, optical_frame
from yowo_fusion.records import EgoMapData, RegisteredCmc

# kalibr's cam_overlaps: two cameras of a group overlap when at least this many points of
# the group's agent track fall in both images (the group SfM's minimum for an edge).
MIN_SHARED_TRACK_POINTS = 8


def _matrix(rows: int, cols: int, values) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.asarray(values, float).reshape(-1)]}


def camera_info_yaml(name: str, camera: CameraModel) -> dict:
    """One camera in the camera_calibration_parsers YAML layout (what camera_info_manager loads)."""
    return {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": name,
        "camera_matrix": _matrix(3, 3, camera.K),
        "distortion_model": camera.distortion_model,
        "distortion_coefficients": _matrix(1, len(camera.D), camera.D),
        "rectification_matrix": _matrix(3, 3, camera.R),
        "projection_matrix": _matrix(3, 4, camera.P),
    }


def colmap_camera(camera: CameraModel) -> tuple[str, list[float]] | str:
    """(COLMAP model, params) of a camera, or why COLMAP has no model for it. COLMAP puts the
    centre of the top-left pixel at (0.5, 0.5), ROS/OpenCV at (0, 0): the principal point
    moves by half a pixel."""
    fx, fy, cx, cy = camera.K[0, 0], camera.K[1, 1], camera.K[0, 2] + 0.5, camera.K[1, 2] + 0.5
    D = np.asarray(camera.D, float)
    if not camera.has_distortion:
        return "PINHOLE", [fx, fy, cx, cy]
    if camera.distortion_model == EQUIDISTANT:
        return "OPENCV_FISHEYE", [fx, fy, cx, cy, *np.pad(D, (0, 4))[:4]]
    if camera.distortion_model in (PLUMB_BOB, RATIONAL_POLYNOMIAL):
        full = np.pad(D, (0, 8))
        if np.any(full[8:]):  # thin-prism / tilt terms of OpenCV's 12/14-coefficient model
            return f"its {len(D)} distortion coefficients include thin-prism/tilt terms COLMAP has no model for"
        if not np.any(full[4:8]):
            return "OPENCV", [fx, fy, cx, cy, *full[:4]]
        return "FULL_OPENCV", [fx, fy, cx, cy, *full[:8]]
    return f"distortion model '{camera.distortion_model}' has no COLMAP camera model"


def kalibr_camera(camera: CameraModel) -> tuple[str, list[float]] | str:
    """(kalibr distortion model, coefficients) of a pinhole camera, or why kalibr has none."""
    D = np.pad(np.asarray(camera.D, float), (0, 4))
    if not camera.has_distortion:
        return "radtan", [0.0, 0.0, 0.0, 0.0]
    if camera.distortion_model == EQUIDISTANT:
        return "equidistant", D[:4].tolist()
    if camera.distortion_model == PLUMB_BOB and not np.any(D[4:]):
        return "radtan", D[:4].tolist()
    return (
        f"distortion model '{camera.distortion_model}' with coefficients {np.round(camera.D, 6).tolist()}: "
        "kalibr's radtan has k1 k2 p1 p2 only"
    )


def _colmap_camera_line(camera_id: int, camera: CameraModel, model: tuple[str, list[float]]) -> str:
    return f"{camera_id} {model[0]} {camera.width} {camera.height} " + " ".join(f"{v:.12g}" for v in model[1])


def _colmap_pose(T_world_cam: np.ndarray) -> str:
    """qw qx qy qz tx ty tz of T_cam_world (COLMAP's world-to-camera)."""
    T = inv_se3(T_world_cam)
    x, y, z, w = quat_xyzw_from_rotation(T[:3, :3])
    return " ".join(f"{v:.12g}" for v in (w, x, y, z, *T[:3, 3]))


@dataclass(frozen=True, kw_only=True)
class ExportImages:
    """The pixels of the images a COLMAP model names (RGB uint8 arrays)."""

    cmc: dict[str, np.ndarray] = field(default_factory=dict)  # camera name -> its background
    ego: dict[int, np.ndarray] = field(default_factory=dict)  # keyframe stamp [ns] -> its colour image


# A landmark takes the colour of the map's nearest cloud point within this distance [m].
COLOUR_RADIUS_M = 0.05


def write_colmap_model(
    folder: Path, cameras: list[RegisteredCmc], ego: EgoMapData | None, images: ExportImages = ExportImages()
) -> list[str]:
    """cameras.txt, images.txt, points3D.txt: one camera and one image per registered CMC
    (cmc/<name>.png, its background; no 2D points), the ego camera and its keyframes
    (ego/<stamp_ns>.png) with their landmark observations; points3D are the ego map's
    landmarks, coloured from the map's cloud. Returns what was left out and why."""
    folder.mkdir(parents=True, exist_ok=True)
    skipped, cam_lines, image_lines, point_lines = [], [], [], []
    for c in cameras:
        if c.T_world_cam is None or c.camera is None:
            skipped.append(f"{c.name}: not registered ({c.status})")
            continue
        model = colmap_camera(c.camera)
        if isinstance(model, str):
            skipped.append(f"{c.name}: {model}")
            continue
        cid = len(cam_lines) + 1
        cam_lines.append(_colmap_camera_line(cid, c.camera, model))
        image_lines += [f"{cid} {_colmap_pose(c.T_world_cam)} {cid} cmc/{c.name}.png", ""]
    if ego is not None and len(ego.stamps_ns):
        model = colmap_camera(ego.camera)
        if isinstance(model, str):
            skipped.append(f"ego camera: {model}")
        else:
            ego_cid = len(cam_lines) + 1
            cam_lines.append(_colmap_camera_line(ego_cid, ego.camera, model))
            point_lines = _ego_images_and_points(ego, ego_cid, len(image_lines) // 2 + 1, image_lines)
    header = "# written by yowo (export of a run); COLMAP text format\n"
    (folder / "cameras.txt").write_text(
        header + "# CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n" + "".join(line + "\n" for line in cam_lines)
    )
    (folder / "images.txt").write_text(
        header + "# IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
        "# POINTS2D[] as (X, Y, POINT3D_ID)\n" + "".join(line + "\n" for line in image_lines)
    )
    (folder / "points3D.txt").write_text(
        header + "# POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as "
        "(IMAGE_ID, POINT2D_IDX)\n" + "".join(line + "\n" for line in point_lines)
    )
    return skipped + _write_images(folder, image_lines, images)


def _write_images(folder: Path, image_lines: list[str], images: ExportImages) -> list[str]:
    """The PNG of every image images.txt names; what has no pixels is said."""
    import cv2

    missing = []
    for line in image_lines[::2]:
        name = line.rsplit(" ", 1)[1]
        kind, stem = name[: -len(".png")].split("/")
        rgb = images.cmc.get(stem) if kind == "cmc" else images.ego.get(int(stem))
        if rgb is None:
            missing.append(name)
            continue
        (folder / kind).mkdir(exist_ok=True)
        cv2.imwrite(str(folder / name), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return (
        [
            f"{len(missing)} of the {len(image_lines) // 2} images named in images.txt have no pixels in this run "
            f"(e.g. {missing[0]}: the recording holds no image of it)"
        ]
        if missing
        else []
    )


def _landmark_colours(ego: EgoMapData) -> np.ndarray:
    """(P, 3) uint8: each landmark's colour, that of the map's nearest cloud point (grey
    where none is within COLOUR_RADIUS_M)."""
    from scipy.spatial import cKDTree

    colours = np.full((len(ego.landmarks), 3), 128, np.uint8)
    if len(ego.cloud_points) and len(ego.landmarks):
        dist, idx = cKDTree(ego.cloud_points).query(ego.landmarks, distance_upper_bound=COLOUR_RADIUS_M)
        near = np.isfinite(dist)
        colours[near] = np.clip(np.round(ego.cloud_colors[idx[near]] * 255), 0, 255).astype(np.uint8)
    return colours


def _ego_images_and_points(ego: EgoMapData, camera_id: int, first_image_id: int, image_lines: list[str]) -> list[str]:
    """Appends the ego keyframes to image_lines; returns the points3D lines. The error of a
    point is its RMS reprojection error [px] at the written poses."""
    tracks: dict[int, list[tuple[int, int]]] = {}
    sq_err: dict[int, list[float]] = {}
    for f, (stamp, T) in enumerate(zip(ego.stamps_ns, ego.T_world_ego)):
        sel = np.flatnonzero(ego.obs_pose == f)
        lm = ego.obs_landmark[sel]
        uv = ego.obs_uv[sel]
        proj, _ = ego.camera.project_world(T, ego.landmarks[lm])
        image_id = first_image_id + f
        for k, (j, e) in enumerate(zip(lm, np.sum((proj - uv) ** 2, axis=1))):
            tracks.setdefault(int(j), []).append((image_id, k))
            sq_err.setdefault(int(j), []).append(float(e))
        image_lines.append(f"{image_id} {_colmap_pose(T)} {camera_id} ego/{int(stamp)}.png")
        image_lines.append(" ".join(f"{x + 0.5:.6f} {y + 0.5:.6f} {int(j) + 1}" for (x, y), j in zip(uv, lm)))
    lines = []
    for j, (X, rgb) in enumerate(zip(ego.landmarks, _landmark_colours(ego))):
        track = tracks.get(j, [])
        err = float(np.sqrt(np.mean(sq_err[j]))) if track else -1.0
        lines.append(
            f"{j + 1} {X[0]:.9g} {X[1]:.9g} {X[2]:.9g} {rgb[0]} {rgb[1]} {rgb[2]} {err:.6g} "
            + " ".join(f"{i} {k}" for i, k in track)
        )
    return lines


def static_transform_args(c: RegisteredCmc) -> list[str]:
    """static_transform_publisher's arguments (ROS 2 Jazzy's named form) for map -> the camera."""
    x, y, z = c.T_world_cam[:3, 3]
    qx, qy, qz, qw = quat_xyzw_from_rotation(c.T_world_cam[:3, :3])
    values = dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), (x, y, z, qx, qy, qz, qw)))
    return [a for k, v in values.items() for a in (f"--{k}", f"{v:.12g}")] + [
        "--frame-id",
        WORLD_FRAME,
        "--child-frame-id",
        optical_frame(c.name),
    ]


LAUNCH_TEMPLATE = '''"""Static transforms map -> <camera>_optical_frame of the registered CMCs (written by yowo).
ros2 launch static_tf.launch.py"""
from launch import LaunchDescription
from launch_ros.actions import Node

# (node name, static_transform_publisher arguments)
TRANSFORMS = {transforms}


def generate_launch_description():
    return LaunchDescription([Node(package="tf2_ros", executable="static_transform_publisher", name=name,
                                   arguments=arguments) for name, arguments in TRANSFORMS])
'''


def write_static_tf(folder: Path, cameras: list[RegisteredCmc]) -> None:
    """static_tf.yaml (one entry per registered camera, with its command line) and
    static_tf.launch.py (one static_transform_publisher per camera)."""
    placed = [c for c in cameras if c.T_world_cam is not None]
    entries = []
    for c in placed:
        x, y, z = (round(float(v), 9) for v in c.T_world_cam[:3, 3])
        qx, qy, qz, qw = (round(float(v), 9) for v in quat_xyzw_from_rotation(c.T_world_cam[:3, :3]))
        entries.append(
            {
                "frame_id": WORLD_FRAME,
                "child_frame_id": optical_frame(c.name),
                "translation": {"x": x, "y": y, "z": z},
                "rotation": {"x": qx, "y": qy, "z": qz, "w": qw},
                "command": "ros2 run tf2_ros static_transform_publisher " + " ".join(static_transform_args(c)),
            }
        )
    (folder / "static_tf.yaml").write_text(yaml.safe_dump({"transforms": entries}, sort_keys=False))
    transforms = [(f"{c.name}_static_tf", static_transform_args(c)) for c in placed]
    (folder / "static_tf.launch.py").write_text(LAUNCH_TEMPLATE.format(transforms=_py_literal(transforms)))


def _py_literal(transforms: list[tuple[str, list[str]]]) -> str:
    if not transforms:
        return "[]"
    return "[\n" + "".join(f"    ({name!r}, {args!r}),\n" for name, args in transforms) + "]"


def kalibr_camchain(group: CameraGroupResult, cameras: dict[str, RegisteredCmc]) -> tuple[dict, list[str]]:
    """kalibr camchain of one group's cameras that kalibr can model (registered, pinhole with
    radtan or equidistant distortion), in the group's order; T_cn_cnm1 takes points from the
    previous written camera's frame to this one's (metric, from the poses in the map).
    Returns (camchain, skipped cameras with why)."""
    chain, skipped, kept = {}, [], []
    for n in group.names:
        c = cameras.get(n)
        if c is None:
            model = "not in the run's cameras"
        elif c.T_world_cam is None or c.camera is None:
            model = f"not registered ({c.status})"
        else:
            model = kalibr_camera(c.camera)
        if isinstance(model, str):
            skipped.append(f"{n}: {model}")
            continue
        K = c.camera.K
        entry = {
            "camera_model": "pinhole",
            "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
            "distortion_model": model[0],
            "distortion_coeffs": [float(v) for v in model[1]],
            "resolution": [int(c.camera.width), int(c.camera.height)],
            "rostopic": topics.cmc_image_topics(n)[0],
        }
        if kept:
            T = inv_se3(c.T_world_cam) @ kept[-1].T_world_cam
            entry["T_cn_cnm1"] = np.round(T, 12).tolist()
        chain[f"cam{len(kept)}"] = entry
        kept.append(c)
    for i, a in enumerate(kept):
        chain[f"cam{i}"]["cam_overlaps"] = [j for j, b in enumerate(kept) if j != i and _overlap(group, a, b)]
    return chain, skipped


def _overlap(group: CameraGroupResult, a: RegisteredCmc, b: RegisteredCmc) -> bool:
    """Whether enough of the group's agent track (group frame) lies in both cameras' images."""
    seen = []
    for c in (a, b):
        P = transform_points(inv_se3(group.T_local_cam[c.name]), group.points)
        uv, front = c.camera.project(P)
        seen.append(front & c.camera.in_image(uv))
    return int(np.sum(seen[0] & seen[1])) >= MIN_SHARED_TRACK_POINTS


def write_exports(
    folder: Path,
    cameras: list[RegisteredCmc],
    groups: list[CameraGroupResult],
    ego: EgoMapData | None,
    images: ExportImages = ExportImages(),
) -> list[Path]:
    """Every export of a full run into folder; README.md lists them and what was left out."""
    shutil.rmtree(folder, ignore_errors=True)  # a previous run's cameras would stay mixed in
    folder.mkdir(parents=True)
    notes = []
    info_dir = folder / "camera_info"
    info_dir.mkdir(exist_ok=True)
    for c in cameras:
        if c.camera is None:
            notes.append(f"camera_info/{c.name}.yaml: not written, no CameraInfo of {c.name} arrived")
            continue
        # flow-style matrices, as camera_calibration_parsers writes them
        (info_dir / f"{c.name}.yaml").write_text(
            yaml.safe_dump(camera_info_yaml(c.name, c.camera), sort_keys=False, default_flow_style=None)
        )
    notes += [f"colmap: {s}" for s in write_colmap_model(folder / "colmap", cameras, ego, images)]
    write_static_tf(folder, cameras)
    by_name = {c.name: c for c in cameras}
    for g in groups:
        chain, skipped = kalibr_camchain(g, by_name)
        notes += [f"camchain_{g.group_id}.yaml: {s}" for s in skipped]
        if chain:
            (folder / f"camchain_{g.group_id}.yaml").write_text(
                f"# kalibr camchain of CMC group {g.group_id}"
                + "".join(f"\n# skipped {s}" for s in skipped)
                + "\n"
                + yaml.safe_dump(chain, sort_keys=False, default_flow_style=None)
            )
        else:
            notes.append(f"camchain_{g.group_id}.yaml: not written, kalibr can model none of its cameras")
    readme = folder / "README.md"
    readme.write_text(
        EXPORT_README + ("\nLeft out:\n" + "".join(f"- {n}\n" for n in notes) if notes else "\nNothing was left out.\n")
    )
    return sorted(p for p in folder.rglob("*") if p.is_file())


EXPORT_README = """# Exports of this run (written by yowo)

- `camera_info/<name>.yaml`: the CameraInfo each CMC was registered with, camera_calibration_parsers
  layout (`camera_info_url:=file:///.../<name>.yaml` for camera_info_manager).
- `colmap/`: COLMAP text model (`pycolmap.Reconstruction("colmap")`, `colmap gui --import_path`): one image
  per registered CMC (`cmc/<name>.png`, its background without the walker; no 2D points) and per ego
  keyframe (`ego/<stamp_ns>.png`), the ego map's landmarks as points3D coloured from the map. COLMAP's pixel convention: principal point and 2D points are +0.5 px from ROS's.
- `static_tf.yaml`, `static_tf.launch.py`: map -> `<name>_optical_frame` per registered CMC
  (`ros2 launch static_tf.launch.py`).
- `camchain_<group>.yaml`: kalibr camchain per CMC group (pinhole; radtan k1 k2 p1 p2 or equidistant).
"""
