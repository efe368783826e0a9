"""The joint optimisation of the aligned groups with the ego map (joint.py solves one
JointProblem): a solution a group cannot be reconciled with is solved again without that
group, which keeps its alignment."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from yowo_cmc.intrinsics import EstimatedCamera
from yowo_common.bundle import Observations, reprojection_residuals
from yowo_common.camera import CameraModel

from .alignment import head_top_rms
from .config import FusionParams
from .grouped import GroupedCmcs
from .joint import JointProblem, JointResult, reidealised, solve_joint, solver_failure
from .records import AgentTrack, EgoMapData
from .verdict import reprojection_rmse


@dataclass(kw_only=True)
class JointOutcome:
    """The joint optimisation's outcome on GroupedCmcs' cameras and agent points: each
    camera's pose (its group's alignment where it was not in a kept solution)."""

    result: JointResult | None  # None: no solution kept (failure says why)
    in_jo: np.ndarray  # (cameras,) bool: the camera's pose is the solution's
    T_world_cmc: list[np.ndarray]
    agent_points: np.ndarray
    left_out: dict[str, str]  # group -> why it was left out of the solution
    failure: str = ""
    intrinsics: dict[str, EstimatedCamera] = field(default_factory=dict)  # camera -> estimated intrinsics refined


def with_intrinsics(
    grouped: GroupedCmcs, refined: dict[str, EstimatedCamera], estimated: dict[str, CameraModel]
) -> GroupedCmcs:
    """The grouped cameras with the refined intrinsics of those whose group SfM estimated
    them (`estimated`: the group's models): their ideal cameras and agent observations."""
    index = {grouped.names.index(n): c for n, c in refined.items()}
    before = {grouped.names.index(n): estimated[n] for n in refined}
    cams = [CameraModel(c.width, c.height, index[i].K) if i in index else c for i, c in enumerate(grouped.cams)]
    return replace(grouped, cams=cams, agent_obs=reidealised(grouped.agent_obs, before, index))


def solve_groups(
    grouped: GroupedCmcs,
    scene_obs: Observations,
    ego: EgoMapData,
    ideal_ego: CameraModel,
    weak: tuple[np.ndarray, np.ndarray],
    params: FusionParams,
    estimated: dict[str, EstimatedCamera] | None = None,
) -> JointOutcome:
    """The joint optimisation of every group; a solution a group cannot be reconciled with
    (its agent reprojection diverged, or its track does not fit the ego trajectory the
    solution made) is solved again without that group, which keeps its alignment: one wrong group
    (rooms joined through a doorway) must not cost the others theirs. `estimated`: the
    intrinsics group SfMs estimated (camera -> model), refined by the solution."""
    estimated = estimated or {}
    n_cams = len(grouped.names)
    none = JointOutcome(
        result=None,
        in_jo=np.zeros(n_cams, bool),
        T_world_cmc=list(grouped.T_init),
        agent_points=grouped.agent.points,
        left_out={},
    )
    ego_obs = _ego_observations(ego, params)
    left_out: dict[str, str] = {}
    while params.joint_optimisation:
        cams = np.array([grouped.group_of[n] not in left_out for n in grouped.names])
        chains = [c for g, (c, _) in grouped.chains.items() if g not in left_out]
        points = np.isin(grouped.agent_chain, chains)
        try:
            problem = _problem(grouped, cams, points, scene_obs, ego, ideal_ego, ego_obs, weak, estimated)
            res = solve_joint(problem, params.joint)
        except RuntimeError as exc:  # GTSAM gave up on the system: keep the aligned poses
            return replace(
                none, left_out=left_out, failure=f"joint optimisation failed ({solver_failure(exc)}): pose without JO"
            )
        T_world_cmc, agent_points = list(grouped.T_init), grouped.agent.points.copy()
        for i, T in zip(np.flatnonzero(cams), res.T_world_cmc):
            T_world_cmc[i] = T
        agent_points[points] = res.agent_points
        names = [n for n, k in zip(grouped.names, cams) if k]
        out = JointOutcome(
            result=res,
            in_jo=cams,
            T_world_cmc=T_world_cmc,
            agent_points=agent_points,
            left_out=left_out,
            intrinsics={names[i]: c for i, c in res.cmc_intrinsics.items()},
        )
        why, group = _diverged(with_intrinsics(grouped, out.intrinsics, estimated), out, grouped, params)
        if not why:
            why, group = _unreconciled(grouped, out, ego, params)
        if not why:
            return out
        if group is None or len(left_out) + 1 >= min(len(grouped.chains), params.max_joint_solves):
            return replace(none, left_out=left_out, failure=f"{why}: pose without JO")
        left_out[group] = f"group {group} left out of the joint optimisation: {why}"
    return none


def _problem(
    grouped: GroupedCmcs,
    cams: np.ndarray,
    points: np.ndarray,
    scene_obs: Observations,
    ego: EgoMapData,
    ideal_ego: CameraModel,
    ego_obs: Observations,
    weak: tuple[np.ndarray, np.ndarray],
    estimated: dict[str, EstimatedCamera],
) -> JointProblem:
    """The joint problem of the ego map with the cameras and agent points kept (cams, points: bool masks)."""
    cam_index, point_index = np.cumsum(cams) - 1, np.cumsum(points) - 1
    kept = [n for n, k in zip(grouped.names, cams) if k]
    agent_obs = grouped.agent_obs.subset(cams[grouped.agent_obs.camera])  # a camera sees its group's points
    agent_obs = replace(agent_obs, camera=cam_index[agent_obs.camera], point=point_index[agent_obs.point])
    scene = scene_obs.subset(cams[scene_obs.camera])
    scene = replace(scene, camera=cam_index[scene.camera])
    return JointProblem(
        ego_camera=ideal_ego,
        ego_stamps_ns=ego.stamps_ns,
        T_world_ego=list(ego.T_world_ego),
        landmarks=ego.landmarks,
        ego_obs=ego_obs,
        cmc_cameras=[c for c, k in zip(grouped.cams, cams) if k],
        T_world_cmc=[T for T, k in zip(grouped.T_init, cams) if k],
        cmc_scene_obs=scene,
        agent_points=grouped.agent.points[points],
        agent_stamps_ns=grouped.agent.stamps_ns[points],
        agent_ids=grouped.agent.ids[points],
        cmc_agent_obs=agent_obs,
        head_offset=grouped.head_offset,
        agent_chain=grouped.agent_chain[points],
        ego_weak_frames=weak[0],
        ego_attitude_held=ego.attitude_held,
        ego_imu=bool(ego.imu),
        cmc_estimated={i: estimated[n] for i, n in enumerate(kept) if n in estimated},
    )


def _diverged(
    solved: GroupedCmcs, jo: JointOutcome, grouped: GroupedCmcs, params: FusionParams
) -> tuple[str, str | None]:
    """Why the joint optimisation's result is rejected: a camera's agent reprojection RMSE
    above ok_rmse_px and worse than before it (on a badly broken ego map it can end in a
    minimum where the group no longer fits its own views), and the camera's group; or ''.
    `solved`: `grouped` with the intrinsics the solution refined."""
    obs = grouped.agent_obs
    after = reprojection_residuals(solved.cams, jo.T_world_cmc, jo.agent_points, solved.agent_obs)
    before = reprojection_residuals(grouped.cams, grouped.T_init, grouped.agent.points, obs)
    for c in np.flatnonzero(jo.in_jo):
        a, b = reprojection_rmse(after[obs.camera == c]), reprojection_rmse(before[obs.camera == c])
        if not np.isfinite(a) or (a > params.ok_rmse_px and a > max(2.0 * b, b + 1.0)):
            name = grouped.names[c]
            return (
                f"joint optimisation diverged ({name}'s agent reprojection RMSE {a:.1f} px, {b:.1f} px before it)"
            ), grouped.group_of[name]
    return "", None


def _unreconciled(
    grouped: GroupedCmcs, jo: JointOutcome, ego: EgoMapData, params: FusionParams
) -> tuple[str, str | None]:
    """Why a solution is rejected: a group's agent track still disagrees with the ego
    trajectory it solved for by more than max_unexplained_track_rms_m (the solution could not
    reconcile the two: a wrong group bends the map, and any unflagged breaks it freed, for all
    the others), and the worst such group; or ''."""
    res = jo.result
    agent = AgentTrack(grouped.agent.stamps_ns, grouped.agent.ids, jo.agent_points)
    worst, culprit = params.max_unexplained_track_rms_m, None
    for gid, (c, _) in sorted(grouped.chains.items()):
        rms = (
            head_top_rms(
                agent,
                grouped.fit_chain,
                c,
                ego.stamps_ns,
                np.asarray(res.T_world_ego),
                res.head_offset,
                params.align.max_time_gap_s,
            )
            if gid not in jo.left_out
            else float("nan")
        )
        if np.isfinite(rms) and rms > worst:
            worst, culprit = rms, gid
    if culprit is None:
        return "", None
    breaks = f" (it found {len(res.ego_breaks)} unflagged break step(s) in the ego map)" if len(res.ego_breaks) else ""
    return (
        f"group {culprit}'s head-top track does not fit the ego trajectory of the joint solution{breaks}: RMS "
        f"{worst:.2f} m > {params.max_unexplained_track_rms_m:g} m"
    ), culprit


def _ego_observations(ego: EgoMapData, params: FusionParams) -> Observations:
    return Observations(
        ego.obs_pose.astype(int),
        ego.obs_landmark.astype(int),
        ego.camera.undistort_pixels(ego.obs_uv),
        np.full(len(ego.obs_pose), params.joint.ego_sigma_px),
    )
