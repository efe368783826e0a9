import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at
from yowo_sim.detector import DetectorSpec, detect
from yowo_sim.walk import WalkSpec, plan_walk

L_SHAPE = Polygon([(0, 0), (8, 0), (8, 3), (3, 3), (3, 8), (0, 8)])


def test_walk_visits_targets_inside_free_space_with_pauses():
    targets = [(7, 1.5), (1.5, 7), (1.5, 1.5)]
    spec = WalkSpec(speed_mps=1.0, pause_s=2.0, long_pause_s=5.0)
    walk = plan_walk(L_SHAPE.buffer(-0.3), (0.5, 0.5), targets, spec, np.random.default_rng(0))
    free = L_SHAPE.buffer(-0.25)
    assert all(free.covers(Point(p)) for p in walk.xy[::10])
    for t in targets:
        assert np.min(np.linalg.norm(walk.xy - t, axis=1)) < 1e-6
    step = np.linalg.norm(np.diff(walk.xy, axis=0), axis=1) * 100.0
    assert step.max() < 1.0 * 1.05  # never faster than the walking speed
    standing_s = np.sum(step < 1e-9) / 100.0
    assert standing_s == pytest.approx(3 * 2.0 + 5.0, abs=0.2)  # the pauses and one long stop


def test_ego_pose_is_at_the_head():
    walk = plan_walk(
        L_SHAPE.buffer(-0.3), (0.5, 0.5), [(7, 1.5)], WalkSpec(agent_height_m=1.8), np.random.default_rng(1)
    )
    for t in np.linspace(0, walk.duration_s, 17):
        T = walk.ego_pose_at(t)
        xy, _, _ = walk.state_at(t)
        np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-9)
        head_top = np.array([*xy, 1.8])
        assert 0.08 < np.linalg.norm(T[:3, 3] - head_top) < 0.2
        assert T[2, 2] < 0.0  # optical axis points below the horizon (pitch down)


def test_detector_noise_free_matches_projection_and_occlusion():
    cam = CameraModel(640, 480, [[400, 0, 320.5], [0, 401, 240.2], [0, 0, 1]], [-0.2, 0.05, 0, 0, 0])
    T = look_at([0, 0, 3.0], [3.0, 0, 0.8])
    kps = {0: np.array([3.0, 0.1, 1.75]), 1: np.array([3.0, 0.1, 0.0]), 2: np.array([-3.0, 0.0, 1.0])}
    quiet = DetectorSpec(sigma_px={0: 0.0, 1: 0.0}, sigma_body_px=0.0, miss_rate=0.0, outlier_rate=0.0)
    far = np.full((480, 640), 100.0, np.float32)
    det = detect(cam, T, kps, far, quiet, np.random.default_rng(0))
    assert det.ids.tolist() == [0, 1]  # id 2 is behind the camera
    expected, _ = cam.project_world(T, np.array([kps[0], kps[1]]))
    np.testing.assert_allclose(det.uv, expected, atol=1e-9)
    # A wall between camera and ground point hides it.
    wall = far.copy()
    u, v = np.round(expected[1]).astype(int)
    wall[v - 2 : v + 3, u - 2 : u + 3] = 1.0
    assert detect(cam, T, kps, wall, quiet, np.random.default_rng(0)).ids.tolist() == [0]


def test_detector_noise_statistics():
    cam = CameraModel.from_fov(640, 480, 80)
    T = look_at([0, 0, 3.0], [3.0, 0, 0.8])
    kps = {0: np.array([3.0, 0.1, 1.75]), 1: np.array([3.0, 0.1, 0.0])}
    spec = DetectorSpec(sigma_px={0: 1.0, 1: 3.0}, miss_rate=0.1, outlier_rate=0.0)
    rng = np.random.default_rng(3)
    errs = {0: [], 1: []}
    for _ in range(2000):
        d = detect(cam, T, kps, np.full((480, 640), 50.0, np.float32), spec, rng)
        for i, uv, uv0 in zip(d.ids, d.uv, d.uv_true):
            errs[int(i)].append(uv - uv0)
    assert np.std(errs[0]) == pytest.approx(1.0, rel=0.1)
    assert np.std(errs[1]) == pytest.approx(3.0, rel=0.1)
    assert len(errs[0]) / 2000 == pytest.approx(0.9, abs=0.03)
