"""The mobile agent's visible body: a walking person made of capsules and a box.

Proportions follow standard anthropometric fractions of the body height H
(hip joint at 0.53 H, shoulders at 0.81 H, chin at 0.87 H). The head top is at
exactly (x, y, H) and the body stands on the floor z = 0, so keypoint 0 (head top)
and keypoint 1 (ground point under the head) are exact.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from yowo_common.geometry import rotation_aligning

# Agent keypoint ids (DESIGN.md §2): 0 and 1 are required, the rest optional.
HEAD_TOP, GROUND, LEFT_FOOT, RIGHT_FOOT, PELVIS, NECK = 0, 1, 2, 3, 4, 5

# Distinctive clothing so detectors and background subtraction find the agent.
SKIN = (224, 172, 140)
HAIR = (60, 40, 25)
SHIRT = (250, 110, 20)
TROUSERS = (35, 60, 150)
SHOES = (25, 25, 30)

LEG_SWING = 0.15  # foot fore/aft amplitude, fraction of H
FOOT_LIFT = 0.05  # swing-foot clearance, fraction of H
ARM_SWING = 0.35  # rad


class AgentMesh(NamedTuple):
    vertices: np.ndarray  # (V, 3) float32, world frame
    triangles: np.ndarray  # (T, 3) int32
    colors: np.ndarray  # (T, 3) uint8 RGB, per triangle


class _Pose(NamedTuple):
    forward: np.ndarray
    left: np.ndarray
    centre: np.ndarray  # (x, y, 0)
    hips: tuple[np.ndarray, np.ndarray]  # left, right hip joints
    feet: tuple[np.ndarray, np.ndarray]  # ankle projected onto the sole, left and right
    shoulders: tuple[np.ndarray, np.ndarray]
    hands: tuple[np.ndarray, np.ndarray]
    neck: np.ndarray  # middle of the neck


def _pose(position_xy, heading_rad: float, H: float, phase: float) -> _Pose:
    """Joint positions for a gait ``phase`` (rad): the left foot is furthest
    forward at phase pi/2 and swings (lifted) while cos(phase) > 0."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    forward, left = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    centre = np.array([float(position_xy[0]), float(position_xy[1]), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    swing = LEG_SWING * H * np.sin(phase)
    feet, hips, shoulders, hands = [], [], [], []
    for side, sign in ((1.0, 1.0), (-1.0, -1.0)):  # left then right
        lift = FOOT_LIFT * H * max(0.0, sign * np.cos(phase))
        feet.append(centre + side * 0.06 * H * left + sign * swing * forward + lift * up)
        hips.append(centre + side * 0.055 * H * left + 0.53 * H * up)
        shoulder = centre + side * 0.145 * H * left + 0.80 * H * up
        arm = -sign * ARM_SWING * np.sin(phase)  # arms swing against the legs
        hand = shoulder + 0.33 * H * (np.sin(arm) * forward - np.cos(arm) * up) + side * 0.02 * H * left
        shoulders.append(shoulder)
        hands.append(hand)
    return _Pose(forward, left, centre, tuple(hips), tuple(feet), tuple(shoulders), tuple(hands),
                 centre + 0.845 * H * up)


def _capsule(a: np.ndarray, b: np.ndarray, radius: float, n_around: int = 10, n_cap: int = 3):
    """Closed capsule around segment a-b; its poles are exactly ``radius`` beyond a and b."""
    length = float(np.linalg.norm(b - a))
    theta = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    rings = []  # (z offset, latitude) bottom to top
    for i in range(1, n_cap + 1):
        rings.append((0.0, -np.pi / 2 + i * np.pi / 2 / n_cap))
    for i in range(n_cap):
        rings.append((length, i * np.pi / 2 / n_cap))
    verts = [np.array([0.0, 0.0, -radius])]
    for z0, lat in rings:
        r, z = radius * np.cos(lat), z0 + radius * np.sin(lat)
        verts.extend(np.column_stack([r * np.cos(theta), r * np.sin(theta), np.full(n_around, z)]))
    verts.append(np.array([0.0, 0.0, length + radius]))
    verts = np.array(verts)
    tris = []
    top = len(verts) - 1
    for k in range(n_around):
        k1 = (k + 1) % n_around
        tris.append((0, 1 + k1, 1 + k))
        last = 1 + (len(rings) - 1) * n_around
        tris.append((top, last + k, last + k1))
        for r in range(len(rings) - 1):
            lo, hi = 1 + r * n_around, 1 + (r + 1) * n_around
            tris.append((lo + k, lo + k1, hi + k1))
            tris.append((lo + k, hi + k1, hi + k))
    R = rotation_aligning([0.0, 0.0, 1.0], b - a) if length > 1e-9 else np.eye(3)
    return verts @ R.T + a, np.array(tris)


def _box(centre: np.ndarray, axes: tuple[np.ndarray, np.ndarray, np.ndarray], half: tuple[float, float, float]):
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
    A = np.column_stack(axes) * np.asarray(half)
    verts = centre + signs @ A.T
    # Corner index = 4*(x>0) + 2*(y>0) + (z>0); two triangles per face.
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))]
    return verts, np.array(tris)


def agent_mesh(position_xy, heading_rad: float, height_m: float, phase: float) -> AgentMesh:
    """Body mesh of the agent standing at ``position_xy`` facing ``heading_rad``
    (from +x towards +y) at gait ``phase`` (rad; one stride per 2 pi)."""
    H = float(height_m)
    p = _pose(position_xy, heading_rad, H, phase)
    up = np.array([0.0, 0.0, 1.0])
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(verts, tris, colour_of_tri):
        parts.append((verts, tris, colour_of_tri))

    def solid(colour):
        return lambda v, t: np.tile(np.array(colour, np.uint8), (len(t), 1))

    r_head = 0.05 * H
    v, t = _capsule(p.centre + (0.87 * H + r_head) * up, p.centre + (H - r_head) * up, r_head)
    # Hair on the crown: the face stays skin-coloured.
    add(v, t, lambda v, t: np.where((v[t][:, :, 2].mean(axis=1) > 0.95 * H)[:, None], HAIR, SKIN).astype(np.uint8))
    add(*_capsule(p.centre + 0.80 * H * up, p.centre + 0.89 * H * up, 0.03 * H), solid(SKIN))
    add(*_box(p.centre + 0.665 * H * up, (p.forward, p.left, up), (0.06 * H, 0.12 * H, 0.145 * H)), solid(SHIRT))
    for i in range(2):
        add(*_capsule(p.shoulders[i], p.hands[i], 0.03 * H), solid(SHIRT))
        add(*_capsule(p.hands[i], p.hands[i], 0.03 * H), solid(SKIN))
        add(*_capsule(p.hips[i], p.feet[i] + 0.04 * H * up, 0.035 * H), solid(TROUSERS))
        # Shoe: a box whose flat sole is exactly at the foot keypoint's height.
        shoe_centre = p.feet[i] + 0.03 * H * p.forward + 0.02 * H * up
        add(*_box(shoe_centre, (p.forward, p.left, up), (0.075 * H, 0.028 * H, 0.02 * H)), solid(SHOES))
    verts, tris, cols, offset = [], [], [], 0
    for v, t, colour in parts:
        verts.append(v)
        tris.append(t + offset)
        cols.append(colour(v, t))
        offset += len(v)
    return AgentMesh(np.concatenate(verts).astype(np.float32), np.concatenate(tris).astype(np.int32),
                     np.concatenate(cols).astype(np.uint8))


def agent_keypoints_3d(position_xy, heading_rad: float, height_m: float, phase: float) -> dict[int, np.ndarray]:
    """Agent keypoints (world frame) consistent with ``agent_mesh`` for the same arguments."""
    H = float(height_m)
    p = _pose(position_xy, heading_rad, H, phase)
    return {
        HEAD_TOP: p.centre + np.array([0.0, 0.0, H]),
        GROUND: p.centre.copy(),
        LEFT_FOOT: p.feet[0].copy(),
        RIGHT_FOOT: p.feet[1].copy(),
        PELVIS: p.centre + np.array([0.0, 0.0, 0.53 * H]),
        NECK: p.neck.copy(),
    }
