"""Collaborative processing end to end (paper "Collaborative Processing" and
"Register 6-DoF Poses for Isolated CMCs"): groups -> world by rebalanced Umeyama,
scene keypoints with pose priors, joint optimisation, isolated CMCs, covariances
and a verdict per camera; the ego map's cloud and layout refined with the jointly
optimised ego poses."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from yowo_cmc.group_sfm import CameraGroupResult
from yowo_cmc.intrinsics import EstimatedCamera
from yowo_cmc.keypoint_tracks import CameraTracks, TrackParams, resample
from yowo_common.bundle import Observations, pose_covariance, reprojection_residuals
from yowo_common.camera import CameraModel
from yowo_common.geometry import Sim3, inv_se3, transform_points
from yowo_ego.layout import KIND_CEILING, Layout, LayoutParams, LayoutPlane
from yowo_ego.scene import CloudParams

from .alignment import AlignParams, ClockFit, align_group, estimate_clock_offset, interpolate_positions
from .isolated import AgentTrack, IsolatedParams, refine_pose, register_over_clock
from .joint import (
    TOP,
    UNKNOWN_COVARIANCE,
    JointParams,
    JointProblem,
    JointResult,
    covariance_unavailable,
    ros_covariance,
    solve_joint,
    solver_failure,
)
from .refined_map import move_cloud, rebuild_layout
from .scene_matching import SceneMatchParams, match_scene

GROUP_SFM, ISOLATED_PNP, NONE = "group_sfm", "isolated_pnp", "none"
OK, WEAK, FAILED = "ok", "weak", "failed"


@dataclass
class EgoMapData:
    camera: CameraModel  # ego intrinsics with distortion
    stamps_ns: np.ndarray  # (F,)
    T_world_ego: np.ndarray  # (F, 4, 4)
    landmarks: np.ndarray  # (P, 3)
    descriptor_type: str
    descriptors: np.ndarray  # (P, D) uint8
    obs_pose: np.ndarray  # (M,)
    obs_landmark: np.ndarray  # (M,)
    obs_uv: np.ndarray  # (M, 2) raw pixels
    cloud_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) world
    cloud_colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) in [0, 1]
    layout: Layout | None = None  # the ego stage's layout of that cloud
    # (F,) per frame: tracked by vision (dense odometry or placed in the map; not a guess or a
    # gyro bridge), and its overlap; None: the ego stage did not say
    tracking_measured: np.ndarray | None = None
    tracking_fitness: np.ndarray | None = None
    imu: bool = False  # the ego stage tracked with the gyro's rotation between frames
    # (F,) the ego stage held the frame's attitude to the building (its walls and floor); None: not said
    attitude_held: np.ndarray | None = None


@dataclass
class CmcInput:
    tracks: CameraTracks  # raw keypoints + camera model with distortion
    background: np.ndarray | None = None  # agent-free RGB image, for scene keypoints
    intrinsics_known: bool = True  # False: the camera model is a nominal one its group SfM estimates


@dataclass
class RegisteredCmc:
    name: str
    group: str
    method: str
    status: str
    reason: str
    T_world_cam: np.ndarray | None
    covariance: np.ndarray | None  # 6x6 ROS order (x, y, z, rx, ry, rz), world frame; NaN: unknown
    camera: CameraModel | None  # the intrinsics (with distortion) used; None: no CameraInfo arrived
    rmse_px: float
    num_agent: int
    num_scene: int
    # The camera's clock - the ego clock [s] and its sigma (None: not estimated, see clock_note).
    clock_offset_s: float | None = None
    clock_sigma_s: float | None = None
    clock_note: str = ""

    @property
    def K(self) -> np.ndarray:
        return self.camera.K if self.camera is not None else np.zeros((3, 3))


@dataclass
class AgentFit:
    """The fused agent track against one grouped CMC's observations, in its raw pixels
    (what the report draws over the camera's background)."""

    name: str
    keypoint_ids: np.ndarray  # (M,)
    observed_uv: np.ndarray  # (M, 2)
    reprojected_uv: np.ndarray  # (M, 2), NaN behind the camera


@dataclass(frozen=True)
class UpstreamParams:
    """Settings of other stages that the fusion applies again to their data. They are not the
    fusion's section: each lives in the tree once, where its stage reads it (UPSTREAM_HOMES;
    the node gets each in a parameter of the field's name): how the group SfM cleans the
    CMC keypoint tracks (cmc.sfm.tracks) and how the ego stage builds its cloud and layout
    (ego.cloud, ego.layout), which the fusion rebuilds at the jointly optimised poses."""

    tracks: TrackParams = TrackParams()
    cloud: CloudParams = CloudParams()
    layout: LayoutParams = LayoutParams()


# Where each of UpstreamParams' fields lives in the configuration tree.
UPSTREAM_HOMES = {"tracks": "cmc.sfm.tracks", "cloud": "ego.cloud", "layout": "ego.layout"}


@dataclass(frozen=True)
class FusionParams:
    align: AlignParams = AlignParams()
    joint: JointParams = JointParams()
    scene: SceneMatchParams = SceneMatchParams()
    isolated: IsolatedParams = IsolatedParams()
    use_scene_keypoints: bool = True
    joint_optimisation: bool = True  # False: ablation "without joint optimisation"
    ok_rmse_px: float = 3.0
    ok_position_sigma_m: float = 0.10
    # Where the ego map is not to be trusted (weak_ego_frames): frames tracked from a keyframe
    # with fewer landmark observations than this (its BA had next to nothing: bare walls, dark)
    # and, where the ego stage says how it tracked, with less overlap than weak_tracking_fitness
    # (depth tracks a bare wall well; a low-overlap step in the dark goes wrong). Registration
    # [m] at 0.65 / 0.5: small texture_poor s0-s2 with IMU 0.084 / 0.048, 0.078 / 0.052,
    # 0.230 / 0.066; s0 without 0.076 / 0.064; dim_light s1 without 0.111 / 0.145...
    weak_keyframe_landmarks: int = 20
    weak_tracking_fitness: float = 0.5
    # With an ego IMU the gyro measured each step's rotation: only a step with less overlap than
    # this is weak (a loose step let a two-camera group bend a good map: small texture_poor s2
    # with IMU, registration 0.104 m at 0.5, 0.034 at 0.4; without the IMU, 0.4 broke s1).
    weak_tracking_fitness_imu: float = 0.4
    # ...or after a gap in its frames longer than this (lost track, rejected frames).
    weak_frame_gap_s: float = 0.3
    # A camera whose registration rests on a stretch of the ego map with more weak frames
    # than this share is never ok (nor one whose stretch holds a gap).
    ok_weak_share: float = 0.2
    # ...nor one whose stretch the joint optimisation moved by more than this (RMS over its ego
    # positions; the map's first pose stays): the ego stage's map was that far off there, and
    # what put it back (agent tracks, the chain of steps from the nearest of them) is not checked
    # by anything else. Small texture_poor s1 / s2 without the IMU: stretches moved 0.16-1.1 m
    # held `ok` cameras 0.12-0.17 m off; dim_light s1 without the IMU 0.10 / 0.14 m (cameras
    # 0.015-0.10 m off); the other 16 hard small runs, with the IMU or without, at most 0.08 m.
    ok_map_moved_m: float = 0.10
    # A registered pose this far below the floor or above a ceiling over it [m], or whose image
    # up points below the horizontal by more than this cosine (upside down), is refused.
    absurd_margin_m: float = 0.5
    max_upside_down_cos: float = 0.5
    # A group's head-top track and the head top the ego trajectory predicts differ by more than
    # this (RMS): one of the two is wrong. After the joint optimisation it says so; before it
    # (the group as aligned, the ego map as the ego stage made it) the joint optimisation had to
    # reconcile the two, and which one it bent is not known: never ok either.
    ok_track_rms_m: float = 0.10
    # A self-consistent group that does not fit a broken ego map as a whole is aligned on
    # the stretch of this many seconds of its walk that fits best (one piece of the map),
    # and the joint optimisation fits the other pieces to its track; 0: such a group's
    # cameras are registered one by one.
    rescue_window_s: float = 6.0
    # A joint solution is kept only if every group's head-top track fits its ego trajectory
    # within this (RMS); the worst group beyond it is left out and the rest solved again. A
    # map bent where no agent track holds it leaves ~0.5 m (small symmetric s0 without IMU:
    # cameras 0.28 -> 1.3 m off); the frames beside a repaired break can stay off by more
    # than ok_track_rms_m (test world, 1.5 m / 40 deg break: 0.24 m, cameras within 5 cm).
    max_unexplained_track_rms_m: float = 0.3
    # Joint solves at most (each leaves one more such group out; a floor's solve takes minutes).
    max_joint_solves: int = 3
    # A head top only one camera of a group saw at a stamp cannot be triangulated, yet with the
    # head top the ego trajectory predicts it anchors the map across that camera's ray: such an
    # observation enters the joint optimisation as an agent point of its own (started at the
    # predicted head top). Our addition: the paper's agent points are the groups' triangulated ones.
    single_view_head_tops: bool = True


@dataclass
class FusionResult:
    cameras: list[RegisteredCmc]
    T_world_ego: np.ndarray
    landmarks: np.ndarray
    agent: AgentTrack
    head_offset: np.ndarray
    point_cloud: np.ndarray  # (N, 3) the ego map's cloud at the refined ego poses
    point_colors: np.ndarray  # (N, 3) in [0, 1]
    layout: Layout | None  # rebuilt from point_cloud (the ego stage's without JO)
    alignments: dict[str, Sim3] = field(default_factory=dict)
    agent_fits: list[AgentFit] = field(default_factory=list)


def _head_offset(alignment: Sim3, top_stamps, top_local, ego: EgoMapData, max_gap_ns: int) -> np.ndarray:
    """Initial rigid head-top offset in the ego camera frame: median of R_f^T (A - t_f)."""
    A = alignment.apply(top_local)
    f = np.clip(np.searchsorted(ego.stamps_ns, top_stamps), 0, len(ego.stamps_ns) - 1)
    close = np.abs(ego.stamps_ns[f] - top_stamps) <= max_gap_ns
    T = ego.T_world_ego[f[close]]
    local = np.einsum("nji,nj->ni", T[:, :3, :3], A[close] - T[:, :3, 3])
    return np.median(local, axis=0) if len(local) else np.zeros(3)


def _on_floor(S: Sim3, group: CameraGroupResult) -> Sim3:
    """Shift vertically so the agent's ground points lie on the ego map's floor (z = 0):
    the head-top/camera offset is mostly vertical and the Umeyama fit absorbs it."""
    bottom = group.point_ids == 1
    if bottom.sum() < 3:
        return S
    dz = float(np.median(S.apply(group.points[bottom])[:, 2]))
    return Sim3(S.s, S.R, S.t - [0.0, 0.0, dz])


def _group_tracks(group: CameraGroupResult, params: AlignParams):
    top, bottom = group.point_ids == 0, group.point_ids == 1
    ground = (group.point_stamps_ns[bottom], group.points[bottom]) if params.use_ground_points else (None, None)
    return group.point_stamps_ns[top], group.points[top], ground


def head_offset_estimate(group: CameraGroupResult, ego: EgoMapData, params: AlignParams) -> tuple[np.ndarray, int]:
    """First pass: rebalanced Umeyama of the head-top track against the ego camera
    positions, put on the floor; the head offset it implies and its weight (the number
    of spatiotemporal clusters: how much of the walk the group saw). ValueError when the
    group does not fit the ego trajectory (its cameras are then registered one by one)."""
    stamps, local, ground = _group_tracks(group, params)
    al = align_group(stamps, local, ego.stamps_ns, ego.T_world_ego[:, :3, 3], params, *ground)
    if al.rms_m > params.max_rms_m:
        raise ValueError(
            f"its agent track does not fit the ego trajectory (RMS {al.rms_m:.2f} m > {params.max_rms_m:g} m)"
        )
    return _head_offset(
        _on_floor(al.sim3_world_local, group), stamps, local, ego, int(params.max_time_gap_s * 1e9)
    ), al.num_clusters


def head_tops(T_world_ego: np.ndarray, head_offset: np.ndarray) -> np.ndarray:
    """(F, 3) the head top each ego pose predicts: the ego camera's pose applied to the offset."""
    return np.einsum("nij,j->ni", T_world_ego[:, :3, :3], head_offset) + T_world_ego[:, :3, 3]


def align_to_world(group: CameraGroupResult, ego: EgoMapData, params: AlignParams, head_offset: np.ndarray) -> Sim3:
    """Rebalanced Umeyama against the head top predicted from the ego poses with the
    rig's head offset (one for all groups: a group that saw a short stretch of the walk
    estimates it badly on its own)."""
    stamps, local, ground = _group_tracks(group, params)
    return align_group(
        stamps, local, ego.stamps_ns, head_tops(ego.T_world_ego, head_offset), params, *ground
    ).sim3_world_local


def weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per column: the value where the cumulative weight reaches half (robust to a group's outlier)."""
    out = []
    for column in np.atleast_2d(values).T:
        order = np.argsort(column)
        cum = np.cumsum(weights[order])
        out.append(column[order][np.searchsorted(cum, 0.5 * cum[-1])])
    return np.array(out)


def weak_ego_frames(ego: EgoMapData, params: FusionParams) -> tuple[np.ndarray, np.ndarray]:
    """(weak, gap), each (F,): frame f's motion from frame f-1 is not to be trusted (weak:
    tracked from a keyframe with fewer than weak_keyframe_landmarks landmark observations,
    and, where the ego stage says how each frame was tracked, with an overlap below
    weak_tracking_fitness, or not by vision at all; or after a gap), and gap: more than
    weak_frame_gap_s after frame f-1 (the ego map lost track or rejected frames there; what
    joins the two sides is a guess). A map without any landmark observations (a trajectory
    alone) is judged by its gaps (and tracking) only. In a well-lit bare room every keyframe
    has few landmarks while depth tracks it to centimetres: by landmarks alone the joint
    optimisation let the agent track shape the whole map (small texture_poor s0: cameras
    1.0 m off, 0.05 m with the tracking's overlap)."""
    n = len(ego.stamps_ns)
    gap = np.zeros(n, bool)
    gap[1:] = np.diff(ego.stamps_ns) > params.weak_frame_gap_s * 1e9
    weak = gap.copy()
    counts = np.bincount(ego.obs_pose.astype(int), minlength=n)[:n]
    keyframes = np.flatnonzero(counts)
    if len(keyframes):
        last = np.searchsorted(keyframes, np.arange(n), side="right") - 1
        few = np.where(last >= 0, counts[keyframes[np.maximum(last, 0)]], 0) < params.weak_keyframe_landmarks
        if ego.tracking_fitness is not None:
            few &= ego.tracking_fitness < (
                params.weak_tracking_fitness_imu if ego.imu else params.weak_tracking_fitness
            )
        weak |= few
    if ego.tracking_measured is not None:
        weak |= ~ego.tracking_measured
    weak[0] = False
    return weak, gap


@dataclass
class EgoStretch:
    """The ego map along the stretch of the walk (first to last frame) a camera's
    registration rests on: its share of weak frames, and the gaps from the map's first
    frame (the world's origin) to the stretch's end: the stretch's place in the world rests
    on every join before it."""

    frames: int
    weak_share: float
    gaps: int
    moved_m: float = 0.0  # how far the joint optimisation moved it (RMS)

    def broken(self, params: FusionParams) -> bool:
        return self.gaps > 0 or self.weak_share > params.ok_weak_share or self.moved_m > params.ok_map_moved_m

    def describe(self) -> str:
        parts = (
            [
                f"{100 * self.weak_share:.0f} % of its {self.frames} frames tracked from keyframes with next to "
                "no landmarks"
            ]
            if self.weak_share >= 0.005
            else []
        )
        if self.gaps:
            parts.append(
                f"{self.gaps} break(s) up to the stretch's end (gaps in its frames, steps the joint "
                "optimisation found broken)"
            )
        if self.moved_m >= 0.01:
            parts.append(f"the joint optimisation moved it by {self.moved_m:.2f} m RMS")
        return ", ".join(parts) or f"its {self.frames} frames well tracked"


def ego_stretch(
    ego: EgoMapData,
    weak: tuple[np.ndarray, np.ndarray],
    stamps_ns: np.ndarray,
    max_gap_s: float,
    T_world_ego_joint: np.ndarray | None = None,
) -> EgoStretch:
    """The ego frames between the first and last of `stamps_ns` that fall in the recording;
    with the joint optimisation's trajectory, how far it moved them."""
    f = np.clip(np.searchsorted(ego.stamps_ns, stamps_ns), 0, len(ego.stamps_ns) - 1)
    f = f[np.abs(ego.stamps_ns[f] - stamps_ns) <= max_gap_s * 1e9]
    if not len(f):
        return EgoStretch(0, 0.0, 0)
    lo, hi = int(f.min()), int(f.max())
    moved = 0.0
    if T_world_ego_joint is not None:
        d = T_world_ego_joint[lo : hi + 1, :3, 3] - ego.T_world_ego[lo : hi + 1, :3, 3]
        moved = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    return EgoStretch(
        hi - lo + 1, float(weak[0][lo + 1 : hi + 1].mean()) if hi > lo else 0.0, int(weak[1][: hi + 1].sum()), moved
    )


EGO_MAP, GROUP, UNDECIDED = "ego map", "group", "undecided"


def blame(group: CameraGroupResult, stretch: EgoStretch, params: FusionParams) -> tuple[str, str]:
    """Which of the two is wrong when a group's agent track and the ego trajectory disagree:
    the group's own reprojection residuals against the ego map's tracking along the
    stretch the group saw. (EGO_MAP, GROUP or UNDECIDED, why)"""
    worst = max(group.rmse_px.values(), default=float("nan"))
    if not (np.isfinite(worst) and worst <= params.ok_rmse_px):
        return GROUP, f"the group's reconstruction is at fault (its reprojection RMSE reaches {worst:.2f} px)"
    own = f"the group is self-consistent (reprojection RMSE <= {worst:.2f} px)"
    if stretch.broken(params):
        return EGO_MAP, f"the ego map is at fault ({stretch.describe()}); {own}"
    # The ego map can break without a sign in what it publishes (a lost track joined by a
    # guessed step): a self-consistent group against it is not to be trusted either way.
    return UNDECIDED, (
        f"undecided: {own} and the ego map shows no weak tracking there ({stretch.describe()}), "
        "though it may have broken unseen"
    )


def window_alignment(group: CameraGroupResult, ego: EgoMapData, params: AlignParams, window_s: float):
    """The group's alignment on the window_s of its walk that fits the ego trajectory best
    (where the ego map broke: one of its pieces), or None."""
    stamps, local, (g_ns, g_local) = _group_tracks(group, params)
    best, span = None, int(window_s * 1e9)
    if not len(stamps):
        return None
    for t0 in range(int(stamps.min()), max(int(stamps.max()) - span, int(stamps.min())) + 1, 10**9):
        sel = (stamps >= t0) & (stamps < t0 + span)
        ground = (
            (None, None)
            if g_ns is None
            else (g_ns[(g_ns >= t0) & (g_ns < t0 + span)], g_local[(g_ns >= t0) & (g_ns < t0 + span)])
        )
        try:
            al = align_group(stamps[sel], local[sel], ego.stamps_ns, ego.T_world_ego[:, :3, 3], params, *ground)
        except ValueError:
            continue
        if best is None or al.rms_m < best.rms_m:
            best = al
    return best


def head_top_rms(
    agent: AgentTrack,
    chain: np.ndarray,
    c: int,
    ego_stamps_ns: np.ndarray,
    T_world_ego: np.ndarray,
    head_offset: np.ndarray,
    max_gap_s: float,
) -> float:
    """RMS distance between a group's head-top points and the head top the ego trajectory
    predicts at their stamps."""
    sel = (chain == c) & (agent.ids == 0)
    predicted, ok = interpolate_positions(
        ego_stamps_ns, head_tops(T_world_ego, head_offset), agent.stamps_ns[sel], int(max_gap_s * 1e9)
    )
    d = np.linalg.norm(agent.points[sel][ok] - predicted[ok], axis=1)
    return float(np.sqrt(np.mean(d**2))) if len(d) else float("nan")


def _verdict(rmse: float, cov: np.ndarray, params: FusionParams, cov_failure: str = "") -> tuple[str, str]:
    reasons = [cov_failure] if cov_failure else []
    if not np.isfinite(rmse) or rmse > params.ok_rmse_px:
        reasons.append(f"reprojection RMSE {rmse:.2f} px > {params.ok_rmse_px:g} px")
    if not cov_failure:
        sigma = float(np.sqrt(np.linalg.eigvalsh(cov[:3, :3]).max()))
        if sigma > params.ok_position_sigma_m:
            reasons.append(f"position sigma {sigma:.3f} m > {params.ok_position_sigma_m:g} m")
    return (WEAK, "; ".join(reasons)) if reasons else (OK, "")


def _covariance(
    camera: CameraModel, T: np.ndarray, points: np.ndarray, uv: np.ndarray, sigma_px: float
) -> tuple[np.ndarray, str]:
    """One camera's pose covariance through fixed points, or unknown and why (degenerate geometry)."""
    try:
        return ros_covariance(pose_covariance(camera, T, points, uv, sigma_px), T[:3, :3]), ""
    except RuntimeError as exc:
        return UNKNOWN_COVARIANCE, covariance_unavailable(exc)


def _rmse(res: np.ndarray) -> float:
    r = res[np.isfinite(res).all(axis=1)]
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")


@dataclass
class _GroupedCmcs:
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


def _gather_groups(
    ego: EgoMapData,
    groups: list[CameraGroupResult],
    ungrouped: dict[str, str],
    cmcs: dict[str, CmcInput],
    params: FusionParams,
    weak: tuple[np.ndarray, np.ndarray],
    tracks: TrackParams,
) -> _GroupedCmcs:
    names, cams, T_init, group_of = [], [], [], {}
    agent_pts, agent_ns, agent_ids, agent_chain, agent_single = [], [], [], [], []
    c_idx, p_idx, uv_obs, sig_obs = [], [], [], []
    alignments, chains = {}, {}
    failed: dict[str, str] = dict(ungrouped)
    groups, ego_shift, clocks = _on_ego_clock(groups, ego, params.align)
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
                rescued[g.group_id] = _on_floor(al.sim3_world_local, g)
                distrusted.update(g.names)
                continue
            failed.update(
                {n: f"group {g.group_id} could not be aligned to the ego trajectory: {exc}: {why}" for n in g.names}
            )
            distrusted.update(g.names if fault != GROUP else [])
    head_offset = (
        weighted_median(
            np.array([o for o, _ in estimates.values()]), np.array([w for _, w in estimates.values()], float)
        )
        if estimates
        else np.zeros(3)
    )
    heads = head_tops(ego.T_world_ego, head_offset)
    for gi, g in enumerate(groups):
        if g.group_id not in estimates and g.group_id not in rescued:
            continue
        S = alignments[g.group_id] = (
            rescued[g.group_id] if g.group_id in rescued else align_to_world(g, ego, params.align, head_offset)
        )
        chains[g.group_id] = (gi, g)
        base = sum(len(p) for p in agent_pts)
        agent_pts.append(S.apply(g.points))
        agent_ns.append(g.point_stamps_ns)
        agent_ids.append(g.point_ids)
        agent_chain.append(np.full(len(g.points), gi))
        agent_single.append(np.zeros(len(g.points), bool))
        key = {(int(s), int(i)): base + k for k, (s, i) in enumerate(zip(g.point_stamps_ns, g.point_ids))}
        stamps = np.unique(g.point_stamps_ns)
        lone_tops: dict[int, list] = {}  # stamp index -> (camera, uv, sigma) of untriangulated head tops
        lone_own: list = []  # (camera, stamp, uv, sigma) where the group has no point
        for n in g.names:
            if n not in cmcs:
                failed[n] = "no keypoints received for this camera"
                continue
            # The member's stamps onto the clock of the group's points (the ego's); once per
            # stamp (point_stamps_ns repeats a stamp for every keypoint id triangulated there).
            shifted = cmcs[n].tracks.shifted(g.clock_offsets_s.get(n, 0.0) + ego_shift[g.group_id])
            # Its own head-top stamps where the group has no point (single_view_head_tops).
            own = (
                _away_from(shifted.tracks[TOP].stamps_ns, stamps)
                if params.single_view_head_tops and TOP in shifted.tracks
                else np.zeros(0, np.int64)
            )
            ideal, samples = resample(shifted, np.concatenate([stamps, own]), tracks)
            ci = len(names)
            names.append(n)
            cams.append(ideal)
            T_init.append(S.transform_pose(g.T_local_cam[n]))
            group_of[n] = g.group_id
            sigma = {i: g.sigma_px_by_id.get(i, params.joint.ego_sigma_px * 1.5) for i in samples}
            if len(own):
                uv, ok = samples[TOP]
                lone_own += [
                    (ci, int(s), uv[len(stamps) + k], sigma[TOP]) for k, s in enumerate(own) if ok[len(stamps) + k]
                ]
            samples = {i: (uv[: len(stamps)], ok[: len(stamps)]) for i, (uv, ok) in samples.items()}
            for kp_id, (uv, ok) in samples.items():
                for k in np.flatnonzero(ok):
                    j = key.get((int(stamps[k]), kp_id))
                    if j is not None:
                        c_idx.append(ci)
                        p_idx.append(j)
                        uv_obs.append(uv[k])
                        sig_obs.append(sigma[kp_id])
                    elif kp_id == TOP:
                        lone_tops.setdefault(int(k), []).append((ci, uv[k], sigma[kp_id]))
        if params.single_view_head_tops:
            # Seen by one member only (two that saw it and were not triangulated disagree).
            single = [
                (ci, int(stamps[k]), uv, sigma_px)
                for k, seen in sorted(lone_tops.items())
                if len(seen) == 1
                for ci, uv, sigma_px in seen
            ] + lone_own
            at = np.array([s for _, s, _, _ in single], np.int64)
            predicted, near = interpolate_positions(ego.stamps_ns, heads, at, int(params.align.max_time_gap_s * 1e9))
            base = sum(len(p) for p in agent_pts)
            for n, (ci, _, uv, sigma_px) in enumerate(x for x, k in zip(single, near) if k):
                c_idx.append(ci)
                p_idx.append(base + n)
                uv_obs.append(uv)
                sig_obs.append(sigma_px)
            agent_pts.append(predicted[near])
            agent_ns.append(at[near])
            agent_ids.append(np.full(int(near.sum()), TOP))
            agent_chain.append(np.full(int(near.sum()), gi))
            agent_single.append(np.ones(int(near.sum()), bool))
    agent = AgentTrack(
        np.concatenate(agent_ns or [np.zeros(0, np.int64)]),
        np.concatenate(agent_ids or [np.zeros(0, int)]),
        np.vstack(agent_pts or [np.zeros((0, 3))]),
    )
    agent_obs = Observations(
        np.array(c_idx, int), np.array(p_idx, int), np.array(uv_obs).reshape(-1, 2), np.array(sig_obs)
    )
    return _GroupedCmcs(
        names,
        cams,
        T_init,
        group_of,
        agent,
        agent_obs,
        np.concatenate(agent_chain or [np.zeros(0, int)]),
        np.concatenate(agent_single or [np.zeros(0, bool)]),
        head_offset,
        alignments,
        failed,
        clocks,
        chains,
        distrusted,
    )


def _away_from(query_ns: np.ndarray, grid_ns: np.ndarray) -> np.ndarray:
    """The query stamps further than half the grid's step from every grid stamp (all of
    them when the grid has fewer than two)."""
    if len(grid_ns) < 2:
        return np.asarray(query_ns, np.int64)
    half = np.median(np.diff(grid_ns)) / 2
    i = np.clip(np.searchsorted(grid_ns, query_ns), 1, len(grid_ns) - 1)
    return query_ns[np.minimum(np.abs(query_ns - grid_ns[i - 1]), np.abs(grid_ns[i] - query_ns)) > half]


def _on_ego_clock(
    groups: list[CameraGroupResult], ego: EgoMapData, params: AlignParams
) -> tuple[list[CameraGroupResult], dict[str, float], dict[str, tuple[float | None, float | None, str]]]:
    """Each group with its track on the ego clock (its reference camera's offset to the
    ego camera estimated from the agent's track against the ego trajectory; 0 where it is
    not observable), that offset per group, and each member's clock against the ego's:
    its offset to the reference plus the reference's."""
    out, shifts, clocks = [], {}, {}
    for g in groups:
        fit = ClockFit(None, None, "not estimated (fusion.align.estimate_clock_offset is off)")
        if params.estimate_clock_offset:
            stamps, local, ground = _group_tracks(g, params)
            fit = estimate_clock_offset(stamps, local, ego.stamps_ns, ego.T_world_ego, params, *ground)
        applied = fit.offset_s is not None and abs(fit.offset_s) > params.min_clock_significance * fit.sigma_s
        delta = shifts[g.group_id] = fit.offset_s if applied else 0.0
        out.append(replace(g, point_stamps_ns=g.point_stamps_ns - round(delta * 1e9)))
        note = f"group {g.group_id}'s track against the ego trajectory (reference {g.reference})"
        if fit.offset_s is not None and not applied:
            note += (
                f": {1e3 * fit.offset_s:+.1f} +- {1e3 * fit.sigma_s:.1f} ms is within "
                f"{params.min_clock_significance:g} sigma of 0, so the clocks are taken as equal"
            )
        for n in g.names:
            if fit.offset_s is None:
                clocks[n] = (None, None, f"group {g.group_id}'s clock against the ego camera: {fit.reason}")
            else:
                clocks[n] = (
                    g.clock_offsets_s.get(n, 0.0) + delta,
                    float(np.hypot(g.clock_sigmas_s.get(n, 0.0), fit.sigma_s)),
                    note,
                )
    return out, shifts, clocks


def fuse(
    ego: EgoMapData,
    groups: list[CameraGroupResult],
    ungrouped: dict[str, str],
    cmcs: dict[str, CmcInput],
    params: FusionParams = FusionParams(),
    upstream: UpstreamParams = UpstreamParams(),
) -> FusionResult:
    # A camera without CameraInfo is projected with the intrinsics its group SfM estimated.
    estimated = {n: c for g in groups for n, c in g.cameras.items() if isinstance(c, EstimatedCamera)}
    cmcs = {
        n: replace(c, tracks=replace(c.tracks, camera=estimated[n])) if n in estimated else c for n, c in cmcs.items()
    }
    ideal_ego = CameraModel(ego.camera.width, ego.camera.height, ego.camera.K)
    ego_obs = Observations(
        ego.obs_pose.astype(int),
        ego.obs_landmark.astype(int),
        ego.camera.undistort_pixels(ego.obs_uv),
        np.full(len(ego.obs_pose), params.joint.ego_sigma_px),
    )
    weak = weak_ego_frames(ego, params)
    grouped = _gather_groups(ego, groups, ungrouped, cmcs, params, weak, upstream.tracks)
    names, cams, T_init, group_of = grouped.names, grouped.cams, grouped.T_init, grouped.group_of
    agent, agent_obs, head_offset = grouped.agent, grouped.agent_obs, grouped.head_offset
    # Each group's track against the ego map as the ego stage made it (before the joint optimisation).
    fit_before = {
        gid: head_top_rms(
            agent, grouped.fit_chain, c, ego.stamps_ns, ego.T_world_ego, head_offset, params.align.max_time_gap_s
        )
        for gid, (c, _) in grouped.chains.items()
    }
    scene_obs, scene_count = _scene_observations(names, cams, T_init, cmcs, ego, params)
    registered: list[RegisteredCmc] = []
    fits: list[AgentFit] = []
    T_ego, landmarks = ego.T_world_ego, ego.landmarks
    cloud, layout = ego.cloud_points, ego.layout
    if names:
        jo = _joint(grouped, scene_obs, ego, ideal_ego, ego_obs, weak, params)
        res, T_final = jo.result, jo.T_world_cmc
        if res is not None:
            # Breaks the joint optimisation found are breaks of the ego map like its gaps.
            found = np.isin(np.arange(len(ego.stamps_ns)), res.ego_breaks)
            weak = (weak[0] | found, weak[1] | found)
            T_ego, landmarks = np.array(res.T_world_ego), res.landmarks
            agent = AgentTrack(agent.stamps_ns, agent.ids, jo.agent_points)
            head_offset = res.head_offset
            if len(cloud):
                views = res.anchors
                cloud = move_cloud(cloud, ideal_ego, ego.T_world_ego[views], T_ego[views], upstream.cloud.depth_max_m)
                layout = rebuild_layout(cloud, T_ego[views, :3, 3], upstream.cloud, upstream.layout)
        covs, cov_failures = [], []
        for i, k in enumerate(np.cumsum(jo.in_jo) - 1):
            if jo.in_jo[i]:
                covs.append(res.cmc_covariances[k])
                cov_failures.append(res.covariance_failure)
                continue
            own = agent_obs.camera == i
            cov, failure = _covariance(cams[i], T_final[i], agent.points[agent_obs.point[own]], agent_obs.uv[own], 2.0)
            covs.append(cov)
            cov_failures.append(failure)
        agent_res = reprojection_residuals(cams, T_final, agent.points, agent_obs)
        distrust_of: dict[str, list[str]] = {}  # a group's, the same for each of its cameras
        for i, n in enumerate(names):
            own = agent_obs.camera == i
            raw = cmcs[n].tracks.camera
            fits.append(
                AgentFit(
                    n,
                    agent.ids[agent_obs.point[own]],
                    raw.distort_pixels(agent_obs.uv[own]),
                    raw.distort_pixels(agent_obs.uv[own] - agent_res[own]),
                )
            )
            rmse = _rmse(agent_res[own])
            status, reason = _verdict(rmse, covs[i], params, cov_failures[i])
            g = group_of[n]
            if g not in distrust_of:
                distrust_of[g] = [jo.failure, jo.left_out.get(g, "")] + _group_distrust(
                    grouped.chains[g],
                    agent,
                    grouped.fit_chain,
                    ego,
                    T_ego,
                    head_offset,
                    weak,
                    params,
                    n in grouped.disputed,
                    fit_before[g],
                )
            distrust = distrust_of[g]
            if any(distrust):
                status, reason = WEAK, "; ".join(r for r in distrust + [reason] if r)
            registered.append(
                RegisteredCmc(
                    n,
                    group_of[n],
                    GROUP_SFM,
                    status,
                    reason,
                    T_final[i],
                    covs[i],
                    raw,
                    rmse,
                    int(own.sum()),
                    scene_count.get(n, 0),
                    *grouped.clocks[n],
                )
            )
    # Isolated CMCs: the optimised agent track where a group saw the agent, and elsewhere the
    # track implied by the ego trajectory (head top = T_world_ego * o, ground point under it
    # on the floor z = 0) -- an extension: the paper needs a group to have seen the agent.
    track = merge_tracks(agent, ego_agent_track(T_ego, ego.stamps_ns, head_offset), params.isolated.max_gap_s)
    known = [c[0] for c in grouped.clocks.values() if c[0] is not None]
    groups_offset = float(np.median(known)) if known else None
    for n, why in sorted(grouped.failed.items()):
        registered.append(
            _register_isolated(
                n,
                why,
                cmcs.get(n),
                track,
                ego,
                T_ego,
                landmarks,
                params,
                upstream.tracks,
                weak,
                n in grouped.disputed,
                groups_offset,
            )
        )
    # The agent points each grouped camera observed (an isolated one's PnP had them in front).
    seen = {n: agent.points[agent_obs.point[agent_obs.camera == i]] for i, n in enumerate(names)}
    ceilings = [p for p in (layout.planes if layout is not None else []) if p.kind == KIND_CEILING]
    registered = [_refuse_absurd(r, seen.get(r.name, np.zeros((0, 3))), params, ceilings) for r in registered]
    return FusionResult(
        sorted(registered, key=lambda r: r.name),
        T_ego,
        landmarks,
        agent,
        head_offset,
        cloud,
        ego.cloud_colors,
        layout,
        grouped.alignments,
        fits,
    )


def absurd_pose(
    T_world_cam: np.ndarray, agent_points: np.ndarray, params: FusionParams, ceilings: list[LayoutPlane] = ()
) -> str:
    """Why a camera pose cannot be a ceiling camera's that saw the walker ('' when it can):
    below the floor (z = 0), above a ceiling the map holds right over it, image upside down,
    or with most of the agent points it saw behind it."""
    from shapely.geometry import Point, Polygon

    z = float(T_world_cam[2, 3])
    if z < -params.absurd_margin_m:
        return f"{-z:.2f} m below the floor"
    over = Point(T_world_cam[:2, 3])
    for c in ceilings:
        height = -float(c.coefficients[3] / c.coefficients[2])  # the plane n . p + d = 0 at x, y
        if z > height + params.absurd_margin_m and len(c.boundary) >= 3 and Polygon(c.boundary[:, :2]).contains(over):
            return f"{z - height:.2f} m above the ceiling the map holds over it (at {height:.2f} m)"
    up = -T_world_cam[:3, 1]  # the image's up direction in the world
    if up[2] < -params.max_upside_down_cos:
        return f"its image is upside down (image up {np.degrees(np.arccos(np.clip(up[2], -1, 1))):.0f} deg from the vertical)"
    if len(agent_points):
        in_cam = transform_points(inv_se3(T_world_cam), agent_points)
        behind = float(np.mean(in_cam[:, 2] <= 0))
        if behind > 0.5:
            return f"{100 * behind:.0f} % of the walker's positions it saw are behind it"
    return ""


def _refuse_absurd(
    r: RegisteredCmc, seen: np.ndarray, params: FusionParams, ceilings: list[LayoutPlane]
) -> RegisteredCmc:
    """A registration no ceiling camera can have is failed with the reason (never published)."""
    if r.T_world_cam is None or r.status == FAILED:
        return r
    why = absurd_pose(r.T_world_cam, seen, params, ceilings)
    if not why:
        return r
    where = ", ".join(f"{v:.2f}" for v in r.T_world_cam[:3, 3])
    return replace(
        r,
        status=FAILED,
        reason=f"rejected: {why} (at {where} m)" + (f"; {r.reason}" if r.reason else ""),
        T_world_cam=None,
        covariance=None,
    )


@dataclass
class _Joint:
    """The joint optimisation's outcome on _GroupedCmcs' cameras and agent points: each
    camera's pose (its group's alignment where it was not in a kept solution)."""

    result: JointResult | None  # None: no solution kept (failure says why)
    in_jo: np.ndarray  # (cameras,) bool: the camera's pose is the solution's
    T_world_cmc: list[np.ndarray]
    agent_points: np.ndarray
    left_out: dict[str, str]  # group -> why it was left out of the solution
    failure: str = ""


def _joint(
    grouped: _GroupedCmcs,
    scene_obs: Observations,
    ego: EgoMapData,
    ideal_ego: CameraModel,
    ego_obs: Observations,
    weak: tuple[np.ndarray, np.ndarray],
    params: FusionParams,
) -> _Joint:
    """The joint optimisation of every group; a solution a group cannot be reconciled with
    (its agent reprojection diverged, or its track does not fit the ego trajectory the
    solution made) is solved again without that group, which keeps its alignment: one wrong group
    (rooms joined through a doorway) must not cost the others theirs."""
    n_cams = len(grouped.names)
    none = _Joint(None, np.zeros(n_cams, bool), list(grouped.T_init), grouped.agent.points, {})
    left_out: dict[str, str] = {}
    while params.joint_optimisation:
        cams = np.array([grouped.group_of[n] not in left_out for n in grouped.names])
        chains = [c for g, (c, _) in grouped.chains.items() if g not in left_out]
        points = np.isin(grouped.agent_chain, chains)
        cam_index, point_index = np.cumsum(cams) - 1, np.cumsum(points) - 1
        agent_obs = grouped.agent_obs.subset(cams[grouped.agent_obs.camera])  # a camera sees its group's points
        agent_obs = replace(agent_obs, camera=cam_index[agent_obs.camera], point=point_index[agent_obs.point])
        scene = scene_obs.subset(cams[scene_obs.camera])
        scene = replace(scene, camera=cam_index[scene.camera])
        problem = JointProblem(
            ideal_ego,
            ego.stamps_ns,
            list(ego.T_world_ego),
            ego.landmarks,
            ego_obs,
            [c for c, k in zip(grouped.cams, cams) if k],
            [T for T, k in zip(grouped.T_init, cams) if k],
            scene,
            grouped.agent.points[points],
            grouped.agent.stamps_ns[points],
            grouped.agent.ids[points],
            agent_obs,
            grouped.head_offset,
            grouped.agent_chain[points],
            weak[0],
            ego.attitude_held,
            bool(ego.imu),
        )
        try:
            res = solve_joint(problem, params.joint)
        except RuntimeError as exc:  # GTSAM gave up on the system: keep the aligned poses
            return replace(
                none, left_out=left_out, failure=f"joint optimisation failed ({solver_failure(exc)}): pose without JO"
            )
        T_world_cmc, agent_points = list(grouped.T_init), grouped.agent.points.copy()
        for i, T in zip(np.flatnonzero(cams), res.T_world_cmc):
            T_world_cmc[i] = T
        agent_points[points] = res.agent_points
        out = _Joint(res, cams, T_world_cmc, agent_points, left_out)
        why, group = _diverged(grouped, out, params)
        if not why:
            why, group = _unreconciled(grouped, out, ego, params)
        if not why:
            return out
        if group is None or len(left_out) + 1 >= min(len(grouped.chains), params.max_joint_solves):
            return replace(none, left_out=left_out, failure=f"{why}: pose without JO")
        left_out[group] = f"group {group} left out of the joint optimisation: {why}"
    return none


def _diverged(grouped: _GroupedCmcs, jo: _Joint, params: FusionParams) -> tuple[str, str | None]:
    """Why the joint optimisation's result is rejected: a camera's agent reprojection RMSE
    above ok_rmse_px and worse than before it (on a badly broken ego map it can end in a
    minimum where the group no longer fits its own views), and the camera's group; or ''."""
    obs = grouped.agent_obs
    after = reprojection_residuals(grouped.cams, jo.T_world_cmc, jo.agent_points, obs)
    before = reprojection_residuals(grouped.cams, grouped.T_init, grouped.agent.points, obs)
    for c in np.flatnonzero(jo.in_jo):
        a, b = _rmse(after[obs.camera == c]), _rmse(before[obs.camera == c])
        if not np.isfinite(a) or (a > params.ok_rmse_px and a > max(2.0 * b, b + 1.0)):
            name = grouped.names[c]
            return (
                f"joint optimisation diverged ({name}'s agent reprojection RMSE {a:.1f} px, {b:.1f} px before it)"
            ), grouped.group_of[name]
    return "", None


def _unreconciled(grouped: _GroupedCmcs, jo: _Joint, ego: EgoMapData, params: FusionParams) -> tuple[str, str | None]:
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


def _group_distrust(
    chain: tuple[int, CameraGroupResult],
    agent: AgentTrack,
    agent_chain: np.ndarray,
    ego: EgoMapData,
    T_world_ego: np.ndarray,
    head_offset: np.ndarray,
    weak: tuple[np.ndarray, np.ndarray],
    params: FusionParams,
    rescued: bool,
    rms_before: float,
) -> list[str]:
    """Why a grouped camera is not ok whatever its residuals: its group's track still
    disagrees with the (optimised) ego trajectory, the ego map along the stretch the group
    saw is known to be weak, or it broke there (rescued: the group fitted the ego map as
    the ego stage made it only on its best window), or the two disagreed before the joint
    optimisation reconciled them (rms_before: the group's head-top RMS then)."""
    c, group = chain
    stretch = ego_stretch(ego, weak, group.point_stamps_ns, params.align.max_time_gap_s, T_world_ego)
    rms = head_top_rms(agent, agent_chain, c, ego.stamps_ns, T_world_ego, head_offset, params.align.max_time_gap_s)
    out = []
    if np.isfinite(rms) and rms > params.ok_track_rms_m:
        out.append(
            f"group {group.group_id}'s agent track and the ego trajectory disagree (head-top RMS {rms:.2f} m > "
            f"{params.ok_track_rms_m:g} m): {blame(group, stretch, params)[1]}"
        )
    elif stretch.broken(params):
        out.append(
            f"the ego map along the stretch group {group.group_id} saw is weak ({stretch.describe()}); "
            f"the agent track holds it (head-top RMS {rms:.2f} m)"
        )
    elif rescued:
        out.append(
            f"the ego map broke along the stretch group {group.group_id} saw (the self-consistent group fitted "
            f"it on its best {params.rescue_window_s:g} s only); the joint optimisation re-fitted the ego map to "
            f"the agent track (head-top RMS {rms:.2f} m)"
        )
    elif np.isfinite(rms_before) and rms_before > params.ok_track_rms_m:
        out.append(
            f"group {group.group_id}'s agent track and the ego map as the ego stage made it disagreed "
            f"(head-top RMS {rms_before:.2f} m > {params.ok_track_rms_m:g} m); the joint optimisation "
            f"reconciled them (head-top RMS {rms:.2f} m), bending the one or the other"
        )
    return out


def ego_agent_track(T_world_ego: np.ndarray, stamps_ns: np.ndarray, head_offset: np.ndarray) -> AgentTrack:
    top = head_tops(T_world_ego, head_offset)
    bottom = top * [1.0, 1.0, 0.0]
    return AgentTrack(
        np.concatenate([stamps_ns, stamps_ns]), np.repeat([0, 1], len(stamps_ns)), np.vstack([top, bottom])
    )


def merge_tracks(primary: AgentTrack, secondary: AgentTrack, gap_s: float) -> AgentTrack:
    """primary, plus secondary's samples farther than gap_s from any primary sample of the same id."""
    keep = np.ones(len(secondary.ids), bool)
    for i in np.unique(primary.ids):
        t = np.sort(primary.stamps_ns[primary.ids == i])
        sel = np.flatnonzero(secondary.ids == i)
        pos = np.clip(np.searchsorted(t, secondary.stamps_ns[sel]), 1, max(len(t) - 1, 1))
        near = np.minimum(
            np.abs(t[pos - 1] - secondary.stamps_ns[sel]),
            np.abs(t[np.minimum(pos, len(t) - 1)] - secondary.stamps_ns[sel]),
        )
        keep[sel[near <= gap_s * 1e9]] = False
    stamps = np.concatenate([primary.stamps_ns, secondary.stamps_ns[keep]])
    ids = np.concatenate([primary.ids, secondary.ids[keep]])
    pts = np.vstack([primary.points, secondary.points[keep]])
    order = np.lexsort((stamps, ids))
    return AgentTrack(stamps[order], ids[order], pts[order])


def _scene_observations(names, cams, T_init, cmcs, ego: EgoMapData, params: FusionParams):
    c_idx, p_idx, uv = [], [], []
    count = {}
    if params.use_scene_keypoints and len(ego.landmarks):
        for i, n in enumerate(names):
            m = match_scene(
                cmcs[n].background,
                cmcs[n].tracks.camera,
                T_init[i],
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


def _register_isolated(
    name: str,
    why: str,
    cmc: CmcInput | None,
    agent: AgentTrack,
    ego: EgoMapData,
    T_world_ego: np.ndarray,
    landmarks: np.ndarray,
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
        return RegisteredCmc(name, "", NONE, FAILED, why, None, None, None, float("nan"), 0, 0)
    if not cmc.intrinsics_known:  # its nominal model would place it wherever its focal length says
        return RegisteredCmc(
            name,
            "",
            NONE,
            FAILED,
            f"{why}; without CameraInfo or an intrinsics file it is "
            "calibrated only within a group (give them with --intrinsics)",
            None,
            None,
            None,
            float("nan"),
            0,
            0,
        )
    pnp, reason, offset = register_over_clock(cmc.tracks, agent, params.isolated, tracks, groups_offset_s)
    if pnp is None:
        return RegisteredCmc(
            name,
            "",
            NONE,
            FAILED,
            f"{why}; isolated registration failed: {reason}",
            None,
            None,
            cmc.tracks.camera,
            float("nan"),
            0,
            0,
        )
    clock = (
        (
            offset,
            params.isolated.clock_step_s / 10,
            "this camera's clock minus the ego camera's, the offset its isolated registration fits best",
        )
        if params.isolated.clock_search_s > 0
        else (None, None, "")
    )
    P, uv, T = pnp.points, pnp.uv, pnp.T_world_cam
    n_agent, n_scene = len(P), 0
    if params.use_scene_keypoints:
        m = match_scene(
            cmc.background, cmc.tracks.camera, T, landmarks, ego.descriptors, ego.descriptor_type, params.scene
        )
        if m is not None:
            P, uv = np.vstack([P, landmarks[m.landmark]]), np.vstack([uv, m.uv])
            n_scene = len(m.landmark)
            T = refine_pose(pnp.camera, T, P, uv)
    proj, _ = pnp.camera.project_world(T, P)
    rmse = _rmse(uv - proj)
    cov, cov_failure = _covariance(pnp.camera, T, P, uv, max(rmse, 0.5))
    status, reason = _verdict(rmse, cov, params, cov_failure)
    # Its 3D points are the agent track, wherever no group saw it the ego trajectory's own.
    stamps = np.concatenate([t.stamps_ns for t in cmc.tracks.tracks.values()] or [np.zeros(0, np.int64)])
    stretch = ego_stretch(ego, weak, stamps, params.isolated.max_gap_s, T_world_ego)
    if stretch.broken(params):
        status, reason = (
            WEAK,
            "; ".join(r for r in (f"the ego map along the stretch it saw is weak ({stretch.describe()})", reason) if r),
        )
    elif disputed:
        status = WEAK
    return RegisteredCmc(
        name,
        "",
        ISOLATED_PNP,
        status,
        "; ".join(r for r in (f"isolated: {why}", reason) if r),
        T,
        cov,
        cmc.tracks.camera,
        rmse,
        n_agent,
        n_scene,
        *clock,
    )
