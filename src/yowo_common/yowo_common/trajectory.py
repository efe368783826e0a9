"""Camera trajectories and their TUM text format (what evo, the TUM RGB-D tools and
ORB-SLAM read and write)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .geometry import quat_xyzw_from_rotation, se3


@dataclass
class Trajectory:
    stamps_ns: np.ndarray  # (N,) int64
    T_world_cam: np.ndarray  # (N, 4, 4)

    @property
    def positions(self) -> np.ndarray:
        return self.T_world_cam[:, :3, 3]


def write_tum(path, traj: Trajectory) -> None:
    """TUM format: 'stamp_s tx ty tz qx qy qz qw' per line (evo reads it)."""
    rows = []
    for ns, T in zip(traj.stamps_ns, traj.T_world_cam):
        q = quat_xyzw_from_rotation(T[:3, :3])
        rows.append(
            f"{int(ns) // 1_000_000_000}.{int(ns) % 1_000_000_000:09d} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q))
        )
    Path(path).write_text("\n".join(rows) + "\n")


def read_tum(path) -> Trajectory:
    stamps, poses = [], []
    for line_no, line in enumerate(Path(path).read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 8:
            raise ValueError(f"{path}:{line_no}: expected 8 columns (stamp x y z qx qy qz qw), got {len(parts)}")
        sec, _, frac = parts[0].partition(".")
        stamps.append(int(sec) * 1_000_000_000 + int((frac + "000000000")[:9]))
        v = np.array(parts[1:], dtype=float)
        poses.append(se3(Rotation.from_quat(v[3:]).as_matrix(), v[:3]))
    return Trajectory(np.array(stamps, dtype=np.int64), np.array(poses).reshape(-1, 4, 4))
