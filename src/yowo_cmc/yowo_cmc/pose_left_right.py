"""Left and right of a pose model's joints made right or absent, from the agent's
walking direction (docs/pose_model.md, "Left and right")."""

from __future__ import annotations

import numpy as np

from .params import PoseModelParams
from .pose_keypoints import ID_OFFSET, PersonPose


def lr_pairs(joints) -> list[tuple[int, int]]:
    """(left id, right id) of every left/right pair of a model's joint names."""
    ids = {n: i + ID_OFFSET for i, n in enumerate(joints)}
    return [(ids[n], ids["right" + n[4:]]) for n in joints if n.startswith("left") and "right" + n[4:] in ids]


class LeftRight:
    """Left/right labels of one camera's agent track made right or absent, model-free.

    A pose model tells left from right by appearance and swaps them for a person seen
    from behind or from above, or for one pair only when the limbs cross. Geometry
    decides instead: a walking person moves forward, and a ceiling camera sees every
    horizontal plane below it from above, so in the image (u right, v down) the offset
    d = left - right of a pair lies clockwise of the walking direction w of the pair's
    midpoint (cross(w, d) < 0; the midpoint is the same whichever label is right). Only
    d's component across w counts, so legs and arms swinging fore and aft do not.
    w comes from a line fit of the midpoint over `lr_window_s` centred on the frame.
    Standing still, a pair keeps its last decided assignment (it moves little between
    frames) for `lr_track_s`. A pair whose sides nearly coincide across w (or, standing,
    whose offset is small or turned), a pair seen on one side only, and a pair with
    neither motion nor a recent decision are dropped: never a possibly swapped id.
    Frames come out lr_window_s / 2 late, in order."""

    def __init__(self, pairs: list[tuple[int, int]], params: PoseModelParams = PoseModelParams()):
        self.pairs, self.p = pairs, params
        self._frames: list[tuple[int, int, PersonPose]] = []  # (stamp, track, pose), time order
        self._next = 0  # index of the next frame to release
        self._last: dict[tuple[int, int], tuple[int, int, np.ndarray]] = {}  # pair -> (stamp, track, d)
        self.kept = self.swapped = self.dropped = 0

    def push(self, stamp_ns: int, track: int, pose: PersonPose) -> list[tuple[int, PersonPose]]:
        """Add the agent's pose of one image (`track` changes where the agent was lost);
        returns the (stamp, pose) whose window is complete."""
        self._frames.append((stamp_ns, track, pose))
        return self._release(stamp_ns - round(0.5e9 * self.p.lr_window_s))

    def flush(self) -> list[tuple[int, PersonPose]]:
        return self._release(None)

    def _release(self, upto: int | None) -> list[tuple[int, PersonPose]]:
        out = []
        while self._next < len(self._frames) and (upto is None or self._frames[self._next][0] <= upto):
            stamp, track, pose = self._frames[self._next]
            out.append((stamp, self._resolve(self._next)))
            self._next += 1
        # Keep only what a later frame's window can reach.
        if self._next < len(self._frames):
            oldest = self._frames[self._next][0] - round(0.5e9 * self.p.lr_window_s)
        else:
            oldest = self._frames[-1][0] + 1 if self._frames else 0
        drop = 0
        while drop < self._next and self._frames[drop][0] < oldest:
            drop += 1
        del self._frames[:drop]
        self._next -= drop
        return out

    def _seen(self, pose: PersonPose, k: int) -> bool:
        return bool(pose.confidence[k] >= self.p.min_keypoint_score and np.isfinite(pose.uv[k]).all())

    def _motion(self, j: int, a: int, b: int) -> np.ndarray | None:
        """The pair's midpoint velocity [px/s] around frame j (same track): zero if not
        significant, None with too short a span."""
        stamp, track, _ = self._frames[j]
        half = 0.5e9 * self.p.lr_window_s
        t, mid = [], []
        for s, tr, pose in self._frames:
            if tr == track and abs(s - stamp) <= half and self._seen(pose, a) and self._seen(pose, b):
                t.append((s - stamp) * 1e-9)
                mid.append(0.5 * (pose.uv[a] + pose.uv[b]))
        if len(t) < 3 or max(t) - min(t) < 0.5 * self.p.lr_window_s:
            return None
        t, mid = np.array(t), np.array(mid)
        tc = t - t.mean()
        v = (tc[:, None] * (mid - mid.mean(axis=0))).sum(axis=0) / (tc**2).sum()
        # Jitter of a standing person's joints is no direction: the fit's own standard error decides.
        res = mid - mid.mean(axis=0) - tc[:, None] * v
        se = np.sqrt((res**2).sum() / max(2 * len(t) - 4, 1) / (tc**2).sum())
        return v if np.hypot(*v) >= 3.0 * se else np.zeros(2)

    def _resolve(self, j: int) -> PersonPose:
        stamp, track, pose = self._frames[j]
        p = self.p
        uv, conf = pose.uv.copy(), pose.confidence.copy()
        size = float(max(pose.box[2] - pose.box[0], pose.box[3] - pose.box[1], 1.0))
        for a, b in self.pairs if p.lr_resolve else ():
            seen_a, seen_b = self._seen(pose, a), self._seen(pose, b)
            if not (seen_a and seen_b):
                if seen_a or seen_b:  # one side only: which side it is cannot be checked
                    conf[[a, b]] = 0.0
                    self.dropped += 1
                continue
            d = pose.uv[a] - pose.uv[b]
            swap = None
            # Continuity: the offset turns little from the pair's last decision (same track, recent).
            follow, last = None, self._last.get((a, b))
            if last is not None and last[1] == track and stamp - last[0] <= p.lr_track_s * 1e9:
                n, n_last = np.hypot(*d), np.hypot(*last[2])
                cos = float(d @ last[2]) / max(n * n_last, 1e-9)
                if n >= p.lr_min_offset * size and abs(cos) >= 0.7:
                    follow = cos < 0
            v = self._motion(j, a, b)
            if v is not None and np.hypot(*v) * p.lr_window_s >= p.lr_min_motion * size:
                w = v / np.hypot(*v)
                across = w[0] * d[1] - w[1] * d[0]
                if abs(across) >= p.lr_min_offset * size:
                    swap = bool(across > 0)
                    if follow is not None and follow != swap:  # the two disagree: noise, drop it
                        swap = None
            else:  # standing: follow the last decision
                swap = follow
            if swap is None:
                conf[[a, b]] = 0.0
                self.dropped += 1
                continue
            if swap:
                uv[[a, b]], conf[[a, b]] = uv[[b, a]], conf[[b, a]]
                self.swapped += 1
            else:
                self.kept += 1
            self._last[(a, b)] = (stamp, track, uv[a] - uv[b])
        return PersonPose(score=pose.score, box=pose.box, ids=pose.ids, uv=uv, confidence=conf)

    def summary(self) -> str:
        return f"left/right pairs {self.kept} kept, {self.swapped} swapped, {self.dropped} dropped"
