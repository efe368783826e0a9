"""Register a CMC that belongs to no group (paper "Register 6-DoF Poses for Isolated
CMCs"): 2D-3D matches between its agent keypoints and the optimised world agent
track by timestamp, PnP + RANSAC, then (optionally) refinement with scene keypoints.
Where no group saw the agent, the world track is the one the ego trajectory implies."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from yowo_cmc.keypoint_tracks import CameraTracks, TrackParams, resample
from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, se3
from yowo_common.pnp import sqpnp_all, sqpnp_ransac

from .alignment import head_tops, interpolate_positions
from .records import AgentTrack


@dataclass(frozen=True)
class IsolatedParams:
    min_matches: int = 8  # agent correspondences, and PnP inliers, a pose needs at least [count]
    pnp_px: float = 4.0  # PnP RANSAC inlier threshold on the reprojection error
    min_spread_m: float = 0.05  # RMS spread of the 3D points below which no pose is attempted
    max_gap_s: float = 0.25  # the world track is interpolated only between samples this close
    # The camera's clock offset to the ego clock is searched within +- this; 0: its stamps are on
    # the ego clock. Set by `yowo run` for CCTV video files, whose start can be seconds off.
    clock_search_s: float = 0.0
    clock_step_s: float = 0.1  # step of that search's grid; then around the best offset at a tenth of it
    # Where groups found their clock offsets, the search is within +- this of theirs instead. One
    # NVR's videos share its clock; over a wide search, walks along the same paths seconds apart
    # gave wrong poses.
    clock_near_groups_s: float = 1.0


@dataclass
class PnpResult:
    T_world_cam: np.ndarray
    points: np.ndarray  # (M, 3) inlier 3D points
    uv: np.ndarray  # (M, 2) ideal pixels
    camera: CameraModel  # ideal (undistorted) intrinsics


def agent_correspondences(
    cam: CameraTracks, track: AgentTrack, params: IsolatedParams, tracks: TrackParams
) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    """(ideal camera, 3D points, 2D ideal pixels) pairing the camera's keypoints with
    the world track interpolated at the camera's own stamps."""
    pts, uvs = [], []
    stamps = np.unique(np.concatenate([t.stamps_ns for t in cam.tracks.values()] or [np.zeros(0, np.int64)]))
    ideal, samples = resample(cam, stamps, tracks)
    for kp_id, (uv, ok) in samples.items():
        sel = track.ids == kp_id
        if sel.sum() < 2:
            continue
        X, near = interpolate_positions(track.stamps_ns[sel], track.points[sel], stamps, int(params.max_gap_s * 1e9))
        valid = ok & near
        pts.append(X[valid])
        uvs.append(uv[valid])
    return ideal, np.vstack(pts or [np.zeros((0, 3))]), np.vstack(uvs or [np.zeros((0, 2))])


def register_by_agent(
    cam: CameraTracks, track: AgentTrack, params: IsolatedParams = IsolatedParams(), tracks: TrackParams = TrackParams()
) -> tuple[PnpResult | None, str]:
    """tracks: the cleaning of the camera's keypoint tracks (cmc.sfm.tracks)."""
    ideal, P, uv = agent_correspondences(cam, track, params, tracks)
    if len(P) < params.min_matches:
        return None, (
            f"only {len(P)} of its agent keypoints fall on the optimised agent track (needs {params.min_matches})"
        )
    spread_m = float(np.sqrt(np.var(P, axis=0).sum()))
    if spread_m < params.min_spread_m:
        return None, (
            f"its {len(P)} agent correspondences lie within {spread_m:.3f} m RMS of each other "
            f"(needs {params.min_spread_m} m: the agent stood still in its view)"
        )
    rvec, tvec, inliers = sqpnp_ransac(P, uv, ideal.K, params.pnp_px)
    candidates = []
    if len(inliers) >= params.min_matches:
        candidates.append((rvec, tvec))
    # Head tops and ground points along a straight walk are nearly coplanar: RANSAC's minimal
    # samples then admit a mirrored pose (a camera metres off, under the agent's head). SQPnP on
    # every correspondence is the second candidate.
    candidates += sqpnp_all(P, uv, ideal.K)
    best = max((_score(P, uv, ideal, rv, tv, params) for rv, tv in candidates), key=lambda c: c[0], default=None)
    if best is None or best[0][1] < params.min_matches:
        return None, f"PnP on {len(P)} agent correspondences found no consistent pose"
    _, T, idx = best
    return PnpResult(T, P[idx], uv[idx], ideal), ""


def register_over_clock(
    cam: CameraTracks,
    track: AgentTrack,
    params: IsolatedParams = IsolatedParams(),
    tracks: TrackParams = TrackParams(),
    groups_offset_s: float | None = None,
) -> tuple[PnpResult | None, str, float]:
    """register_by_agent at the clock offset (camera's clock - the ego clock) whose pose has the
    most agent inliers, then the lowest reprojection error: within params.clock_search_s, or
    within clock_near_groups_s of `groups_offset_s` (the groups' offset to the ego clock) where
    known; a best offset at the edge of the search is none. (result, why not, offset [s])."""
    if params.clock_search_s <= 0:
        return (*register_by_agent(cam, track, params, tracks), 0.0)
    centre, half = (
        (0.0, params.clock_search_s) if groups_offset_s is None else (groups_offset_s, params.clock_near_groups_s)
    )

    def best_of(shifts):
        found = []
        for s in shifts:
            pnp, _ = register_by_agent(cam.shifted(float(s)), track, params, tracks)
            if pnp is not None:
                err = np.linalg.norm(pnp.camera.project_world(pnp.T_world_cam, pnp.points)[0] - pnp.uv, axis=1)
                found.append(((len(pnp.points), -float(np.mean(err))), float(s)))
        return max(found)[1] if found else None

    step = params.clock_step_s
    grid = centre + np.arange(-half, half + step / 2, step)
    coarse = best_of(grid)
    if coarse is None or coarse in (grid[0], grid[-1]):
        where = "no pose" if coarse is None else f"the best pose at the edge ({coarse:+.1f} s)"
        return None, f"{where} of its clock offset search ({centre:+.1f} +- {half:g} s)", 0.0
    offset = best_of(coarse + np.arange(-step, step + step / 20, step / 10))
    pnp, why = register_by_agent(cam.shifted(offset), track, params, tracks)
    return pnp, why, offset


def _score(P, uv, camera: CameraModel, rvec, tvec, params: IsolatedParams):
    """((above the agent, inliers), refined T_world_cam, inlier indices). A ceiling camera
    is above the agent's head: a pose below the highest agent point it sees is a mirror
    image of the right one."""
    proj = cv2.projectPoints(P, rvec, tvec, camera.K, None)[0].reshape(-1, 2)
    idx = np.flatnonzero(np.linalg.norm(proj - uv, axis=1) <= params.pnp_px)
    if len(idx) >= 6:
        rvec, tvec = cv2.solvePnPRefineLM(P[idx], uv[idx], camera.K, None, rvec.copy(), tvec.copy())
    T = inv_se3(se3(cv2.Rodrigues(rvec)[0], np.asarray(tvec).ravel()))
    return (bool(T[2, 3] > P[:, 2].max()), len(idx)), T, idx


def refine_pose(camera: CameraModel, T_world_cam: np.ndarray, points: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt on all 2D-3D matches (agent and scene) from a prior pose."""
    T_cw = inv_se3(T_world_cam)
    rvec, tvec = cv2.solvePnPRefineLM(
        points, uv, camera.K, None, cv2.Rodrigues(T_cw[:3, :3])[0], T_cw[:3, 3].reshape(3, 1).copy()
    )
    return inv_se3(se3(cv2.Rodrigues(rvec)[0], tvec.ravel()))


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
