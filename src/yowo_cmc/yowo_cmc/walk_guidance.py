"""Guidance during the walk (issue #48): each ceiling camera's coverage (coverage.py's model and
verdict) on the agent keypoints received so far, cheap enough to run every second while they
arrive. The group SfM node feeds it every camera's keypoints and publishes the result.

Incremental: a frame's keypoints are counted into the camera's image grid and ninths once, and
its time into the co-visibility slots once; an update costs the frames received since the last
one. The measures differ from the group SfM's in two ways, both small for guidance: the
keypoints are raw pixels (not smoothed nor undistorted), and a camera's frame counts as seen in
every slot of the fastest camera's frame period it spans (the group SfM interpolates the tracks
onto that grid). During the walk no camera is in a group yet: the verdict leaves the groups out
until the final update, which takes them (and the depths) from the group SfM's result."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .coverage import FROM_RECEIVED, NEEDS_MORE, Coverage, group_coverage, judge, region_name, region_reason
from .params import CoverageParams, SfmParams

if TYPE_CHECKING:
    from yowo_common.camera import CameraModel

    from .group_sfm import GroupingResult

# Frames whose stamps give a camera's frame period (the median of their differences).
PERIOD_FRAMES = 50
NO_CAMERA_INFO = "no usable CameraInfo received yet: where in the image the agent was seen is unknown"
NOTHING_YET = "nothing received from this camera yet (no keypoints, no CameraInfo)"


@dataclass
class _Camera:
    """What the guide keeps of one camera."""

    model: CameraModel | None = None
    cells: np.ndarray | None = None  # observations per cell of the overlap score's grid
    ninths: np.ndarray = field(default_factory=lambda: np.zeros((3, 3), int))  # observations per ninth
    pending: list[np.ndarray] = field(default_factory=list)  # keypoints not yet counted (uv)
    first_stamps: list[int] = field(default_factory=list)  # the first frames' stamps (its period)
    seen: list[tuple[int, int]] = field(default_factory=list)  # (stamp, keypoints) of frames with the agent
    folded: int = 0  # frames of `seen` counted into the co-visibility slots
    observations: int = 0  # keypoints x the grid slots each frame spans

    def period_ns(self) -> int | None:
        if len(self.first_stamps) < 2:
            return None
        return max(1, int(np.median(np.diff(self.first_stamps))))


class WalkGuide:
    """Every camera's coverage on the keypoints received so far: `add` each frame as it comes,
    `coverages` whenever the guidance is due."""

    def __init__(self, names: list[str], params: CoverageParams = CoverageParams(), sfm: SfmParams = SfmParams()):
        self.names, self.params, self.sfm = list(names), params, sfm
        self.cams = {n: _Camera() for n in self.names}
        self.index = {n: i for i, n in enumerate(self.names)}
        self.last_stamp_ns = 0  # the newest frame received (any camera)
        self.grid_ns: int | None = None  # the co-visibility slots' period
        self._slots: dict[int, int] = {}  # slot -> bit mask of the cameras seeing the agent in it
        self._covisible = np.zeros((len(self.names), len(self.names)), np.int64)  # shared slots per pair

    def set_camera(self, name: str, model: CameraModel | None) -> None:
        """The camera's intrinsics (its image size places the keypoints in the image)."""
        if model is not None and self.cams[name].model is None:
            cam = self.cams[name]
            cam.model, cam.cells = model, np.zeros((self.sfm.grid_rows, self.sfm.grid_cols), np.int64)

    def add(self, name: str, stamp_ns: int, uv: np.ndarray) -> None:
        """One frame of a camera: its stamp and the agent keypoints kept in it (none: the agent
        was not seen)."""
        cam = self.cams[name]
        self.last_stamp_ns = max(self.last_stamp_ns, int(stamp_ns))
        if len(cam.first_stamps) < PERIOD_FRAMES:
            cam.first_stamps.append(int(stamp_ns))
        if len(uv):
            cam.seen.append((int(stamp_ns), len(uv)))
            cam.pending.append(np.asarray(uv, float).reshape(-1, 2))

    # --- the update ---------------------------------------------------------------
    def coverages(self, grouping: GroupingResult | None = None) -> list[Coverage]:
        """Every camera's coverage and verdict on what was received so far, in the order of
        `names`. `grouping`: the group SfM's result at the end of the walk (groups, depths and
        reprojection errors then count in the verdict); None during the walk."""
        for cam in self.cams.values():
            self._count_image(cam)
        self._fold_times()
        final = grouping is not None
        grouped = group_coverage(grouping.groups, grouping.ungrouped, self.params, self.sfm) if final else {}
        return [self._coverage(c, name, grouped.get(name), final) for c, name in enumerate(self.names)]

    def _count_image(self, cam: _Camera) -> None:
        if cam.model is None or not cam.pending:
            return
        uv = np.concatenate(cam.pending)
        cam.pending.clear()
        w, h = cam.model.width, cam.model.height
        for counts in (cam.ninths, cam.cells):
            rows, cols = counts.shape
            r = np.clip((uv[:, 1] / h * rows).astype(int), 0, rows - 1)
            c = np.clip((uv[:, 0] / w * cols).astype(int), 0, cols - 1)
            np.add.at(counts, (r, c), 1)

    def _fold_times(self) -> None:
        """Count the new frames into the co-visibility slots (all frames again when the fastest
        camera's period changed, as it may while the first frames arrive)."""
        periods = {n: c.period_ns() for n, c in self.cams.items()}
        known = [p for p in periods.values() if p]
        if not known:
            return
        grid = min(known)
        if grid != self.grid_ns:
            self.grid_ns, self._slots = grid, {}
            self._covisible[:] = 0
            for cam in self.cams.values():
                cam.folded, cam.observations = 0, 0
        for n, cam in self.cams.items():
            if periods[n] is None:
                continue
            span = max(1, round(periods[n] / grid))  # the grid slots one of its frames spans
            bit, c = 1 << self.index[n], self.index[n]
            for stamp, keypoints in cam.seen[cam.folded :]:
                cam.observations += keypoints * span
                first = stamp // grid
                for slot in range(first, first + span):
                    mask = self._slots.get(slot, 0)
                    if mask & bit:
                        continue
                    others = mask
                    while others:
                        d = (others & -others).bit_length() - 1
                        others &= others - 1
                        self._covisible[c, d] += 1
                        self._covisible[d, c] += 1
                    self._slots[slot] = mask | bit
            cam.folded = len(cam.seen)

    def _coverage(self, c: int, name: str, grouped: Coverage | None, final: bool) -> Coverage:
        cam = self.cams[name]
        covisible = {
            other: int(self._covisible[c, d]) for d, other in enumerate(self.names) if d != c and self._covisible[c, d]
        }
        cov = Coverage(
            name=name,
            source=FROM_RECEIVED,
            observations=cam.observations if cam.seen else 0,
            cell_share=None,
            overlap=None,
            covisible=dict(sorted(covisible.items(), key=lambda kv: -kv[1])),
            groups_known=final,
        )
        if grouped is not None:  # the end of the walk: the group SfM's verdict on the camera
            cov.group, cov.ungrouped_reason, cov.rmse_px = grouped.group, grouped.ungrouped_reason, grouped.rmse_px
            cov.depth, cov.depth_median, cov.depth_unit = grouped.depth, grouped.depth_median, grouped.depth_unit
        if cam.model is None:
            judge(cov, self.params, "")
            if cam.first_stamps or final:
                cov.reasons.insert(0, NO_CAMERA_INFO)
            else:  # its tracker has not started, or its camera sends nothing
                cov.reasons = [NOTHING_YET]
            cov.verdict = NEEDS_MORE
            return cov
        occupied = cam.cells > 0
        cov.cell_share = float(occupied.mean())
        cov.overlap = grid_overlap(occupied)
        ninths = [(r, k) for r in range(3) for k in range(3)]
        cov.regions_seen = [region_name(r, k) for r, k in ninths if cam.ninths[r, k]]
        cov.regions_missing = [region_name(r, k) for r, k in ninths if not cam.ninths[r, k]]
        region = region_reason(cam.ninths, self.params) if cam.ninths.sum() else "agent never seen in the image"
        return judge(cov, self.params, region)


def grid_overlap(occupied: np.ndarray) -> float:
    """The paper's overlap score (eqs. grid, overlap; scene_graph.overlap_score) of an occupancy
    grid: the occupied cells' spread (rows x columns, normalised) times their number."""
    r, c = np.nonzero(occupied)
    if len(r) == 0:
        return 0.0
    spread = (r.max() - r.min()) * (c.max() - c.min()) / occupied.size
    return float(spread * occupied.sum())
