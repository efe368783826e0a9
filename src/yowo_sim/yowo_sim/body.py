"""The mobile agent's visible body: a walking person made of ellipsoids, capsules,
an elliptical torso and box shoes, articulated at the shoulders, elbows, hips and
knees, with a face, hair and hands, so a human-pose model finds it in ceiling
camera views (issue #17; docs/pose_model.md).

Proportions follow standard anthropometric fractions of the body height H
(hip joint at 0.53 H, shoulders at 0.815 H, chin at 0.87 H). The head top is at
exactly (x, y, H) and the body stands on the floor z = 0, so keypoint 0 (head top)
and keypoint 1 (ground point under the head) are exact.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from yowo_cmc.pose_keypoints import MOVENET_JOINTS
from yowo_common.geometry import rotation_aligning

# Agent keypoint ids (docs/design.md §3): 0 and 1 are required, the rest optional.
HEAD_TOP, GROUND, LEFT_FOOT, RIGHT_FOOT, PELVIS, NECK = 0, 1, 2, 3, 4, 5

# Distinctive clothing so detectors and background subtraction find the agent.
SKIN = (224, 172, 140)
HAIR = (60, 40, 25)
SHIRT = (250, 110, 20)
TROUSERS = (35, 60, 150)
SHOES = (25, 25, 30)
SKIN_SHADE = (200, 148, 118)  # nose and ears: skin a little darker
EYES = (35, 25, 25)
LIPS = (150, 70, 70)


class Clothing(NamedTuple):
    """A person's colours (RGB): the agent's are the module's constants; bystanders get
    others (yowo_sim.bystanders) so a detector that tracks the agent can tell them apart."""

    shirt: tuple[int, int, int] = SHIRT
    trousers: tuple[int, int, int] = TROUSERS
    shoes: tuple[int, int, int] = SHOES
    skin: tuple[int, int, int] = SKIN
    skin_shade: tuple[int, int, int] = SKIN_SHADE
    hair: tuple[int, int, int] = HAIR


AGENT_CLOTHING = Clothing()

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
    hands: tuple[np.ndarray, np.ndarray]  # wrist joints
    neck: np.ndarray  # middle of the neck
    elbows: tuple[np.ndarray, np.ndarray]
    knees: tuple[np.ndarray, np.ndarray]
    ankles: tuple[np.ndarray, np.ndarray]


# Segment lengths, fractions of H (Drillis & Contini / Winter): upper arm, forearm, hand
# (wrist to fingertips), thigh and shank (hip to ankle 0.49 H standing; a little longer
# so a foot reaches LEG_SWING forward with a bent knee).
UPPER_ARM, FOREARM, HAND = 0.186, 0.146, 0.10
THIGH = SHANK = 0.26
ANKLE = 0.04  # ankle joint above the sole


def _bend(a: np.ndarray, c: np.ndarray, length: float, towards: np.ndarray) -> np.ndarray:
    """The middle joint of a two-segment limb of equal segments from a to c, bent
    towards ``towards`` (a knee forward, an elbow forward)."""
    d = c - a
    dist = float(np.linalg.norm(d))
    axis = d / dist
    side = towards - np.dot(towards, axis) * axis
    side /= np.linalg.norm(side)
    return a + 0.5 * d + np.sqrt(max(length**2 - (0.5 * dist) ** 2, 0.0)) * side


def _pose(position_xy, heading_rad: float, H: float, phase: float) -> _Pose:
    """Joint positions for a gait ``phase`` (rad): the left foot is furthest
    forward at phase pi/2 and swings (lifted) while cos(phase) > 0."""
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    forward, left = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    centre = np.array([float(position_xy[0]), float(position_xy[1]), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    swing = LEG_SWING * H * np.sin(phase)
    feet, hips, shoulders, hands, elbows, knees, ankles = [], [], [], [], [], [], []
    for side, sign in ((1.0, 1.0), (-1.0, -1.0)):  # left then right
        lift = FOOT_LIFT * H * max(0.0, sign * np.cos(phase))
        foot = centre + side * 0.06 * H * left + sign * swing * forward + lift * up
        hip = centre + side * 0.06 * H * left + 0.53 * H * up
        ankle = foot + ANKLE * H * up
        feet.append(foot)
        hips.append(hip)
        ankles.append(ankle)
        knees.append(_bend(hip, ankle, THIGH * H, forward))
        shoulder = centre + side * 0.12 * H * left + 0.815 * H * up
        arm = -sign * ARM_SWING * np.sin(phase)  # arms swing against the legs
        # Arms hang a little away from the hips; the elbow bends more as the arm swings forward.
        out = 0.06 * side * left
        elbow = shoulder + UPPER_ARM * H * (np.sin(arm) * forward - np.cos(arm) * up + out)
        fore = arm + 0.25 + 0.4 * max(arm, 0.0)
        hand = elbow + FOREARM * H * (np.sin(fore) * forward - np.cos(fore) * up + 0.5 * out)
        shoulders.append(shoulder)
        elbows.append(elbow)
        hands.append(hand)
    return _Pose(
        forward,
        left,
        centre,
        tuple(hips),
        tuple(feet),
        tuple(shoulders),
        tuple(hands),
        centre + 0.845 * H * up,
        tuple(elbows),
        tuple(knees),
        tuple(ankles),
    )


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
    R = rotation_aligning([0.0, 0.0, 1.0], b - a) if length > 1e-9 else np.eye(3)
    return verts @ R.T + a, _ring_triangles(len(rings), n_around)


def _ring_triangles(n_rings: int, n_around: int) -> np.ndarray:
    """Triangles of a closed surface: vertex 0 the bottom pole, then n_rings rings of
    n_around vertices bottom to top, then the top pole."""
    tris = []
    top = 1 + n_rings * n_around
    last = 1 + (n_rings - 1) * n_around
    for k in range(n_around):
        k1 = (k + 1) % n_around
        tris.append((0, 1 + k1, 1 + k))
        tris.append((top, last + k, last + k1))
        for r in range(n_rings - 1):
            lo, hi = 1 + r * n_around, 1 + (r + 1) * n_around
            tris.append((lo + k, lo + k1, hi + k1))
            tris.append((lo + k, hi + k1, hi + k))
    return np.array(tris)


def _ellipsoid(centre: np.ndarray, axes, radii, n_around: int = 16, n_lat: int = 9):
    """Closed ellipsoid with semi-axes ``radii`` along ``axes`` (unit vectors; the third
    is the polar one, its poles exactly at centre +- radii[2] * axes[2])."""
    theta = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    lats = -np.pi / 2 + np.pi * np.arange(1, n_lat) / n_lat
    local = [np.array([0.0, 0.0, -1.0])]
    for lat in lats:
        local.extend(
            np.column_stack([np.cos(lat) * np.cos(theta), np.cos(lat) * np.sin(theta), np.full(n_around, np.sin(lat))])
        )
    local.append(np.array([0.0, 0.0, 1.0]))
    A = np.column_stack(axes) * np.asarray(radii, float)
    return centre + np.array(local) @ A.T, _ring_triangles(len(lats), n_around)


def _loft(rings, forward: np.ndarray, left: np.ndarray, n_around: int = 16):
    """Closed tube through horizontal elliptical rings (centre, half width along left,
    half depth along forward), bottom to top, capped at both ends."""
    theta = np.linspace(0.0, 2.0 * np.pi, n_around, endpoint=False)
    verts = [rings[0][0]]
    for c, hw, hd in rings:
        verts.extend(c + np.outer(hd * np.cos(theta), forward) + np.outer(hw * np.sin(theta), left))
    verts.append(rings[-1][0])
    return np.array(verts), _ring_triangles(len(rings), n_around)


def _box(centre: np.ndarray, axes: tuple[np.ndarray, np.ndarray, np.ndarray], half: tuple[float, float, float]):
    signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)
    A = np.column_stack(axes) * np.asarray(half)
    verts = centre + signs @ A.T
    # Corner index = 4*(x>0) + 2*(y>0) + (z>0); two triangles per face.
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))]
    return verts, np.array(tris)


# Head: an ellipsoid whose top pole is the head top (H) and chin at 0.87 H; face
# features on its front (a pose model finds the face first; hair on the crown and the
# back of the head tells front from back, as on a real person).
HEAD_RADII = (0.058, 0.05, 0.065)  # front-back, side, vertical; fractions of H
EYE_Z, EYE_SIDE, NOSE_Z, MOUTH_Z, EAR_Z = 0.94, 0.019, 0.918, 0.896, 0.928


def _head_points(p: _Pose, H: float) -> dict[str, np.ndarray]:
    """Face landmarks on the head's surface (ears at its sides)."""
    up = np.array([0.0, 0.0, 1.0])
    c = p.centre + (1.0 - HEAD_RADII[2]) * H * up
    a, b, r = (x * H for x in HEAD_RADII)

    def front(z, side=0.0):  # the head's surface point at height z, side offset along left
        dz, dy = z * H - c[2], side * H
        x = a * np.sqrt(max(1.0 - (dz / r) ** 2 - (dy / b) ** 2, 0.0))
        return c + x * p.forward + dy * p.left + dz * up

    return {
        "centre": c,
        "nose": front(NOSE_Z) + 0.012 * H * p.forward,
        "left_eye": front(EYE_Z, EYE_SIDE),
        "right_eye": front(EYE_Z, -EYE_SIDE),
        "left_ear": c + (EAR_Z * H - c[2]) * up + b * p.left,
        "right_ear": c + (EAR_Z * H - c[2]) * up - b * p.left,
        "mouth": front(MOUTH_Z),
    }


def agent_mesh(
    position_xy, heading_rad: float, height_m: float, phase: float, clothing: Clothing = AGENT_CLOTHING
) -> AgentMesh:
    """Body mesh of the agent standing at ``position_xy`` facing ``heading_rad``
    (from +x towards +y) at gait ``phase`` (rad; one stride per 2 pi): a person in a
    short-sleeved shirt, trousers and shoes, with a face, hair, hands, bent knees and
    elbows, left and right alike (a pose model must tell them apart by the body's
    shape, as on a real person). ``clothing``: its colours (a bystander's differ)."""
    H = float(height_m)
    p = _pose(position_xy, heading_rad, H, phase)
    up = np.array([0.0, 0.0, 1.0])
    f, lf = p.forward, p.left
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(verts, tris, colour_of_tri):
        parts.append((verts, tris, colour_of_tri))

    def solid(colour):
        return lambda v, t: np.tile(np.array(colour, np.uint8), (len(t), 1))

    head = _head_points(p, H)
    hc = head["centre"]

    def head_colour(v, t):
        m = v[t].mean(axis=1) - hc
        fwd, z = m @ f, m[:, 2]
        # Hair: the crown, and the back of the head down to the nape.
        hair = (z > 0.035 * H) | ((fwd < 0.012 * H) & (z > -0.045 * H))
        return np.where(hair[:, None], clothing.hair, clothing.skin).astype(np.uint8)

    add(*_ellipsoid(hc, (f, lf, up), [x * H for x in HEAD_RADII]), head_colour)
    for side in ("left_eye", "right_eye"):
        add(*_ellipsoid(head[side] - 0.004 * H * f, (f, lf, up), (0.007 * H, 0.011 * H, 0.006 * H), 8, 4), solid(EYES))
        brow = head[side] + 0.016 * H * up - 0.004 * H * f
        add(*_ellipsoid(brow, (f, lf, up), (0.006 * H, 0.014 * H, 0.003 * H), 8, 4), solid(clothing.hair))
    add(
        *_ellipsoid(head["nose"] - 0.01 * H * f + 0.008 * H * up, (f, lf, up), (0.013 * H, 0.009 * H, 0.016 * H), 8, 4),
        solid(clothing.skin_shade),
    )
    add(*_ellipsoid(head["mouth"] - 0.004 * H * f, (f, lf, up), (0.006 * H, 0.016 * H, 0.004 * H), 8, 4), solid(LIPS))
    for side in ("left_ear", "right_ear"):
        add(*_ellipsoid(head[side], (f, lf, up), (0.014 * H, 0.006 * H, 0.02 * H), 8, 4), solid(clothing.skin_shade))
    add(*_capsule(p.centre + 0.80 * H * up, p.centre + 0.885 * H * up, 0.026 * H), solid(clothing.skin))
    # Torso: hips to shoulders in elliptical sections (half width, half depth; Winter).
    sections = [
        (0.49, 0.082, 0.058),
        (0.53, 0.090, 0.062),
        (0.58, 0.085, 0.058),
        (0.64, 0.076, 0.054),
        (0.70, 0.084, 0.058),
        (0.75, 0.094, 0.060),
        (0.79, 0.104, 0.056),
        (0.815, 0.098, 0.050),
        (0.835, 0.060, 0.040),
        (0.845, 0.030, 0.028),
    ]
    v, t = _loft([(p.centre + z * H * up, hw * H, hd * H) for z, hw, hd in sections], f, lf)
    belt = 0.585 * H
    add(
        v,
        t,
        lambda v, t: np.where((v[t][:, :, 2].mean(axis=1) > belt)[:, None], clothing.shirt, clothing.trousers).astype(
            np.uint8
        ),
    )
    for i in range(2):
        s, e, w = p.shoulders[i], p.elbows[i], p.hands[i]
        sleeve = s + 0.6 * (e - s)
        add(*_capsule(s, sleeve, 0.034 * H), solid(clothing.shirt))  # short sleeve over the upper arm
        add(*_capsule(sleeve, e, 0.026 * H), solid(clothing.skin))
        add(*_capsule(e, w, 0.021 * H), solid(clothing.skin))
        # Hand: a flat mitten from the wrist on along the forearm.
        d = (w - e) / np.linalg.norm(w - e)
        add(
            *_ellipsoid(w + 0.5 * HAND * H * d, (f, lf, d), (0.016 * H, 0.028 * H, 0.5 * HAND * H), 8, 4),
            solid(clothing.skin),
        )
        add(*_capsule(p.hips[i], p.knees[i], 0.043 * H), solid(clothing.trousers))
        add(*_capsule(p.knees[i], p.ankles[i], 0.032 * H), solid(clothing.trousers))
        # Shoe: a box whose flat sole is exactly at the foot keypoint's height.
        shoe_centre = p.feet[i] + 0.03 * H * p.forward + 0.02 * H * up
        add(*_box(shoe_centre, (p.forward, p.left, up), (0.075 * H, 0.028 * H, 0.02 * H)), solid(clothing.shoes))
    verts, tris, cols, offset = [], [], [], 0
    for v, t, colour in parts:
        verts.append(v)
        tris.append(t + offset)
        cols.append(colour(v, t))
        offset += len(v)
    return AgentMesh(
        np.concatenate(verts).astype(np.float32),
        np.concatenate(tris).astype(np.int32),
        np.concatenate(cols).astype(np.uint8),
    )


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


# COCO-17 body joints in MoveNet's order; person's left / right.
BODY_JOINTS = MOVENET_JOINTS


def agent_joints_3d(position_xy, heading_rad: float, height_m: float, phase: float) -> np.ndarray:
    """(17, 3) world positions of the BODY_JOINTS of ``agent_mesh`` for the same arguments:
    the ground truth a pose model's joints are measured against (evaluation only)."""
    H = float(height_m)
    p = _pose(position_xy, heading_rad, H, phase)
    head = _head_points(p, H)
    face = [head[n] for n in BODY_JOINTS[:5]]
    return np.array(face + [j for pair in (p.shoulders, p.elbows, p.hands, p.hips, p.knees, p.ankles) for j in pair])
