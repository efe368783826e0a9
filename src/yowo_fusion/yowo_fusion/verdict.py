"""The verdict rules: which frames of the ego map are not to be trusted, the stretch of it a
camera's registration rests on, which of a group and the ego map is at fault when they
disagree, each camera's status (ok or weak) from its reprojection residuals and pose
covariance, and the poses no ceiling camera can have (failed)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from yowo_cmc.group_sfm import CameraGroupResult
from yowo_common.bundle import pose_covariance
from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, transform_points
from yowo_ego.layout import LayoutPlane

from .alignment import head_top_rms
from .config import FusionParams
from .joint import UNKNOWN_COVARIANCE, covariance_unavailable, ros_covariance
from .records import FAILED, OK, WEAK, AgentTrack, EgoMapData, RegisteredCmc


def weak_ego_frames(ego: EgoMapData, params: FusionParams) -> tuple[np.ndarray, np.ndarray]:
    """(weak, gap), each (F,): frame f's motion from frame f-1 is not to be trusted (weak:
    tracked from a keyframe with fewer than weak_keyframe_landmarks landmark observations,
    and, where the ego stage says how each frame was tracked, with an overlap below
    weak_tracking_fitness, or not by vision at all; or after a gap), and gap: more than
    weak_frame_gap_s after frame f-1 (the ego map lost track or rejected frames there; what
    joins the two sides is a guess). A map without any landmark observations (a trajectory
    alone) is judged by its gaps (and tracking) only. In a well-lit bare room every keyframe
    has few landmarks while depth tracks it to centimetres: by landmarks alone the joint
    optimisation let the agent track shape the whole map (docs/notes/fusion.md). The jump where
    two recordings read as one meet (ego.joins_ns) is no gap where the ego stage tracked the
    frame after it by vision: the second walk is tied to the first by measurement."""
    n = len(ego.stamps_ns)
    gap = np.zeros(n, bool)
    gap[1:] = np.diff(ego.stamps_ns) > params.weak_frame_gap_s * 1e9
    if len(ego.joins_ns) and ego.tracking_measured is not None:
        after = np.searchsorted(ego.stamps_ns, ego.joins_ns)
        after = after[(after > 0) & (after < n)]
        gap[after] &= ~ego.tracking_measured[after]
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


@dataclass(kw_only=True)
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
        return EgoStretch(frames=0, weak_share=0.0, gaps=0)
    lo, hi = int(f.min()), int(f.max())
    moved = 0.0
    if T_world_ego_joint is not None:
        d = T_world_ego_joint[lo : hi + 1, :3, 3] - ego.T_world_ego[lo : hi + 1, :3, 3]
        moved = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    return EgoStretch(
        frames=hi - lo + 1,
        weak_share=float(weak[0][lo + 1 : hi + 1].mean()) if hi > lo else 0.0,
        gaps=int(weak[1][: hi + 1].sum()),
        moved_m=moved,
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


def residual_verdict(rmse: float, cov: np.ndarray, params: FusionParams, cov_failure: str = "") -> tuple[str, str]:
    reasons = [cov_failure] if cov_failure else []
    if not np.isfinite(rmse) or rmse > params.ok_rmse_px:
        reasons.append(f"reprojection RMSE {rmse:.2f} px > {params.ok_rmse_px:g} px")
    if not cov_failure:
        sigma = float(np.sqrt(np.linalg.eigvalsh(cov[:3, :3]).max()))
        if sigma > params.ok_position_sigma_m:
            reasons.append(f"position sigma {sigma:.3f} m > {params.ok_position_sigma_m:g} m")
    return (WEAK, "; ".join(reasons)) if reasons else (OK, "")


def group_distrust(
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


def refuse_absurd(
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


def fixed_point_covariance(
    camera: CameraModel, T: np.ndarray, points: np.ndarray, uv: np.ndarray, sigma_px: float
) -> tuple[np.ndarray, str]:
    """One camera's pose covariance through fixed points, or unknown and why (degenerate geometry)."""
    try:
        return ros_covariance(pose_covariance(camera, T, points, uv, sigma_px), T[:3, :3]), ""
    except RuntimeError as exc:
        return UNKNOWN_COVARIANCE, covariance_unavailable(exc)


def reprojection_rmse(res: np.ndarray) -> float:
    """RMS of the finite reprojection residuals (N, 2); NaN when none is."""
    r = res[np.isfinite(res).all(axis=1)]
    return float(np.sqrt(np.mean(np.sum(r**2, axis=1)))) if len(r) else float("nan")
