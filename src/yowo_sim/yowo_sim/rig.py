"""Ceiling-mounted cameras (CMCs): placement on walls/ceilings looking down, intrinsics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at, se3


@dataclass(frozen=True)
class CmcSpec:
    width: int = 640
    height: int = 480
    hfov_deg: tuple[float, float] = (70.0, 95.0)
    mount_height_m: tuple[float, float] = (2.4, 4.0)
    tilt_down_deg: tuple[float, float] = (35.0, 65.0)  # below the horizon (30-80 allowed)
    max_roll_deg: float = 4.0  # mounting is never perfectly level
    distortion: bool = True


@dataclass(kw_only=True)
class Cmc:
    name: str
    room: str
    camera: CameraModel
    T_world_cam: np.ndarray
    target_xy: np.ndarray  # floor point the camera looks at (the walk visits it)


def make_intrinsics(spec: CmcSpec, rng: np.random.Generator) -> CameraModel:
    cam = CameraModel.from_fov(spec.width, spec.height, rng.uniform(*spec.hfov_deg))
    cam.K[0, 2] += rng.uniform(-6, 6)
    cam.K[1, 2] += rng.uniform(-6, 6)
    cam.K[1, 1] *= rng.uniform(0.995, 1.005)
    if spec.distortion:
        cam.D = np.array([rng.uniform(-0.15, -0.03), rng.uniform(0.0, 0.04), 0.0, 0.0, 0.0])
    return cam


def place_cmc(
    name: str, room, ceiling_height: float, spec: CmcSpec, rng: np.random.Generator, margin: float = 0.25
) -> Cmc:
    """A camera near a wall or corner of `room` (bounds x0, y0, x1, y1), looking
    down across the room at a floor point inside it."""
    x0, y0, x1, y1 = room.bounds
    top = min(spec.mount_height_m[1], ceiling_height - 0.05)
    h = rng.uniform(min(spec.mount_height_m[0], top), top)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    # Mount point: a random spot on the room's boundary, pulled in by the margin.
    side = rng.integers(4)
    u = rng.uniform(0.1, 0.9)
    mount = {
        0: (x0 + margin, y0 + u * (y1 - y0)),
        1: (x1 - margin, y0 + u * (y1 - y0)),
        2: (x0 + u * (x1 - x0), y0 + margin),
        3: (x0 + u * (x1 - x0), y1 - margin),
    }[int(side)]
    mount = np.array(mount)
    # Look towards the room's central area at a downward tilt from the spec.
    direction = centre + rng.uniform(-0.25, 0.25, 2) * [x1 - x0, y1 - y0] - mount
    direction /= np.linalg.norm(direction)
    tilt = np.radians(rng.uniform(*spec.tilt_down_deg))
    dist = (h - 1.0) / np.tan(tilt)  # aim at chest height so a standing agent is well framed
    target = mount + direction * dist
    target = np.clip(target, [x0 + 0.5, y0 + 0.5], [x1 - 0.5, y1 - 0.5])
    T = look_at([*mount, h], [*target, 1.0])
    roll = Rotation.from_rotvec([0, 0, np.radians(rng.uniform(-1, 1) * spec.max_roll_deg)]).as_matrix()
    T = se3(T[:3, :3] @ roll, T[:3, 3])
    return Cmc(name=name, room=room.name, camera=make_intrinsics(spec, rng), T_world_cam=T, target_xy=target)
