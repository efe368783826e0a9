import numpy as np
import pytest

from yowo_eval import hloc_style
from yowo_fusion import scene_matching


@pytest.mark.parametrize(
    "detect",
    [lambda rgb: scene_matching.detect_features(rgb, "SIFT", 100)[0], lambda rgb: hloc_style.extract(rgb, 100).uv],
    ids=["scene", "hloc"],
)
def test_sift_keypoints_are_unbiased(detect):
    """SIFT keypoints of Gaussian blobs sit at the blob centres (pixel centres at integer
    coordinates): OpenCV's default upscaling shifts them by +0.25 px."""
    v, u = np.mgrid[0:240, 0:320].astype(float)
    centres = np.array([(60.3, 50.7), (150.0, 120.0), (250.5, 180.25), (200.2, 60.6)])
    img = np.full(u.shape, 60.0)
    for cx, cy in centres:
        img += 150 * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * 3.0**2))
    uv = detect(np.repeat(img.astype(np.uint8)[..., None], 3, axis=2))
    nearest = np.array([uv[np.argmin(np.linalg.norm(uv - c, axis=1))] for c in centres])
    assert np.abs(nearest - centres).max() < 0.05


def test_landmarks_claiming_one_feature_give_no_match_instead_of_an_opencv_error():
    """Texture-poor view: many landmarks find the same single keypoint. One feature serves
    one landmark, which leaves fewer points than PnP takes: None (the caller keeps its
    prior), not OpenCV's assertion (seen on the texture_poor benchmark scene)."""
    from yowo_common.camera import CameraModel

    v, u = np.mgrid[0:240, 0:320].astype(float)
    img = np.full(u.shape, 60.0)
    for cx, cy in [(100.0, 120.0)] + [(x, y) for x in (190.0, 240.0, 290.0) for y in (30.0, 80.0, 130.0, 180.0, 220.0)]:
        img += 150 * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * 3.0**2))
    rgb = np.repeat(img.astype(np.uint8)[..., None], 3, axis=2)
    uv, desc = scene_matching.detect_features(rgb, "SIFT", 100)
    assert len(uv) >= scene_matching.SceneMatchParams().min_inliers  # else match_scene stops before matching
    k = int(np.argmin(np.linalg.norm(uv - [100.0, 120.0], axis=1)))
    camera = CameraModel.from_fov(320, 240, 70.0)
    offsets = np.random.default_rng(0).uniform(-5, 5, (20, 2))  # 20 landmarks around the one blob
    rays = np.column_stack([(uv[k] + offsets - camera.K[:2, 2]) / camera.K[0, 0], np.ones(20)])
    landmarks = 2.0 * rays
    matches = scene_matching.match_scene(
        rgb, camera, np.eye(4), landmarks, np.repeat(desc[k][None], 20, axis=0), "SIFT"
    )
    assert matches is None


def test_matches_whose_pose_is_far_from_the_prior_are_not_kept():
    """A textured wall 4 m in front of the camera, its landmarks where they are, and a prior
    0.3 m to the side: every landmark still finds its own keypoint within the search radius
    (34 px off its predicted pixel) and PnP verifies the true pose. The matches cannot tell
    such a prior from a repeated pattern one period over: no match (the caller keeps the
    prior); with a looser gate the true pose is found."""
    from yowo_common.camera import CameraModel
    from yowo_common.geometry import se3

    rng = np.random.default_rng(1)
    v, u = np.mgrid[0:480, 0:640].astype(float)
    img = np.full(u.shape, 60.0)
    for cx, cy in rng.uniform([30, 30], [610, 450], (80, 2)):
        img += rng.uniform(80, 160) * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * rng.uniform(2, 5) ** 2))
    rgb = np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    uv, desc = scene_matching.detect_features(rgb, "SIFT", 400)
    camera = CameraModel.from_fov(640, 480, 70.0)
    landmarks = 4.0 * np.column_stack([(uv - camera.K[:2, 2]) / camera.K[0, 0], np.ones(len(uv))])
    prior = se3(np.eye(3), [0.3, 0.0, 0.0])
    assert scene_matching.match_scene(rgb, camera, prior, landmarks, desc, "SIFT") is None
    loose = scene_matching.match_scene(
        rgb, camera, prior, landmarks, desc, "SIFT", scene_matching.SceneMatchParams(max_prior_median_px=40.0)
    )
    assert loose is not None and len(loose.landmark) > 20
    assert np.linalg.norm(loose.T_world_cam[:3, 3]) < 0.01, loose.T_world_cam[:3, 3]
