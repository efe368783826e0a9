"""Left/right consistency of the pose source (pose_left_right.LeftRight), model-free, on
synthetic joint sequences: a person's left/right joint pairs walking and standing under
ceiling cameras, projected by a real camera model, with the label swaps a pose model
makes (every pair for a person seen from behind, single pairs at random). Whatever comes
out must be right or absent."""

import numpy as np
import pytest

from yowo_cmc.params import PoseModelParams
from yowo_cmc.pose_keypoints import MOVENET_JOINTS, PersonPose
from yowo_cmc.pose_left_right import LeftRight, lr_pairs
from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at

PAIRS = lr_pairs(MOVENET_JOINTS)
K = len(MOVENET_JOINTS) + 2
# Per pair (eyes, ears, shoulders, elbows, wrists, hips, knees, ankles): height [m],
# half the lateral offset [m], fore-aft swing amplitude [m] (limbs swing against each other).
BODY = [
    (1.62, 0.032, 0.0),
    (1.58, 0.075, 0.0),
    (1.40, 0.20, 0.0),
    (1.08, 0.21, 0.12),
    (0.83, 0.23, 0.2),
    (0.92, 0.10, 0.0),
    (0.50, 0.10, 0.12),
    (0.07, 0.10, 0.25),
]
HZ = 10.0


def walk_3d(heading: float, n: int, speed: float = 1.0, stand: tuple[int, int] = (0, 0)):
    """(n, K, 3) true joint positions (ids as the model's) of a person walking forward from
    the origin along `heading`, standing still (and turning by 90 deg) in frames stand[0]:stand[1]."""
    out = np.full((n, K, 3), np.nan)
    h = heading
    xy = -0.5 * speed * (n - stand[1] + stand[0]) / HZ * np.array([np.cos(h), np.sin(h)])  # centred on the origin
    for i in range(n):
        standing = stand[0] <= i < stand[1]
        if standing:
            h += np.pi / 2 / max(stand[1] - stand[0], 1)
        fwd, left = np.array([np.cos(h), np.sin(h), 0.0]), np.array([-np.sin(h), np.cos(h), 0.0])
        phase = 2 * np.pi * i / HZ * 0.85
        for (a, b), (z, half, swing) in zip(PAIRS, BODY):
            s = 0.0 if standing else swing * np.sin(phase)
            base = np.array([xy[0], xy[1], z])
            out[i, a] = base + half * left + s * fwd
            out[i, b] = base - half * left - s * fwd
        if not standing:
            xy = xy + speed / HZ * fwd[:2]
    return out


CAMERAS = [  # ceiling cameras looking down at the walk from several sides and tilts
    (CameraModel.from_fov(640, 480, 80.0), look_at((-3.0, -2.0, 3.2), (0.0, 0.0, 0.6))),
    (CameraModel.from_fov(640, 480, 90.0), look_at((2.5, 2.5, 2.6), (0.0, 0.0, 0.8))),
    (
        CameraModel(640, 480, [[380.0, 0, 319.5], [0, 380.0, 239.5], [0, 0, 1]], [-0.25, 0.06, 0, 0, 0]),
        look_at((0.5, -2.2, 3.8), (0.0, 0.0, 0.3)),
    ),
]


def poses(camera, T, joints3d, swapped_frames, rng, noise_px=1.5):
    """PersonPoses of the projected joints with every pair swapped in `swapped_frames`
    (the model's labels for a person seen from behind) and single pairs swapped at random."""
    out = []
    for i, j3 in enumerate(joints3d):
        uv, ok = camera.project_world(T, np.nan_to_num(j3))
        uv = uv + rng.normal(0, noise_px, uv.shape)
        inside = ok & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        conf = np.where(inside & np.isfinite(j3).all(axis=1), 0.8, 0.0)
        conf[:2] = 0.0
        truth = uv.copy()
        if i in swapped_frames:
            for a, b in PAIRS:
                uv[[a, b]] = uv[[b, a]]
        elif rng.random() < 0.3:
            a, b = PAIRS[rng.integers(len(PAIRS))]
            uv[[a, b]] = uv[[b, a]]
        seen = uv[conf > 0] if (conf > 0).any() else uv
        box = np.concatenate([seen.min(axis=0), seen.max(axis=0)])
        out.append((truth, PersonPose(score=0.9, box=box, ids=np.arange(K), uv=uv, confidence=conf)))
    return out


def run(lr: LeftRight, frames, t0_ns=1_000_000_000, track=0):
    stamps = [t0_ns + round(i * 1e9 / HZ) for i in range(len(frames))]
    out = []
    for s, (_, pose) in zip(stamps, frames):
        out += lr.push(s, track, pose)
    out += lr.flush()
    assert [s for s, _ in out] == stamps  # every frame comes out, in order
    return [pose for _, pose in out]


def check(frames, resolved):
    """(right, wrong) pair counts: a pair is right when both sides are emitted at their
    own true positions."""
    right = wrong = 0
    for (truth, _), pose in zip(frames, resolved):
        for a, b in PAIRS:
            emitted = pose.confidence[[a, b]] > 0
            if emitted.any():
                ok = emitted.all() and np.array_equal(pose.uv[[a, b]], truth[[a, b]])
                right += ok
                wrong += not ok
    return right, wrong


@pytest.mark.parametrize("cam", range(len(CAMERAS)))
@pytest.mark.parametrize("heading", np.radians([0, 60, 135, 200, 290]))
def test_injected_swaps_are_corrected_or_dropped(cam, heading):
    camera, T = CAMERAS[cam]
    rng = np.random.default_rng(cam * 10 + int(heading * 10))
    # 6 s: walking, seen "from behind" (every pair swapped) for 2 s, standing and turning for 1.5 s.
    frames = poses(camera, T, walk_3d(heading, 60, speed=0.8, stand=(35, 50)), set(range(10, 30)), rng)
    resolved = run(LeftRight(PAIRS, PoseModelParams()), frames)
    right, wrong = check(frames, resolved)
    assert wrong == 0, (right, wrong)
    # Most pairs in view come out: the eyes (6 cm apart) may be dropped as ambiguous, the rest rarely.
    in_view = sum((pose.confidence[[a, b]] > 0).all() for _, pose in frames for a, b in PAIRS)
    assert in_view >= 0.5 * len(frames) * len(PAIRS) and right >= 0.6 * in_view, (right, in_view)
    # Without the fix the injected swaps come out as they are.
    raw = run(LeftRight(PAIRS, PoseModelParams(lr_resolve=False)), frames)
    assert check(frames, raw)[1] > 0.3 * len(frames)


def test_standing_from_the_start_and_coincident_sides_are_dropped():
    camera, T = CAMERAS[0]
    rng = np.random.default_rng(3)
    # Nobody walks: no direction, no earlier decision: nothing can tell left from right.
    frames = poses(camera, T, walk_3d(0.3, 20, stand=(0, 20)), set(range(5, 12)), rng)
    resolved = run(LeftRight(PAIRS, PoseModelParams()), frames)
    assert all((p.confidence[[a for a, _ in PAIRS] + [b for _, b in PAIRS]] == 0).all() for p in resolved)
    # Walking, but the model puts both knees on one leg: that pair is dropped, the others kept.
    j3 = walk_3d(0.3, 30)
    knee_l, knee_r = PAIRS[6]
    assert MOVENET_JOINTS[knee_l - 2] == "left_knee"
    frames = poses(camera, T, j3, set(), np.random.default_rng(4), noise_px=0.0)
    for _, pose in frames:
        pose.uv[knee_r] = pose.uv[knee_l] + 1.0
    resolved = run(LeftRight(PAIRS, PoseModelParams()), frames)
    assert all(p.confidence[knee_l] == 0 and p.confidence[knee_r] == 0 for p in resolved)
    assert sum(p.confidence[PAIRS[2][0]] > 0 for p in resolved) >= 25  # shoulders


def test_a_pair_seen_on_one_side_only_is_dropped():
    camera, T = CAMERAS[1]
    frames = poses(camera, T, walk_3d(1.0, 30), set(), np.random.default_rng(5))
    wrist_l, wrist_r = PAIRS[4]
    for _, pose in frames:
        pose.confidence[wrist_r] = 0.1  # below min_keypoint_score
    resolved = run(LeftRight(PAIRS, PoseModelParams()), frames)
    assert all(p.confidence[wrist_l] == 0 for p in resolved)
