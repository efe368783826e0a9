import numpy as np
import pytest

from yowo_common.camera import EQUIDISTANT, CameraModel
from yowo_common.geometry import look_at


def grid_points(n=50, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.7, 0.7, n), rng.uniform(1.5, 6, n)])


def test_pinhole_projection_matches_K():
    cam = CameraModel.from_fov(640, 480, 90.0)
    assert cam.K[0, 0] == pytest.approx(320.0)
    uv, ok = cam.project([[0, 0, 2.0], [1.0, 0.5, 1.0], [0, 0, -1]])
    np.testing.assert_allclose(uv[0], [319.5, 239.5])
    np.testing.assert_allclose(uv[1], [319.5 + 320.0, 239.5 + 160.0])
    assert ok.tolist() == [True, True, False]


@pytest.mark.parametrize(
    "model,D",
    [
        ("plumb_bob", [-0.25, 0.07, 0.001, -0.0005, 0.0]),
        ("rational_polynomial", [-0.2, 0.05, 0, 0, 0, 0.01, 0.0, 0.0]),
        (EQUIDISTANT, [0.05, -0.01, 0.002, 0.0]),
    ],
)
def test_distortion_roundtrip(model, D):
    cam = CameraModel(640, 480, [[400, 0, 321.3], [0, 402, 238.7], [0, 0, 1]], D, model)
    P = grid_points()
    uv, _ = cam.project(P)
    ideal = cam.undistort_pixels(uv)
    expected = P[:, :2] / P[:, 2:] @ cam.K[:2, :2].T + cam.K[:2, 2]
    np.testing.assert_allclose(ideal, expected, atol=1e-3)
    np.testing.assert_allclose(cam.distort_pixels(expected), uv, atol=1e-6)  # and back
    rays = cam.bearings(uv)
    np.testing.assert_allclose(rays, P / np.linalg.norm(P, axis=1, keepdims=True), atol=1e-5)
    # No points (a keyframe without features): empty arrays, not OpenCV's None.
    uv, ok = cam.project(np.zeros((0, 3)))
    assert uv.shape == (0, 2) and ok.shape == (0,)


def test_project_world_uses_pose():
    cam = CameraModel.from_fov(640, 480, 60.0)
    T = look_at([1.0, 2.0, 3.0], [1.0, 4.0, 0.0])
    uv, ok = cam.project_world(T, [[1.0, 4.0, 0.0]])
    assert ok[0]
    np.testing.assert_allclose(uv[0], cam.K[:2, 2], atol=1e-9)


def test_problems_name_what_is_wrong():
    assert CameraModel.from_fov(640, 480, 60).problems() == []
    bad = CameraModel(640, 480, np.zeros((3, 3)))
    assert any("focal" in p for p in bad.problems())
    weird = CameraModel(640, 480, np.eye(3) * 300, [0.1, 0, 0, 0], "kannala_brandt_custom")
    assert any("not supported" in p for p in weird.problems())
    good = CameraModel.from_fov(640, 480, 60)
    assert any("last row 0 0 1" in p for p in CameraModel(640, 480, good.K.T).problems())  # transposed
    assert any("non-finite" in p for p in CameraModel(640, 480, good.K, [0.1, np.nan, 0, 0, 0]).problems())
    assert any(
        "D has 6 coefficients; plumb_bob takes 4 or 5" in p for p in CameraModel(640, 480, good.K, [0.1] * 6).problems()
    )
    assert any("equidistant takes 4" in p for p in CameraModel(640, 480, good.K, [0.1] * 5, "equidistant").problems())
    assert CameraModel(640, 480, good.K, [0.1, 0.01, 0, 0, 0.001, 0.1, 0, 0], "rational_polynomial").problems() == []


def test_rays_beyond_the_distortion_fold_are_outside_the_model():
    # k1 < 0 turns the radial mapping back at ~63 deg: a ray at 74 deg lands inside the image.
    cam = CameraModel(640, 480, [[442, 0, 319.5], [0, 440.6, 242.4], [0, 0, 1]], [-0.1034, 0.0025, 0, 0, 0])
    P = np.array(
        [
            [3.5 * np.cos(0.3), 3.5 * np.sin(0.3), 1.0],  # 74 deg off-axis
            [0.5, -0.3, 1.0],  # 30 deg
            [0.0, 0.0, -1.0],
        ]
    )  # behind
    uv, in_front = cam.project(P)
    assert cam.in_image(uv[:1]).all() and in_front[0]  # the fold: inside the image
    assert cam.within_model(P).tolist() == [False, True, False]
    assert CameraModel.from_fov(640, 480, 80.0).within_model(P).tolist() == [True, True, False]
