"""The grouped cameras in the world, ready for the joint optimisation: each group's track on
the ego clock, the rig's head offset from the groups that fit the ego trajectory (a
self-consistent group on a broken map aligned on its best window instead), each group
aligned with that offset, and the agent points and their observations (with the head tops
one camera alone saw, where single_view_head_tops)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from yowo_cmc.group_sfm import CameraGroupResult
from yowo_cmc.keypoint_tracks import CameraTracks, TrackParams, resample
from yowo_common.bundle import Observations
from yowo_common.camera import CameraModel
from yowo_common.geometry import Sim3

from .alignment import (
    align_to_world,
    head_offset_estimate,
    head_tops,
    interpolate_positions,
    on_ego_clock,
    put_on_floor,
    weighted_median,
    window_alignment,
)
from .config import FusionParams
from .joint import TOP
from .records import AgentTrack, CmcInput, EgoMapData
from .verdict import GROUP, blame, ego_stretch


@dataclass(kw_only=True)
class GroupedCmcs:
    """The grouped cameras, each group aligned to the world, and their agent observations
    (points: every group's local track moved by its alignment; chain: the group of each)."""

    names: list[str]
    cams: list[CameraModel]  # ideal pinhole (undistorted)
    T_init: list[np.ndarray]  # T_world_cam from the group's alignment
    group_of: dict[str, str]
    agent: AgentTrack
    agent_obs: Observations
    agent_chain: np.ndarray
    agent_single: np.ndarray  # (K,) a head top one camera saw (single_view_head_tops)
    head_offset: np.ndarray
    alignments: dict[str, Sim3]
    failed: dict[str, str]  # camera -> why it is not among the grouped ones
    clocks: dict[str, tuple[float | None, float | None, str]]  # camera -> its clock - the ego's, sigma, note
    chains: dict[str, tuple[int, CameraGroupResult]]  # group -> its agent_chain value and the group (ego clock)
    disputed: set[str]  # cameras of a self-consistent group the ego stage's trajectory contradicts

    @property
    def fit_chain(self) -> np.ndarray:
        """agent_chain with the single-view head tops in none: where they lie along their ray
        follows the ego trajectory, so they say nothing of how a group's track fits it."""
        return np.where(self.agent_single, -1, self.agent_chain)


def gather_groups(
    ego: EgoMapData,
    groups: list[CameraGroupResult],
    ungrouped: dict[str, str],
    cmcs: dict[str, CmcInput],
    params: FusionParams,
    weak: tuple[np.ndarray, np.ndarray],
    tracks: TrackParams,
) -> GroupedCmcs:
    """Every group that can be aligned, with its cameras and their observations of its agent
    points; the cameras of the others (and the ungrouped ones) in GroupedCmcs.failed."""
    failed: dict[str, str] = dict(ungrouped)
    groups, ego_shift, clocks = on_ego_clock(groups, ego, params.align)
    estimates, rescued, distrusted = _first_alignments(groups, ego, weak, params, failed)
    head_offset = (
        weighted_median(
            np.array([o for o, _ in estimates.values()]), np.array([w for _, w in estimates.values()], float)
        )
        if estimates
        else np.zeros(3)
    )
    heads = head_tops(ego.T_world_ego, head_offset)
    gathering = _Gathering(cmcs, params, tracks, failed)
    alignments, chains = {}, {}
    for gi, g in enumerate(groups):
        if g.group_id not in estimates and g.group_id not in rescued:
            continue
        S = alignments[g.group_id] = (
            rescued[g.group_id] if g.group_id in rescued else align_to_world(g, ego, params.align, head_offset)
        )
        chains[g.group_id] = (gi, g)
        single = gathering.add_group(gi, g, S, ego_shift[g.group_id])
        if params.single_view_head_tops:
            gathering.add_single_view_head_tops(gi, single, ego.stamps_ns, heads)
    return gathering.grouped(
        head_offset=head_offset, alignments=alignments, clocks=clocks, chains=chains, disputed=distrusted
    )


def _first_alignments(
    groups: list[CameraGroupResult],
    ego: EgoMapData,
    weak: tuple[np.ndarray, np.ndarray],
    params: FusionParams,
    failed: dict[str, str],
) -> tuple[dict[str, tuple[np.ndarray, int]], dict[str, Sim3], set[str]]:
    """(estimates, rescued, distrusted): each group's head offset and weight where its track
    fits the ego trajectory; where it does not, a group not at fault itself aligned on its
    best window (its cameras distrusted), or else its cameras failed (distrusted too unless
    the group is at fault)."""
    estimates, rescued, distrusted = {}, {}, set()
    for g in groups:
        try:
            estimates[g.group_id] = head_offset_estimate(g, ego, params.align)
        except ValueError as exc:
            fault, why = blame(g, ego_stretch(ego, weak, g.point_stamps_ns, params.align.max_time_gap_s), params)
            al = (
                window_alignment(g, ego, params.align, params.rescue_window_s)
                if fault != GROUP and params.rescue_window_s > 0
                else None
            )
            if al is not None and al.rms_m <= params.ok_track_rms_m:
                rescued[g.group_id] = put_on_floor(al.sim3_world_local, g)
                distrusted.update(g.names)
                continue
            failed.update(
                {n: f"group {g.group_id} could not be aligned to the ego trajectory: {exc}: {why}" for n in g.names}
            )
            distrusted.update(g.names if fault != GROUP else [])
    return estimates, rescued, distrusted


class _Gathering:
    """What gather_groups collects group by group: the cameras, the agent points (a group's
    track moved to the world, then its single-view head tops) and their observations."""

    def __init__(self, cmcs: dict[str, CmcInput], params: FusionParams, tracks: TrackParams, failed: dict[str, str]):
        self.cmcs, self.params, self.tracks, self.failed = cmcs, params, tracks, failed
        self.names, self.cams, self.T_init, self.group_of = [], [], [], {}
        self.points, self.stamps_ns, self.ids, self.chain, self.single = [], [], [], [], []
        self.obs_camera, self.obs_point, self.obs_uv, self.obs_sigma = [], [], [], []

    def add_points(self, points: np.ndarray, stamps_ns: np.ndarray, ids: np.ndarray, chain: int, single: bool):
        self.points.append(points)
        self.stamps_ns.append(stamps_ns)
        self.ids.append(ids)
        self.chain.append(np.full(len(points), chain))
        self.single.append(np.full(len(points), single))

    def observe(self, camera: int, point: int, uv: np.ndarray, sigma_px: float) -> None:
        self.obs_camera.append(camera)
        self.obs_point.append(point)
        self.obs_uv.append(uv)
        self.obs_sigma.append(sigma_px)

    def add_group(self, chain: int, g: CameraGroupResult, S: Sim3, ego_shift_s: float) -> list:
        """The group's track moved to the world by S, and its members' observations of it;
        returns the head tops one member alone saw, (camera, stamp, uv, sigma) each."""
        base = sum(len(p) for p in self.points)
        self.add_points(S.apply(g.points), g.point_stamps_ns, g.point_ids, chain, False)
        key = {(int(s), int(i)): base + k for k, (s, i) in enumerate(zip(g.point_stamps_ns, g.point_ids))}
        stamps = np.unique(g.point_stamps_ns)
        lone_tops: dict[int, list] = {}  # stamp index -> (camera, uv, sigma) of untriangulated head tops
        lone_own: list = []  # (camera, stamp, uv, sigma) where the group has no point
        for n in g.names:
            if n not in self.cmcs:
                self.failed[n] = "no keypoints received for this camera"
                continue
            # The member's stamps onto the clock of the group's points (the ego's); once per
            # stamp (point_stamps_ns repeats a stamp for every keypoint id triangulated there).
            shifted = self.cmcs[n].tracks.shifted(g.clock_offsets_s.get(n, 0.0) + ego_shift_s)
            lone_own += self._add_member(n, g, S, shifted, stamps, key, lone_tops)
        # Seen by one member only (two that saw it and were not triangulated disagree).
        return [
            (ci, int(stamps[k]), uv, sigma_px)
            for k, seen in sorted(lone_tops.items())
            if len(seen) == 1
            for ci, uv, sigma_px in seen
        ] + lone_own

    def _add_member(
        self,
        n: str,
        g: CameraGroupResult,
        S: Sim3,
        shifted: CameraTracks,
        stamps: np.ndarray,
        key: dict[tuple[int, int], int],
        lone_tops: dict[int, list],
    ) -> list:
        """Camera n of group g at its pose from S, and its observations of the group's points
        (key: (stamp, keypoint id) -> point) at the group's stamps; a head top it saw at one of
        them that the group has no point for goes to lone_tops. Returns those it saw at its own
        stamps where the group has none, (camera, stamp, uv, sigma) each."""
        # Its own head-top stamps where the group has no point (single_view_head_tops).
        own = (
            _away_from(shifted.tracks[TOP].stamps_ns, stamps)
            if self.params.single_view_head_tops and TOP in shifted.tracks
            else np.zeros(0, np.int64)
        )
        ideal, samples = resample(shifted, np.concatenate([stamps, own]), self.tracks)
        ci = len(self.names)
        self.names.append(n)
        self.cams.append(ideal)
        self.T_init.append(S.transform_pose(g.T_local_cam[n]))
        self.group_of[n] = g.group_id
        sigma = {i: g.sigma_px_by_id.get(i, self.params.joint.ego_sigma_px * 1.5) for i in samples}
        lone_own = []
        if len(own):
            uv, ok = samples[TOP]
            lone_own = [(ci, int(s), uv[len(stamps) + k], sigma[TOP]) for k, s in enumerate(own) if ok[len(stamps) + k]]
        samples = {i: (uv[: len(stamps)], ok[: len(stamps)]) for i, (uv, ok) in samples.items()}
        for kp_id, (uv, ok) in samples.items():
            for k in np.flatnonzero(ok):
                j = key.get((int(stamps[k]), kp_id))
                if j is not None:
                    self.observe(ci, j, uv[k], sigma[kp_id])
                elif kp_id == TOP:
                    lone_tops.setdefault(int(k), []).append((ci, uv[k], sigma[kp_id]))
        return lone_own

    def add_single_view_head_tops(self, chain: int, single: list, ego_stamps_ns: np.ndarray, heads: np.ndarray):
        """Each head top in `single` as an agent point of its own, started at the head top the
        ego trajectory predicts (heads, per ego frame) at its stamp."""
        at = np.array([s for _, s, _, _ in single], np.int64)
        predicted, near = interpolate_positions(ego_stamps_ns, heads, at, int(self.params.align.max_time_gap_s * 1e9))
        base = sum(len(p) for p in self.points)
        for n, (ci, _, uv, sigma_px) in enumerate(x for x, k in zip(single, near) if k):
            self.observe(ci, base + n, uv, sigma_px)
        self.add_points(predicted[near], at[near], np.full(int(near.sum()), TOP), chain, True)

    def grouped(self, **rest) -> GroupedCmcs:
        """What was gathered, with the rest of GroupedCmcs' fields."""
        return GroupedCmcs(
            names=self.names,
            cams=self.cams,
            T_init=self.T_init,
            group_of=self.group_of,
            agent=AgentTrack(
                np.concatenate(self.stamps_ns or [np.zeros(0, np.int64)]),
                np.concatenate(self.ids or [np.zeros(0, int)]),
                np.vstack(self.points or [np.zeros((0, 3))]),
            ),
            agent_obs=Observations(
                np.array(self.obs_camera, int),
                np.array(self.obs_point, int),
                np.array(self.obs_uv).reshape(-1, 2),
                np.array(self.obs_sigma),
            ),
            agent_chain=np.concatenate(self.chain or [np.zeros(0, int)]),
            agent_single=np.concatenate(self.single or [np.zeros(0, bool)]),
            failed=self.failed,
            **rest,
        )


def _away_from(query_ns: np.ndarray, grid_ns: np.ndarray) -> np.ndarray:
    """The query stamps further than half the grid's step from every grid stamp (all of
    them when the grid has fewer than two)."""
    if len(grid_ns) < 2:
        return np.asarray(query_ns, np.int64)
    half = np.median(np.diff(grid_ns)) / 2
    i = np.clip(np.searchsorted(grid_ns, query_ns), 1, len(grid_ns) - 1)
    return query_ns[np.minimum(np.abs(query_ns - grid_ns[i - 1]), np.abs(grid_ns[i] - query_ns)) > half]
