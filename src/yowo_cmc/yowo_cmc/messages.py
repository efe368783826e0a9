"""CameraGroupArray <-> CMC group results, WalkGuidance <-> coverages (message classes only, no rclpy)."""

from __future__ import annotations

import numpy as np
from std_msgs.msg import Header

from yowo_common.camera import CameraModel
from yowo_common.rosconv import (
    array_to_points,
    camera_info_to_model,
    matrix_to_pose,
    model_to_camera_info,
    ns_to_time,
    points_to_array,
    pose_to_matrix,
    stamp_to_ns,
)
from yowo_msgs.msg import CameraGroup, CameraGroupArray, CameraGuidance, WalkGuidance

from .coverage import NEEDS_MORE, Coverage
from .group_sfm import CameraGroupResult, GroupingResult
from .intrinsics import EstimatedCamera

NAN = float("nan")


def _estimated(camera: CameraModel, focal_sigma_px: float, k1_sigma: float) -> CameraModel:
    """The camera as the group SfM estimated it, when its focal has a sigma (NaN: from CameraInfo)."""
    if not np.isfinite(focal_sigma_px):
        return camera
    return EstimatedCamera.of(camera, focal_sigma_px, k1_sigma)


def groups_to_msg(result: GroupingResult, stamp_ns: int) -> CameraGroupArray:
    msg = CameraGroupArray(header=Header(stamp=ns_to_time(stamp_ns), frame_id=""))
    for g in result.groups:
        msg.groups.append(
            CameraGroup(
                group_id=g.group_id,
                reference_camera=g.reference,
                initial_pair_camera=g.initial_pair[1],
                camera_names=list(g.names),
                poses_local_camera=[matrix_to_pose(g.T_local_cam[n]) for n in g.names],
                reprojection_rmse_px=[float(g.rmse_px[n]) for n in g.names],
                num_observations=[int(g.num_observations[n]) for n in g.names],
                camera_infos=[model_to_camera_info(g.cameras[n]) for n in g.names if n in g.cameras],
                focal_sigmas_px=[float(getattr(g.cameras.get(n), "focal_sigma_px", NAN)) for n in g.names],
                k1_sigmas=[float(getattr(g.cameras.get(n), "k1_sigma", NAN)) for n in g.names],
                clock_offsets_s=[float(g.clock_offsets_s.get(n, np.nan)) for n in g.names],
                clock_sigmas_s=[float(g.clock_sigmas_s.get(n, np.nan)) for n in g.names],
                clocks_applied=g.clocks_applied,
                sigma_keypoint_ids=[int(i) for i in g.sigma_px_by_id],
                sigma_px=[float(s) for s in g.sigma_px_by_id.values()],
                track_stamps=[ns_to_time(int(s)) for s in g.point_stamps_ns],
                track_keypoint_ids=[int(i) for i in g.point_ids],
                track_points=array_to_points(g.points),
            )
        )
    msg.ungrouped_cameras = list(result.ungrouped)
    msg.ungrouped_reasons = list(result.ungrouped.values())
    return msg


def groups_from_msg(msg: CameraGroupArray) -> tuple[list[CameraGroupResult], dict[str, str]]:
    groups = []
    for g in msg.groups:
        names = list(g.camera_names)
        groups.append(
            CameraGroupResult(
                group_id=g.group_id,
                reference=g.reference_camera,
                names=names,
                T_local_cam={n: pose_to_matrix(p) for n, p in zip(names, g.poses_local_camera)},
                point_stamps_ns=np.array([stamp_to_ns(s) for s in g.track_stamps], dtype=np.int64),
                point_ids=np.array(g.track_keypoint_ids, dtype=int),
                points=points_to_array(g.track_points),
                rmse_px=dict(zip(names, g.reprojection_rmse_px)),
                num_observations=dict(zip(names, g.num_observations)),
                sigma_px_by_id={int(i): float(s) for i, s in zip(g.sigma_keypoint_ids, g.sigma_px)},
                initial_pair=(g.reference_camera, g.initial_pair_camera),
                # a group without them (an older message) has no intrinsics to give
                cameras={
                    n: _estimated(camera_info_to_model(i), s, k)
                    for n, i, s, k in zip(
                        names, g.camera_infos, _or_nan(g.focal_sigmas_px, names), _or_nan(g.k1_sigmas, names)
                    )
                }
                if len(g.camera_infos) == len(names)
                else {},
                clock_offsets_s={n: float(o) for n, o in zip(names, g.clock_offsets_s) if np.isfinite(o)},
                clock_sigmas_s={
                    n: float(s) for n, s, o in zip(names, g.clock_sigmas_s, g.clock_offsets_s) if np.isfinite(o)
                },
                clocks_applied=g.clocks_applied,
            )
        )
    return groups, dict(zip(msg.ungrouped_cameras, msg.ungrouped_reasons))


def _or_nan(values, names) -> list[float]:
    """A per-camera array, NaN for every camera when the message has none (an older one)."""
    return list(values) if len(values) == len(names) else [NAN] * len(names)


def guidance_to_msg(coverages: list[Coverage], stamp_ns: int, final: bool) -> WalkGuidance:
    """The walk guidance (walk_guidance.WalkGuide.coverages) as yowo_msgs/WalkGuidance."""

    def number(v) -> float:
        return NAN if v is None else float(v)

    cameras = [
        CameraGuidance(
            name=c.name,
            verdict=c.verdict,
            reasons=list(c.reasons),
            regions_missing=list(c.regions_missing),
            regions_seen=list(c.regions_seen),
            observations=int(c.observations or 0),
            grid_cell_share=number(c.cell_share),
            overlap_score=number(c.overlap),
            depth_near=number(c.depth[0] if c.depth else None),
            depth_far=number(c.depth[1] if c.depth else None),
            depth_unit=c.depth_unit if c.depth else "",
            covisible_cameras=list(c.covisible),
            covisible_times=[int(n) for n in c.covisible.values()],
            in_group=bool(c.group),
            group_id=c.group,
        )
        for c in coverages
    ]
    return WalkGuidance(
        header=Header(stamp=ns_to_time(stamp_ns)),
        final=final,
        source=coverages[0].source if coverages else "",
        needs_more=sum(c.verdict == NEEDS_MORE for c in coverages),
        cameras=cameras,
    )


def guidance_from_msg(msg: WalkGuidance) -> list[Coverage]:
    """yowo_msgs/WalkGuidance -> one Coverage per camera (the fields the message carries)."""

    def value(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    out = []
    for c in msg.cameras:
        near, far = value(c.depth_near), value(c.depth_far)
        out.append(
            Coverage(
                name=c.name,
                source=msg.source,
                observations=int(c.observations),
                cell_share=value(c.grid_cell_share),
                overlap=value(c.overlap_score),
                regions_seen=list(c.regions_seen),
                regions_missing=list(c.regions_missing),
                covisible=dict(zip(c.covisible_cameras, map(int, c.covisible_times))),
                group=c.group_id,
                groups_known=msg.final,
                depth=None if near is None or far is None else (near, far),
                depth_unit=c.depth_unit or "m",
                verdict=c.verdict,
                reasons=list(c.reasons),
            )
        )
    return out
