"""Synthetic agent keypoint tracks seen by known CMCs (for the CMC tests)."""

import numpy as np

from yowo_cmc.keypoint_tracks import CameraTracks, KeypointTrack
from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at

HEIGHT = 1.75


def ceiling_camera(x, y, target, z=3.0, hfov=80.0, D=None):
    cam = CameraModel.from_fov(640, 480, hfov)
    if D is not None:
        cam.D = np.asarray(D, float)
    return cam, look_at([x, y, z], [*target, 1.0])


def loop_walk(center, radius, period_s=20.0):
    cx, cy = center
    rx, ry = radius
    return lambda t: np.array(
        [cx + rx * np.sin(2 * np.pi * t / period_s), cy + ry * np.sin(4 * np.pi * t / period_s + 0.3)]
    )


def observe(cams, walk, duration_s, rate_hz=10.0, offsets_s=None, sigma_px=0.0, visible=None, seed=0, start_ns=10**18):
    """CameraTracks of head top (0) and ground point (1) for each camera.
    `visible(name, xy)` says whether a camera can see the agent at xy (walls)."""
    rng = np.random.default_rng(seed)
    out = []
    for i, (name, (cam, T)) in enumerate(cams.items()):
        rate = rate_hz[name] if isinstance(rate_hz, dict) else rate_hz
        off = 0.0 if offsets_s is None else offsets_s[i]
        t = np.arange(off, duration_s, 1.0 / rate)
        stamps = start_ns + np.round(t * 1e9).astype(np.int64)
        xy = np.array([walk(tt) for tt in t])
        tracks = {}
        for kp, z in ((0, HEIGHT), (1, 0.0)):
            P = np.column_stack([xy, np.full(len(t), z)])
            uv, front = cam.project_world(T, P)
            ok = front & cam.in_image(uv)
            if visible is not None:
                ok &= np.array([visible(name, p) for p in xy])
            uv = uv + rng.normal(size=uv.shape) * sigma_px
            tracks[kp] = KeypointTrack(stamps[ok], uv[ok], np.full(ok.sum(), 0.9))
        out.append(CameraTracks(name, cam, tracks, int(round(1e9 / rate))))
    return out
