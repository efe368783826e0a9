"""The results directory of a run: writers and readers of cameras.yaml,
ego_trajectory.tum (yowo_common.trajectory), map.ply and layout.json (map_ego.ply and
layout_ego.json: the ego stage's, before joint optimisation)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from yowo_cmc.config import CmcParams
from yowo_cmc.coverage import coverage_entry, group_coverage
from yowo_cmc.group_sfm import CameraGroupResult
from yowo_cmc.intrinsics import EstimatedCamera
from yowo_common.camera import CameraModel
from yowo_common.geometry import quat_xyzw_from_rotation, rotation_from_quat_xyzw, se3
from yowo_fusion.records import RegisteredCmc


def pose_entry(T: np.ndarray) -> dict:
    return {
        "position": [round(float(v), 9) for v in T[:3, 3]],
        "orientation_xyzw": [round(float(v), 9) for v in quat_xyzw_from_rotation(T[:3, :3])],
    }


def pose_from_entry(entry: dict) -> np.ndarray:
    return se3(rotation_from_quat_xyzw(entry["orientation_xyzw"]), entry["position"])


def pose_sigma(covariance) -> np.ndarray | None:
    """Standard deviations (x, y, z, rx, ry, rz) of a 6x6 covariance; None when the fusion
    could not compute it (missing or NaN: the camera's reason says why)."""
    if covariance is None or not np.isfinite(covariance).all():
        return None
    return np.sqrt(np.clip(np.diag(covariance), 0, None))


# Where the clock offset of a CMC against the ego clock is not estimated, it is written as
# unknown with the assumption the registration made, never as a measured 0.
CLOCK_ENTRY = {"clock_offset_s": None, "clock": "assumed synchronised with the ego camera (offset not estimated)"}


def clock_entry(name: str, group: CameraGroupResult | None, camera: RegisteredCmc | None = None) -> dict:
    """The clock against the ego camera (from the fusion, where estimated), and against
    the camera's group reference from the agent's motion (yowo_cmc.clock)."""
    entry = dict(CLOCK_ENTRY)
    if camera is not None and camera.clock_offset_s is not None:
        entry = {
            "clock_offset_s": round(camera.clock_offset_s, 6),
            "clock_sigma_s": round(camera.clock_sigma_s, 6),
            "clock": f"this camera's clock minus the ego camera's, from {camera.clock_note}; applied",
        }
    elif camera is not None and camera.clock_note:
        entry["clock"] = f"assumed synchronised with the ego camera: {camera.clock_note}"
    if group is not None and name in group.clock_offsets_s:
        entry["clock_offset_to_group_reference_s"] = {
            "offset_s": round(group.clock_offsets_s[name], 6),
            "sigma_s": round(group.clock_sigmas_s[name], 6),
            "reference_camera": group.reference,
            "applied": group.clocks_applied,
            "note": "this camera's clock minus the reference camera's, from the agent's motion; "
            + (
                "the group was calibrated on stamps corrected by it"
                if group.clocks_applied
                else "reported, not applied to the stamps"
            ),
        }
    return entry


def intrinsics_entry(camera: CameraModel | None) -> dict:
    """The intrinsics a camera was registered with: its CameraInfo's (None: no CameraInfo
    arrived), or those estimated (intrinsics.EstimatedCamera: by its group SfM, refined by the
    joint optimisation) with their sigmas."""
    if camera is None:
        return {
            "image_width": None,
            "image_height": None,
            "K": None,
            "distortion_model": None,
            "distortion_coefficients": None,
        }
    entry = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "K": np.asarray(camera.K).round(6).tolist(),
        "distortion_model": camera.distortion_model,
        "distortion_coefficients": [round(float(v), 9) for v in camera.D],
        "intrinsics_estimated": isinstance(camera, EstimatedCamera),
    }
    if isinstance(camera, EstimatedCamera):
        entry["focal_sigma_px"] = round(camera.focal_sigma_px, 4)
        entry["k1_sigma"] = round(camera.k1_sigma, 6) if np.isfinite(camera.k1_sigma) else None
        entry["k2_sigma"] = round(camera.k2_sigma, 6) if np.isfinite(camera.k2_sigma) else None
    return entry


def group_intrinsics(camera: CameraModel | None, group: CameraGroupResult | None, name: str) -> CameraModel | None:
    """A registered camera's intrinsics: `camera` (the registration's: estimated ones as the
    joint optimisation refined them), else its group SfM's estimate where it made one."""
    estimated = group.cameras.get(name) if group is not None else None
    if isinstance(camera, EstimatedCamera) or not isinstance(estimated, EstimatedCamera):
        return camera
    return estimated


def keypoint_noise_entry(group: CameraGroupResult | None) -> dict:
    """The pixel noise the camera's group bundle adjustment estimated (one per keypoint class, listed per id)."""
    if group is None or not group.sigma_px_by_id:
        why = (
            "the camera is in no group"
            if group is None
            else f"group {group.group_id}'s bundle adjustment estimated none (cmc.sfm.class_sigma off, or too few "
            "observations per keypoint class)"
        )
        return {"keypoint_noise": None, "keypoint_noise_note": f"not estimated: {why}"}
    sigma = dict(sorted(group.sigma_px_by_id.items()))
    values = np.array(list(sigma.values()))
    return {
        "keypoint_noise": {
            "estimated_by": f"group {group.group_id} bundle adjustment, one sigma per keypoint class (shared by its cameras)",
            "sigma_px_by_keypoint_id": {int(i): round(float(v), 4) for i, v in sigma.items()},
            "median_px": round(float(np.median(values)), 4),
            "min_px": round(float(values.min()), 4),
            "max_px": round(float(values.max()), 4),
        }
    }


def write_cameras_yaml(
    path: Path,
    cameras: list[RegisteredCmc],
    groups: list[CameraGroupResult] = (),
    cmc: CmcParams = CmcParams(),
    walkers: dict[str, dict] | None = None,
) -> None:
    """Per CMC: how it was registered, T_world_camera (map -> <name>_optical_frame),
    the 6x6 covariance (x, y, z, rx, ry, rz; m^2, rad^2), intrinsics and distortion, clock
    offset, its group's keypoint noise (from `groups`), RMSE, counts, its coverage
    (yowo_cmc.coverage with the run's cmc.coverage and cmc.sfm, from its group's agent points:
    the tracks are not kept here) and, for the pose model's cameras, which person was taken
    for the walker and why (`walkers`, yowo_cmc.walker.WalkerChoice.as_dict)."""
    walkers = walkers or {}
    group_by_id = {g.group_id: g for g in groups}
    coverage = group_coverage(
        list(groups),
        {c.name: c.reason for c in cameras if not c.group},
        world_poses={c.name: c.T_world_cam for c in cameras if c.T_world_cam is not None},
        cameras={c.name: c.camera for c in cameras if c.camera is not None},
        params=cmc.coverage,
        sfm=cmc.sfm,
    )
    out = []
    for c in cameras:
        entry = {"name": c.name, "group": c.group, "method": c.method, "status": c.status, "reason": c.reason}
        if c.T_world_cam is not None:
            entry["T_world_camera"] = pose_entry(c.T_world_cam)
            sig = pose_sigma(c.covariance)
            entry["covariance"] = np.asarray(c.covariance).round(12).tolist() if sig is not None else None
            entry["sigma"] = (
                "unknown (see reason)"
                if sig is None
                else {"position_m": sig[:3].round(5).tolist(), "rotation_deg": np.degrees(sig[3:]).round(4).tolist()}
            )
        entry.update(
            {
                **intrinsics_entry(group_intrinsics(c.camera, group_by_id.get(c.group), c.name)),
                **clock_entry(c.name, group_by_id.get(c.group), c),
                **keypoint_noise_entry(group_by_id.get(c.group)),
                "reprojection_rmse_px": round(float(c.rmse_px), 4),
                "num_agent_observations": int(c.num_agent),
                "num_scene_observations": int(c.num_scene),
                **coverage_entry(coverage.get(c.name)),
                **({"walker": walkers[c.name]} if c.name in walkers else {}),
            }
        )
        out.append(entry)
    path.write_text(yaml.safe_dump({"frame": "map", "cameras": out}, sort_keys=False))


def write_no_cameras_yaml(path: Path, why: str, problems: list[str]) -> None:
    """cameras.yaml of a run that registered no camera (an ego-only run): says so, why, and
    what is wrong with each CMC of the recording, instead of leaving the file out."""
    path.write_text(
        yaml.safe_dump(
            {
                "frame": "map",
                "registered": 0,
                "note": f"no cameras registered: {why}",
                "cmc_problems": list(problems),
                "cameras": [],
            },
            sort_keys=False,
        )
    )


def read_camera_poses(path: Path) -> dict[str, np.ndarray]:
    """The pose of every camera in a cameras.yaml: T_world_camera of a full run, or
    T_group_camera of a CMC-only calibration."""
    doc = yaml.safe_load(Path(path).read_text())
    return {
        c["name"]: pose_from_entry(c.get("T_world_camera") or c["T_group_camera"])
        for c in doc["cameras"]
        if "T_world_camera" in c or "T_group_camera" in c
    }


def write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray | None = None) -> None:
    """Binary little-endian PLY point cloud."""
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    data = np.empty(len(xyz), dtype=fields)
    data["x"], data["y"], data["z"] = xyz.T
    if rgb is not None:
        data["red"], data["green"], data["blue"] = np.asarray(rgb, dtype=np.uint8).reshape(-1, 3).T
    ply_type = {"f4": "float", "u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(xyz)}"]
    header += [f"property {ply_type[t]} {n}" for n, t in fields] + ["end_header"]
    Path(path).write_bytes(("\n".join(header) + "\n").encode() + data.tobytes())


def write_layout_json(path: Path, layout) -> None:
    """yowo_msgs/SceneLayout -> layout.json (planes and floor polygons in `map`)."""
    kinds = {0: "other", 1: "floor", 2: "wall", 3: "ceiling"}
    doc = {
        "frame": "map",
        "floor_height": layout.floor_height,
        "ceiling_height": None if not np.isfinite(layout.ceiling_height) else layout.ceiling_height,
        "floor_polygons": [[[p.x, p.y] for p in poly.points] for poly in layout.floor_polygons],
        "planes": [
            {
                "kind": kinds.get(p.kind, "other"),
                "coefficients": list(p.coefficients),
                "boundary": [[q.x, q.y, q.z] for q in p.boundary],
                "num_points": p.num_points,
            }
            for p in layout.planes
        ],
    }
    Path(path).write_text(json.dumps(doc, indent=1))


def read_floor_polygons(path: Path) -> list[np.ndarray]:
    return [np.asarray(p, dtype=float) for p in json.loads(Path(path).read_text())["floor_polygons"]]


WEAK_PLACES_HEADER = """\
# The walk's weak places (yowo_fusion.weak_places): where a second walk would help the map.
#   weak tracking: the ego camera tracked weakly or lost track (walk it again, slower, facing texture);
#   walked once: never returned to, nothing checks its drift (walk back through it);
#   track misses the walk: a group's agent track and the ego map disagree (walk it again in view of the group).
# start_s / end_s: seconds from the walk's first frame; x_m / y_m: the place's centre in the map frame;
# extent_m: the stretch's path length, or the walked-once area's diagonal.
"""


def write_weak_places_yaml(path: Path, places: list[dict]) -> None:
    path.write_text(WEAK_PLACES_HEADER + yaml.safe_dump({"weak_places": places}, sort_keys=False))
