"""A coverage model per ceiling camera: where in its image and from
which depths the agent was seen, with which other cameras at the same time, whether it is
in a group and how well the group's bundle adjustment explains it; a verdict, `ok` or
`needs more`, with the reasons in plain words naming what is missing and where.

Two sources. From the keypoint tracks (camera_coverage on the group SfM's grid
observations, or tracks_coverage): every observation of the agent. From a group result
alone (group_coverage, what the results writer has): the group's triangulated agent points
projected into each member's image, and nothing for a camera in no group."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .params import CoverageParams, SfmParams

# The configuration tree holds CoverageParams (params.py): the scene graph's libraries
# (cv2, networkx) and the group SfM's are imported where coverage is computed, as a keypoint
# tracker reads the tree but needs none of them.
if TYPE_CHECKING:
    from yowo_common.camera import CameraModel

    from .group_sfm import CameraGroupResult, GroupingResult
    from .keypoint_tracks import CameraTracks
    from .scene_graph import GridObservations

OK, NEEDS_MORE = "ok", "needs more"
ROWS, COLS = ("top", "middle", "bottom"), ("left", "centre", "right")
FROM_TRACKS = "the agent's keypoint tracks sampled on the group SfM's time grid"
FROM_RECEIVED = (
    "the agent keypoints received so far during the walk (raw pixels; co-visibility on the fastest "
    "camera's frame period)"
)
FROM_GROUP = (
    "the group's triangulated agent points projected into the image (the keypoint tracks are not "
    "kept with the results): co-visibility is where they project into both images"
)


@dataclass(kw_only=True)
class Coverage:
    name: str
    source: str  # what the coverage was computed from (FROM_TRACKS or FROM_GROUP)
    observations: int | None  # agent keypoint observations (None: unknown)
    cell_share: float | None  # share of the image grid's cells where the agent was seen
    overlap: float | None  # the paper's overlap score (eqs. grid, overlap) of those observations
    regions_seen: list[str] = field(default_factory=list)  # the image's ninths holding observations
    regions_missing: list[str] = field(default_factory=list)  # the image's ninths holding none
    covisible: dict[str, int] = field(default_factory=dict)  # other camera -> shared grid times
    group: str = ""  # its group ('' none)
    groups_known: bool = True  # False during the walk: the groups are formed at its end
    ungrouped_reason: str = ""
    depth: tuple[float, float] | None = None  # the agent's depths, 5th and 95th percentile
    depth_median: float | None = None
    depth_unit: str = "m"  # "m", or "group units" where the group's scale is unknown
    rmse_px: float | None = None  # its group's reprojection RMSE
    verdict: str = OK
    reasons: list[str] = field(default_factory=list)


def region_name(r: int, c: int) -> str:
    """One of the image's ninths (row r, column c of its thirds) in words."""
    if r == 1 and c == 1:
        return "centre"
    if r == 1:
        return f"{COLS[c]} edge"
    if c == 1:
        return f"{ROWS[r]} edge"
    return f"{ROWS[r]}-{COLS[c]} corner"


def region_counts(uv: np.ndarray, camera: CameraModel) -> np.ndarray:
    """(3, 3) observations per ninth of the image (rows top to bottom, columns left to right)."""
    cols = np.clip((uv[:, 0] / camera.width * 3).astype(int), 0, 2)
    rows = np.clip((uv[:, 1] / camera.height * 3).astype(int), 0, 2)
    counts = np.zeros((3, 3), int)
    np.add.at(counts, (rows, cols), 1)
    return counts


def region_reason(counts: np.ndarray, params: CoverageParams) -> str:
    """'' if the observations reach every third of the image across and down, else where they are."""
    filled = counts >= params.min_region_share * max(counts.sum(), 1)
    rows, cols = np.flatnonzero(filled.any(axis=1)), np.flatnonzero(filled.any(axis=0))
    if len(rows) == 3 and len(cols) == 3:
        return ""
    if len(rows) == 1 and len(cols) == 1:
        return f"agent seen only in the image's {region_name(rows[0], cols[0])}"
    if len(cols) == 1:
        return f"agent seen only in the image's {COLS[cols[0]]} third"
    if len(rows) == 1:
        return f"agent seen only in the image's {ROWS[rows[0]]} third"
    empty = [f"{COLS[c]}" for c in range(3) if c not in cols] + [f"{ROWS[r]}" for r in range(3) if r not in rows]
    return f"agent never seen in the image's {' or '.join(empty)} third"


def _overlap(uv: np.ndarray, camera: CameraModel, sfm: SfmParams) -> float:
    from .scene_graph import overlap_score

    return overlap_score(uv, camera, sfm)


def cell_share(uv: np.ndarray, camera: CameraModel, sfm: SfmParams) -> float:
    """Share of the overlap score's grid cells holding an observation."""
    if len(uv) == 0:
        return 0.0
    cols = np.clip((uv[:, 0] / camera.width * sfm.grid_cols).astype(int), 0, sfm.grid_cols - 1)
    rows = np.clip((uv[:, 1] / camera.height * sfm.grid_rows).astype(int), 0, sfm.grid_rows - 1)
    return len(set(zip(rows.tolist(), cols.tolist()))) / (sfm.grid_cols * sfm.grid_rows)


def depths(group: CameraGroupResult, name: str, keep: np.ndarray | None = None) -> np.ndarray:
    """The depths (optical z) of the group's agent points in camera `name`, in front of it."""
    T = group.T_local_cam[name]
    X = group.points if keep is None else group.points[keep]
    z = (X - T[:3, 3]) @ T[:3, 2]
    return z[z > 0]


def group_scale(group: CameraGroupResult, world_poses: dict[str, np.ndarray]) -> float | None:
    """Metres per group unit from the members' registered poses (median ratio of the
    distances between camera centres); None with fewer than two registered members."""
    names = [n for n in group.names if n in world_poses and n in group.T_local_cam]
    ratios = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            local = np.linalg.norm(group.T_local_cam[a][:3, 3] - group.T_local_cam[b][:3, 3])
            world = np.linalg.norm(world_poses[a][:3, 3] - world_poses[b][:3, 3])
            if local > 1e-9:
                ratios.append(world / local)
    return float(np.median(ratios)) if ratios else None


def judge(cov: Coverage, params: CoverageParams, region: str) -> Coverage:
    """Fill the verdict and its reasons from the measured coverage."""
    reasons = []
    if cov.observations is not None and cov.observations < params.min_observations:
        reasons.append(f"only {cov.observations} agent observations (needs {params.min_observations})")
    if region:
        reasons.append(region)
    if cov.cell_share is not None and cov.cell_share < params.min_cell_share:
        reasons.append(
            # Rounded down: a share just short of the bar must not read as reaching it.
            f"agent seen in {np.floor(cov.cell_share * 100):.0f}% of the image's grid cells "
            f"(needs {params.min_cell_share:.0%})"
        )
    if cov.depth is not None and cov.depth_median:
        near, far = cov.depth
        if far - near < params.min_depth_spread * cov.depth_median:
            reasons.append(f"seen from one depth only ({near:.1f}-{far:.1f} {cov.depth_unit})")
    if not cov.group and cov.groups_known:
        why = f": {cov.ungrouped_reason}" if cov.ungrouped_reason else ""
        reasons.append(f"in no group of cameras{why}")
    best = max(cov.covisible.values(), default=0)
    if cov.source in (FROM_TRACKS, FROM_RECEIVED) or cov.group:
        if best == 0:
            reasons.append("no other camera saw the agent at the same time")
        elif best < params.min_covisible_times:
            other = max(cov.covisible, key=cov.covisible.get)
            reasons.append(
                f"saw the agent at the same time as another camera only {best} times "
                f"(most with '{other}'; needs {params.min_covisible_times})"
            )
    if cov.rmse_px is not None and np.isfinite(cov.rmse_px) and cov.rmse_px > params.max_rmse_px:
        reasons.append(
            f"its pose is poorly determined: reprojection RMSE {cov.rmse_px:.1f} px (above {params.max_rmse_px:.1f} px)"
        )
    cov.reasons, cov.verdict = reasons, (NEEDS_MORE if reasons else OK)
    return cov


def _measure(
    name: str, uv: np.ndarray, camera: CameraModel, params: CoverageParams, sfm: SfmParams, **kwargs
) -> tuple[Coverage, str]:
    """A camera's coverage from its image observations `uv`, and its region reason."""
    counts = region_counts(uv, camera) if len(uv) else np.zeros((3, 3), int)
    ninths = [(r, c) for r in range(3) for c in range(3)]
    cov = Coverage(
        name=name,
        cell_share=cell_share(uv, camera, sfm),
        overlap=_overlap(uv, camera, sfm),
        regions_seen=[region_name(r, c) for r, c in ninths if counts[r, c]],
        regions_missing=[region_name(r, c) for r, c in ninths if not counts[r, c]],
        **kwargs,
    )
    return cov, region_reason(counts, params) if len(uv) else "agent never seen in the image"


def _depth_fields(group: CameraGroupResult, name: str, keep, scale: float | None) -> dict:
    z = depths(group, name, keep) * (scale or 1.0)
    if len(z) == 0:
        return {}
    near, far = np.percentile(z, [5, 95])
    return {
        "depth": (float(near), float(far)),
        "depth_median": float(np.median(z)),
        "depth_unit": "m" if scale else "group units",
        "rmse_px": float(group.rmse_px.get(name, np.nan)),
    }


def camera_coverage(
    obs: GridObservations,
    grouping: GroupingResult | None = None,
    params: CoverageParams = CoverageParams(),
    sfm: SfmParams = SfmParams(),
    scales: dict[str, float] | None = None,
) -> list[Coverage]:
    """Every camera's coverage from the group SfM's grid observations (scene_graph.sample_on_grid)
    and, where given, its grouping. `scales`: metres per group unit by group id (depths in group
    units without)."""
    from .scene_graph import MAX_IDS

    groups = {n: g for g in (grouping.groups if grouping else []) for n in g.names}
    ungrouped = grouping.ungrouped if grouping else {}
    times = [{k // MAX_IDS for k in per} for per in obs.per_camera]
    out = []
    for c, name in enumerate(obs.names):
        keys = obs.keys(c)
        uv = np.array([obs.per_camera[c][k] for k in keys]).reshape(-1, 2)
        covisible = {
            other: len(times[c] & times[d]) for d, other in enumerate(obs.names) if d != c and times[c] & times[d]
        }
        group = groups.get(name)
        cov, region = _measure(
            name,
            uv,
            obs.cameras[c] if obs.cameras else None,
            params,
            sfm,
            source=FROM_TRACKS,
            observations=len(keys),
            covisible=dict(sorted(covisible.items(), key=lambda kv: -kv[1])),
            group=group.group_id if group else "",
            ungrouped_reason=ungrouped.get(name, ""),
        )
        if group is not None and len(obs.grid_ns):
            # The group's points this camera observed: their (grid time, id) keys among its own.
            index = np.searchsorted(obs.grid_ns, group.point_stamps_ns).clip(0, len(obs.grid_ns) - 1)
            on_grid = obs.grid_ns[index] == group.point_stamps_ns
            keep = on_grid & np.isin(index * MAX_IDS + group.point_ids, keys)
            scale = (scales or {}).get(group.group_id)
            for k, v in _depth_fields(group, name, keep, scale).items():
                setattr(cov, k, v)
        out.append(judge(cov, params, region))
    return out


def tracks_coverage(
    cams: list[CameraTracks],
    grouping: GroupingResult | None = None,
    params: CoverageParams = CoverageParams(),
    sfm: SfmParams = SfmParams(),
    scales: dict[str, float] | None = None,
) -> list[Coverage]:
    """camera_coverage of the tracks, sampled on the grid as the group SfM samples them."""
    from .scene_graph import sample_on_grid

    return camera_coverage(sample_on_grid(cams, sfm.tracks), grouping, params, sfm, scales)


def group_coverage(
    groups: list[CameraGroupResult],
    ungrouped: dict[str, str],
    params: CoverageParams = CoverageParams(),
    sfm: SfmParams = SfmParams(),
    world_poses: dict[str, np.ndarray] | None = None,
    cameras: dict[str, CameraModel] | None = None,
) -> dict[str, Coverage]:
    """Every camera's coverage from the group results alone (no tracks): each member's image
    coverage from the group's agent points projected into it, co-visibility from the points
    that project into both images, depths in metres where `world_poses` (registered poses)
    give the group's scale. A camera in no group: its reason only. `cameras`: intrinsics of
    cameras whose group carries none."""
    out = {}
    for g in groups:
        scale = group_scale(g, world_poses or {})
        inside = {}
        for n in g.names:
            model = g.cameras.get(n) or (cameras or {}).get(n)
            if model is None or n not in g.T_local_cam:
                continue
            T = g.T_local_cam[n]
            uv, front = model.project((g.points - T[:3, 3]) @ T[:3, :3])
            inside[n] = (front & model.in_image(uv), uv, model)
        for n in g.names:
            if n not in inside:
                cov = Coverage(
                    name=n,
                    source=FROM_GROUP,
                    observations=g.num_observations.get(n),
                    cell_share=None,
                    overlap=None,
                    group=g.group_id,
                    rmse_px=float(g.rmse_px.get(n, np.nan)),
                )
                out[n] = judge(cov, params, "")
                continue
            seen, uv, model = inside[n]
            shared = {m: len(np.unique(g.point_stamps_ns[seen & inside[m][0]])) for m in inside if m != n}
            cov, region = _measure(
                n,
                uv[seen],
                model,
                params,
                sfm,
                source=FROM_GROUP,
                observations=g.num_observations.get(n),
                covisible=dict(sorted(((m, k) for m, k in shared.items() if k), key=lambda kv: -kv[1])),
                group=g.group_id,
            )
            for k, v in _depth_fields(g, n, seen, scale).items():
                setattr(cov, k, v)
            out[n] = judge(cov, params, region)
    for n, why in ungrouped.items():
        if n not in out:
            cov = Coverage(
                name=n, source=FROM_GROUP, observations=None, cell_share=None, overlap=None, ungrouped_reason=why
            )
            out[n] = judge(cov, params, "")
    return out


def coverage_entry(cov: Coverage | None) -> dict:
    """cameras.yaml's `coverage:` mapping of a camera."""
    if cov is None:
        return {"coverage": None}

    def rounded(v, digits):
        return None if v is None or not np.isfinite(v) else round(float(v), digits)

    return {
        "coverage": {
            "verdict": cov.verdict,
            "reasons": list(cov.reasons),
            "grid_cell_share": rounded(cov.cell_share, 3),
            "overlap_score": rounded(cov.overlap, 3),
            "agent_observations": cov.observations,
            "image_regions_seen": list(cov.regions_seen),
            "image_regions_missing": list(cov.regions_missing),
            "depth_range": None
            if cov.depth is None
            else {
                "near": rounded(cov.depth[0], 3),
                "far": rounded(cov.depth[1], 3),
                "median": rounded(cov.depth_median, 3),
                "unit": cov.depth_unit,
                "note": "5th and 95th percentile of the agent's depths from the camera",
            },
            "covisible_cameras": {k: int(v) for k, v in cov.covisible.items()},
            "in_group": bool(cov.group),
            "reprojection_rmse_px": rounded(cov.rmse_px, 4),
            "source": cov.source,
        }
    }
