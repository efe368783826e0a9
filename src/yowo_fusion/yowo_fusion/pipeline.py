"""Collaborative processing end to end (paper "Collaborative Processing" and
"Register 6-DoF Poses for Isolated CMCs"), fuse() in named steps: the groups aligned to the
world by rebalanced Umeyama (grouped.py), their scene keypoints matched with pose priors,
the joint optimisation (joint_groups.py), the ego map's cloud and layout refined at the
jointly optimised ego poses, each grouped camera's covariance and verdict (verdict.py), the
isolated CMCs registered, and the poses no ceiling camera can have refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from yowo_cmc.group_sfm import CameraGroupResult
from yowo_cmc.intrinsics import EstimatedCamera
from yowo_cmc.keypoint_tracks import TrackParams
from yowo_common.bundle import Observations, reprojection_residuals
from yowo_common.camera import CameraModel
from yowo_ego.layout import KIND_CEILING

from .alignment import head_top_rms
from .config import FusionParams, UpstreamParams
from .grouped import GroupedCmcs, gather_groups
from .isolated import PnpResult, ego_agent_track, merge_tracks, refine_pose, register_over_clock
from .joint_groups import JointOutcome, solve_groups, with_intrinsics
from .records import (
    GROUP_SFM,
    ISOLATED_PNP,
    WEAK,
    AgentFit,
    AgentTrack,
    CmcInput,
    EgoMapData,
    FusionResult,
    RegisteredCmc,
    unregistered,
)
from .refined_map import move_cloud, rebuild_layout
from .scene_matching import match_scene
from .verdict import (
    ego_stretch,
    fixed_point_covariance,
    group_distrust,
    refuse_absurd,
    reprojection_rmse,
    residual_verdict,
    weak_ego_frames,
)
from .weak_places import weak_places


def fuse(
    ego: EgoMapData,
    groups: list[CameraGroupResult],
    ungrouped: dict[str, str],
    cmcs: dict[str, CmcInput],
    params: FusionParams = FusionParams(),
    upstream: UpstreamParams = UpstreamParams(),
) -> FusionResult:
    """Every camera registered in the ego map's world frame, with its verdict, and the ego map
    refined by the joint optimisation."""
    estimated = {n: c for g in groups for n, c in g.cameras.items() if isinstance(c, EstimatedCamera)}
    cmcs = _with_cameras(cmcs, estimated)
    weak = weak_ego_frames(ego, params)
    grouped = gather_groups(ego, groups, ungrouped, cmcs, params, weak, upstream.tracks)
    scene_obs, scene_count = _scene_observations(grouped, cmcs, ego, params)
    # The ego stage's map until the joint optimisation refines it; the cameras come last.
    result = FusionResult(
        cameras=[],
        T_world_ego=ego.T_world_ego,
        landmarks=ego.landmarks,
        agent=grouped.agent,
        head_offset=grouped.head_offset,
        point_cloud=ego.cloud_points,
        point_colors=ego.cloud_colors,
        layout=ego.layout,
        alignments=grouped.alignments,
    )
    registered: list[RegisteredCmc] = []
    fits: list[AgentFit] = []
    if grouped.names:
        ideal_ego = CameraModel(ego.camera.width, ego.camera.height, ego.camera.K)
        jo = solve_groups(grouped, scene_obs, ego, ideal_ego, weak, params, estimated)
        grouped, cmcs = with_intrinsics(grouped, jo.intrinsics, estimated), _with_cameras(cmcs, jo.intrinsics)
        result, weak = _refine_map(result, jo, ego, ideal_ego, weak, upstream)
        registered, fits = _register_grouped(grouped, jo, result, ego, weak, scene_count, cmcs, params)
    registered += _register_isolated_cameras(grouped, result, ego, weak, cmcs, params, upstream.tracks)
    registered = _refuse_absurd_poses(registered, grouped, result, params)
    places = weak_places(
        ego.stamps_ns,
        result.T_world_ego,
        weak,
        result.agent,
        grouped.fit_chain,
        {g: c for g, (c, _) in grouped.chains.items()},
        result.head_offset,
        params.weak_places,
    )
    return replace(result, cameras=sorted(registered, key=lambda r: r.name), agent_fits=fits, weak_places=places)


def _with_cameras(cmcs: dict[str, CmcInput], cameras: dict[str, CameraModel]) -> dict[str, CmcInput]:
    """The cameras' inputs with other intrinsics: a camera without CameraInfo is projected with
    those its group SfM estimated, then with those the joint optimisation refined."""
    return {n: replace(c, tracks=replace(c.tracks, camera=cameras[n])) if n in cameras else c for n, c in cmcs.items()}


def _scene_observations(
    grouped: GroupedCmcs, cmcs: dict[str, CmcInput], ego: EgoMapData, params: FusionParams
) -> tuple[Observations, dict[str, int]]:
    """The grouped cameras' scene keypoints matched to the ego map's landmarks at their
    aligned poses, and how many each camera matched."""
    c_idx, p_idx, uv = [], [], []
    count = {}
    if params.use_scene_keypoints and len(ego.landmarks):
        for i, n in enumerate(grouped.names):
            m = match_scene(
                cmcs[n].background,
                cmcs[n].tracks.camera,
                grouped.T_init[i],
                ego.landmarks,
                ego.descriptors,
                ego.descriptor_type,
                params.scene,
            )
            if m is None:
                continue
            c_idx += [i] * len(m.landmark)
            p_idx += m.landmark.tolist()
            uv.append(m.uv)
            count[n] = len(m.landmark)
    obs = Observations(
        np.array(c_idx, int), np.array(p_idx, int), np.vstack(uv or [np.zeros((0, 2))]), np.full(len(c_idx), 1.5)
    )
    return obs, count


def _refine_map(
    result: FusionResult,
    jo: JointOutcome,
    ego: EgoMapData,
    ideal_ego: CameraModel,
    weak: tuple[np.ndarray, np.ndarray],
    upstream: UpstreamParams,
) -> tuple[FusionResult, tuple[np.ndarray, np.ndarray]]:
    """The ego map (trajectory, landmarks, cloud, layout), the agent track and the head offset
    at the joint solution, if one was kept; the weak frames with the breaks it found."""
    res = jo.result
    if res is None:
        return result, weak
    # Breaks the joint optimisation found are breaks of the ego map like its gaps.
    found = np.isin(np.arange(len(ego.stamps_ns)), res.ego_breaks)
    weak = (weak[0] | found, weak[1] | found)
    T_ego = np.array(res.T_world_ego)
    cloud, layout = result.point_cloud, result.layout
    if len(cloud):
        views = res.anchors
        cloud = move_cloud(cloud, ideal_ego, ego.T_world_ego[views], T_ego[views], upstream.cloud.depth_max_m)
        layout = rebuild_layout(cloud, T_ego[views, :3, 3], upstream.cloud, upstream.layout)
    refined = replace(
        result,
        T_world_ego=T_ego,
        landmarks=res.landmarks,
        agent=AgentTrack(result.agent.stamps_ns, result.agent.ids, jo.agent_points),
        head_offset=res.head_offset,
        point_cloud=cloud,
        layout=layout,
    )
    return refined, weak


def _register_grouped(
    grouped: GroupedCmcs,
    jo: JointOutcome,
    result: FusionResult,
    ego: EgoMapData,
    weak: tuple[np.ndarray, np.ndarray],
    scene_count: dict[str, int],
    cmcs: dict[str, CmcInput],
    params: FusionParams,
) -> tuple[list[RegisteredCmc], list[AgentFit]]:
    """Each grouped camera at its pose after the joint optimisation, with its verdict, and
    its agent fit."""
    agent, agent_obs, T_final = result.agent, grouped.agent_obs, jo.T_world_cmc
    covs, cov_failures = _covariances(grouped, jo, agent)
    agent_res = reprojection_residuals(grouped.cams, T_final, agent.points, agent_obs)
    distrust_of = _distrust_by_group(grouped, jo, result, ego, weak, params)
    registered, fits = [], []
    for i, n in enumerate(grouped.names):
        own = agent_obs.camera == i
        raw = cmcs[n].tracks.camera
        fits.append(
            AgentFit(
                name=n,
                keypoint_ids=agent.ids[agent_obs.point[own]],
                observed_uv=raw.distort_pixels(agent_obs.uv[own]),
                reprojected_uv=raw.distort_pixels(agent_obs.uv[own] - agent_res[own]),
            )
        )
        rmse = reprojection_rmse(agent_res[own])
        status, reason = residual_verdict(rmse, covs[i], params, cov_failures[i])
        g = grouped.group_of[n]
        if any(distrust_of[g]):
            status, reason = WEAK, "; ".join(r for r in distrust_of[g] + [reason] if r)
        offset, sigma, note = grouped.clocks[n]
        registered.append(
            RegisteredCmc(
                name=n,
                group=g,
                method=GROUP_SFM,
                status=status,
                reason=reason,
                T_world_cam=T_final[i],
                covariance=covs[i],
                camera=raw,
                rmse_px=rmse,
                num_agent=int(own.sum()),
                num_scene=scene_count.get(n, 0),
                clock_offset_s=offset,
                clock_sigma_s=sigma,
                clock_note=note,
            )
        )
    return registered, fits


def _distrust_by_group(
    grouped: GroupedCmcs,
    jo: JointOutcome,
    result: FusionResult,
    ego: EgoMapData,
    weak: tuple[np.ndarray, np.ndarray],
    params: FusionParams,
) -> dict[str, list[str]]:
    """Why the cameras of each group with a grouped camera are not ok whatever their
    residuals (empty strings: no reason)."""
    out: dict[str, list[str]] = {}
    for n in grouped.names:
        g = grouped.group_of[n]
        if g in out:
            continue
        # The group's track against the ego map as the ego stage made it (before the joint optimisation).
        before = head_top_rms(
            grouped.agent,
            grouped.fit_chain,
            grouped.chains[g][0],
            ego.stamps_ns,
            ego.T_world_ego,
            grouped.head_offset,
            params.align.max_time_gap_s,
        )
        out[g] = [jo.failure, jo.left_out.get(g, "")] + group_distrust(
            grouped.chains[g],
            result.agent,
            grouped.fit_chain,
            ego,
            result.T_world_ego,
            result.head_offset,
            weak,
            params,
            n in grouped.disputed,
            before,
        )
    return out


def _covariances(grouped: GroupedCmcs, jo: JointOutcome, agent: AgentTrack) -> tuple[list[np.ndarray], list[str]]:
    """Each grouped camera's pose covariance and why it is unknown: the joint solution's, or
    through its agent points where the camera was not in it."""
    obs, covs, failures = grouped.agent_obs, [], []
    for i, k in enumerate(np.cumsum(jo.in_jo) - 1):
        if jo.in_jo[i]:
            covs.append(jo.result.cmc_covariances[k])
            failures.append(jo.result.covariance_failure)
            continue
        own = obs.camera == i
        cov, failure = fixed_point_covariance(
            grouped.cams[i], jo.T_world_cmc[i], agent.points[obs.point[own]], obs.uv[own], 2.0
        )
        covs.append(cov)
        failures.append(failure)
    return covs, failures


def _register_isolated_cameras(
    grouped: GroupedCmcs,
    result: FusionResult,
    ego: EgoMapData,
    weak: tuple[np.ndarray, np.ndarray],
    cmcs: dict[str, CmcInput],
    params: FusionParams,
    tracks: TrackParams,
) -> list[RegisteredCmc]:
    """Every camera not among the grouped ones, registered alone."""
    # Isolated CMCs: the optimised agent track where a group saw the agent, and elsewhere the
    # track implied by the ego trajectory (head top = T_world_ego * o, ground point under it
    # on the floor z = 0) -- an extension: the paper needs a group to have seen the agent.
    track = merge_tracks(
        result.agent,
        ego_agent_track(result.T_world_ego, ego.stamps_ns, result.head_offset),
        params.isolated.max_gap_s,
    )
    known = [c[0] for c in grouped.clocks.values() if c[0] is not None]
    groups_offset = float(np.median(known)) if known else None
    return [
        _register_isolated(
            n, why, cmcs.get(n), track, ego, result, params, tracks, weak, n in grouped.disputed, groups_offset
        )
        for n, why in sorted(grouped.failed.items())
    ]


def _register_isolated(
    name: str,
    why: str,
    cmc: CmcInput | None,
    agent: AgentTrack,
    ego: EgoMapData,
    result: FusionResult,
    params: FusionParams,
    tracks: TrackParams,
    weak: tuple[np.ndarray, np.ndarray],
    disputed: bool = False,
    groups_offset_s: float | None = None,
) -> RegisteredCmc:
    """disputed: the camera's self-consistent group contradicts the ego trajectory its
    registration now rests on (never ok); groups_offset_s: the groups' clock offset to the ego
    clock, where the clock search (params.isolated.clock_search_s) looks first."""
    if cmc is None:
        return unregistered(name, why)
    if not cmc.intrinsics_known:  # its nominal model would place it wherever its focal length says
        return unregistered(
            name,
            f"{why}; without CameraInfo or an intrinsics file it is "
            "calibrated only within a group (give them with --intrinsics)",
        )
    pnp, reason, offset = register_over_clock(cmc.tracks, agent, params.isolated, tracks, groups_offset_s)
    if pnp is None:
        return unregistered(name, f"{why}; isolated registration failed: {reason}", cmc.tracks.camera)
    searched = params.isolated.clock_search_s > 0
    T, P, uv, n_scene = _with_scene_keypoints(pnp, cmc, ego, result.landmarks, params)
    proj, _ = pnp.camera.project_world(T, P)
    rmse = reprojection_rmse(uv - proj)
    cov, cov_failure = fixed_point_covariance(pnp.camera, T, P, uv, max(rmse, 0.5))
    status, reason = residual_verdict(rmse, cov, params, cov_failure)
    # Its 3D points are the agent track, wherever no group saw it the ego trajectory's own.
    stamps = np.concatenate([t.stamps_ns for t in cmc.tracks.tracks.values()] or [np.zeros(0, np.int64)])
    stretch = ego_stretch(ego, weak, stamps, params.isolated.max_gap_s, result.T_world_ego)
    if stretch.broken(params):
        status, reason = (
            WEAK,
            "; ".join(r for r in (f"the ego map along the stretch it saw is weak ({stretch.describe()})", reason) if r),
        )
    elif disputed:
        status = WEAK
    return RegisteredCmc(
        name=name,
        group="",
        method=ISOLATED_PNP,
        status=status,
        reason="; ".join(r for r in (f"isolated: {why}", reason) if r),
        T_world_cam=T,
        covariance=cov,
        camera=cmc.tracks.camera,
        rmse_px=rmse,
        num_agent=len(pnp.points),
        num_scene=n_scene,
        # Where its clock was searched: the offset its registration fits best.
        clock_offset_s=offset if searched else None,
        clock_sigma_s=params.isolated.clock_step_s / 10 if searched else None,
        clock_note=(
            "this camera's clock minus the ego camera's, the offset its isolated registration fits best"
            if searched
            else ""
        ),
    )


def _with_scene_keypoints(
    pnp: PnpResult, cmc: CmcInput, ego: EgoMapData, landmarks: np.ndarray, params: FusionParams
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """(pose, 3D points, ideal pixels, scene matches): the agent PnP's, refined with the
    camera's scene keypoints matched to the ego map's landmarks where they match."""
    P, uv, T = pnp.points, pnp.uv, pnp.T_world_cam
    if not params.use_scene_keypoints:
        return T, P, uv, 0
    m = match_scene(cmc.background, cmc.tracks.camera, T, landmarks, ego.descriptors, ego.descriptor_type, params.scene)
    if m is None:
        return T, P, uv, 0
    P, uv = np.vstack([P, landmarks[m.landmark]]), np.vstack([uv, m.uv])
    return refine_pose(pnp.camera, T, P, uv), P, uv, len(m.landmark)


def _refuse_absurd_poses(
    registered: list[RegisteredCmc], grouped: GroupedCmcs, result: FusionResult, params: FusionParams
) -> list[RegisteredCmc]:
    # The agent points each grouped camera observed (an isolated one's PnP had them in front).
    obs = grouped.agent_obs
    seen = {n: result.agent.points[obs.point[obs.camera == i]] for i, n in enumerate(grouped.names)}
    ceilings = [p for p in (result.layout.planes if result.layout is not None else []) if p.kind == KIND_CEILING]
    return [refuse_absurd(r, seen.get(r.name, np.zeros((0, 3))), params, ceilings) for r in registered]
