"""Every person a camera sees, as tracks that keep their identity through crossings and
short occlusions: the pose model's persons of each image assigned to the tracks by
where each track is heading, its body size in the image and its clothes' colours
(an optimal assignment per image). Which track is the walker is decided later
(yowo_cmc.walker), from the whole tracks."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from .params import PeopleParams
from .pose_keypoints import PersonPose

_HUE_BINS, _SAT_BINS = 12, 4


def appearance(rgb: np.ndarray, box: np.ndarray) -> np.ndarray | None:
    """Hue-saturation histograms of the upper and the lower half of a person's box (shirt,
    trousers), each normalised to sum 1; None for a box of no pixels in the image."""
    h, w = rgb.shape[:2]
    x0, y0 = max(int(box[0]), 0), max(int(box[1]), 0)
    x1, y1 = min(int(np.ceil(box[2])) + 1, w), min(int(np.ceil(box[3])) + 1, h)
    if x1 - x0 < 2 or y1 - y0 < 4:
        return None
    # The middle of the box's width: its sides hold more background than person.
    mx = (x1 - x0) // 4
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb[y0:y1, x0 + mx : x1 - mx]), cv2.COLOR_RGB2HSV)
    mid = (y1 - y0) // 2
    parts = []
    for half in (hsv[:mid], hsv[mid:]):
        hist = cv2.calcHist([half], [0, 1], None, [_HUE_BINS, _SAT_BINS], [0, 180, 0, 256]).ravel()
        parts.append(hist / max(float(hist.sum()), 1.0))
    return np.concatenate(parts).astype(np.float32)


def appearance_distance(a: np.ndarray | None, b: np.ndarray | None) -> float:
    """Bhattacharyya distance of two appearances in [0, 1] (the mean of both halves');
    0.5 when either is unknown (neither for nor against)."""
    if a is None or b is None:
        return 0.5
    n = len(a) // 2
    return 0.5 * sum(
        float(cv2.compareHist(a[s], b[s], cv2.HISTCMP_BHATTACHARYYA)) for s in (slice(0, n), slice(n, None))
    )


def box_centre(box: np.ndarray) -> np.ndarray:
    return np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2], float)


def box_height(box: np.ndarray) -> float:
    return max(float(box[3] - box[1]), 1.0)


def box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boxes (x_min, y_min, x_max, y_max)."""
    iw = min(a[2], b[2]) - max(a[0], b[0])
    ih = min(a[3], b[3]) - max(a[1], b[1])
    if iw <= 0 or ih <= 0:
        return 0.0
    inter = iw * ih
    return float(inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter))


@dataclass(kw_only=True)
class PersonTrack:
    """One person's track in one camera: per image it was assigned, the stamp, the pose
    and whether another person's box overlapped it (`crowded`: its keypoints may be the
    other person's)."""

    track_id: int
    stamps_ns: list[int] = field(default_factory=list)
    poses: list[PersonPose] = field(default_factory=list)
    crowded: list[bool] = field(default_factory=list)
    look: np.ndarray | None = None  # running mean of the appearance
    velocity_px_s: np.ndarray = field(default_factory=lambda: np.zeros(2))

    @property
    def last_stamp_ns(self) -> int:
        return self.stamps_ns[-1]

    def predicted_centre(self, stamp_ns: int) -> np.ndarray:
        return box_centre(self.poses[-1].box) + self.velocity_px_s * (stamp_ns - self.last_stamp_ns) * 1e-9

    def seconds(self) -> float:
        return (self.stamps_ns[-1] - self.stamps_ns[0]) * 1e-9 if self.stamps_ns else 0.0


class PersonTracker:
    """Tracks of every person one camera sees. `update` per image returns, for each person
    assigned to a track, (track, pose, the boxes of the others overlapping it)."""

    def __init__(self, params: PeopleParams = PeopleParams()):
        self.p = params
        self.tracks: list[PersonTrack] = []
        self._next_id = 0

    def active(self, stamp_ns: int) -> list[PersonTrack]:
        return [t for t in self.tracks if (stamp_ns - t.last_stamp_ns) * 1e-9 <= self.p.lost_after_s]

    def update(
        self, stamp_ns: int, rgb: np.ndarray, people: list[PersonPose]
    ) -> list[tuple[PersonTrack, PersonPose, bool]]:
        p = self.p
        overlapping = [
            [o.box for j, o in enumerate(people) if j != i and box_iou(q.box, o.box) >= p.crowded_iou]
            for i, q in enumerate(people)
        ]
        crowded = [bool(o) for o in overlapping]
        # An overlapped box's colours are partly the other person's: no evidence either way.
        looks = [None if c else appearance(rgb, q.box) for q, c in zip(people, crowded)]
        live = self.active(stamp_ns)
        assigned: dict[int, PersonTrack] = {}
        if live and people:
            cost = np.full((len(live), len(people)), np.inf)
            for i, t in enumerate(live):
                dt = (stamp_ns - t.last_stamp_ns) * 1e-9
                h_t = box_height(t.poses[-1].box)
                pred = t.predicted_centre(stamp_ns)
                for j, q in enumerate(people):
                    h_q = box_height(q.box)
                    move = float(np.hypot(*(box_centre(q.box) - pred))) / max(h_t, h_q)
                    size = abs(float(np.log(h_q / h_t)))
                    look = appearance_distance(t.look, looks[j])
                    if move > p.max_move_heights + p.max_speed_heights_s * dt or size > p.max_size_change:
                        continue
                    if t.look is not None and looks[j] is not None and look > p.max_appearance_distance:
                        continue  # unknown (crowded) looks neither continue nor break a track
                    cost[i, j] = move + size + p.appearance_weight * look
            finite = np.where(np.isfinite(cost), cost, 1e9)
            for i, j in zip(*linear_sum_assignment(finite)):
                if np.isfinite(cost[i, j]):
                    assigned[j] = live[i]
        out = []
        for j, q in enumerate(people):
            track = assigned.get(j)
            if track is None:
                track = PersonTrack(track_id=self._next_id)
                self._next_id += 1
                self.tracks.append(track)
            self._extend(track, stamp_ns, q, crowded[j], looks[j])
            out.append((track, q, np.array(overlapping[j]).reshape(-1, 4)))
        return out

    def _extend(self, t: PersonTrack, stamp_ns: int, q: PersonPose, crowded: bool, look) -> None:
        if t.stamps_ns:
            dt = (stamp_ns - t.last_stamp_ns) * 1e-9
            if dt > 0:
                v = (box_centre(q.box) - box_centre(t.poses[-1].box)) / dt
                t.velocity_px_s = 0.5 * (t.velocity_px_s + v)  # smoothed: the box centre jitters
        t.stamps_ns.append(stamp_ns)
        t.poses.append(q)
        t.crowded.append(crowded)
        if look is not None:
            t.look = look if t.look is None else (1 - self.p.appearance_rate) * t.look + self.p.appearance_rate * look


def identities(tracks: list[PersonTrack], params: PeopleParams) -> list[list[PersonTrack]]:
    """Tracks of one person joined: a person who leaves the view (or is hidden for longer than
    lost_after_s) comes back as a new track. Two groups join when no two of their tracks were
    in view at once and every pair of their tracks' clothes is within link_appearance_distance
    (complete linkage: no chain of small steps from one person to another); closest first."""
    n = len(tracks)
    seen = [set(t.stamps_ns) for t in tracks]
    D = np.full((n, n), np.inf)  # between two tracks: inf when both were in view at once
    for i in range(n):
        for j in range(i + 1, n):
            if tracks[i].look is not None and tracks[j].look is not None and not seen[i] & seen[j]:
                D[i, j] = D[j, i] = appearance_distance(tracks[i].look, tracks[j].look)
    groups = [[i] for i in range(n)]
    while len(groups) > 1:
        d, a, b = min(
            (D[np.ix_(g, h)].max(), a, b) for a, g in enumerate(groups) for b, h in enumerate(groups) if a < b
        )
        if d > params.link_appearance_distance:
            break
        groups[a] = groups[a] + groups.pop(b)
    groups = [[tracks[i] for i in g] for g in groups]
    return [sorted(g, key=lambda t: t.stamps_ns[0]) for g in groups]
