"""The ROS-free keypoint tracker the node and the offline API both run: intrinsics from
CameraInfo, a file or a nominal model; validated frames; the background."""

import numpy as np
import pytest

from yowo_cmc.config import CmcParams
from yowo_cmc.keypoint_input import KeypointFrame
from yowo_cmc.keypoint_tracker import KeypointTracker
from yowo_common.camera import CameraModel
from yowo_common.intrinsics_io import camera_info_yaml

CAMERA = CameraModel(640, 480, [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
PERIOD_NS = 10**8


def _frame(k: int, x: float = 100.0) -> KeypointFrame:
    return KeypointFrame(
        10**18 + k * PERIOD_NS, np.array([0, 1]), np.array([[x, 50.0], [x + 10, 60.0]]), np.array([0.9, 0.8])
    )


def test_recorded_keypoints_are_validated_and_sampled_images_give_the_background():
    params = CmcParams()
    t = KeypointTracker(camera="c1", source="keypoints", params=params, has_images=True)
    assert t.wants_camera_info and t.detector is None and t.camera is None
    assert t.take_camera(CAMERA) == [] and not t.wants_camera_info
    assert t.take_keypoints(_frame(0)) is not None
    assert t.take_keypoints(_frame(0)) is None  # a stamp not after the previous one
    kept = t.take_keypoints(_frame(1, x=1e5))  # both keypoints far outside the image
    assert kept is not None and len(kept.ids) == 0
    assert "1 stamp not after the previous frame" in t.summary() and "invalid coordinates" in t.summary()
    # Only images a background period apart are asked for; their median is the background.
    period = round(params.background_period_s * 1e9)
    rng = np.random.default_rng(0)
    shades = []
    for k in range(5):
        stamp = 10**18 + k * period
        assert t.wants_image(stamp)
        shade = int(rng.integers(0, 255))
        shades.append(shade)
        assert t.take_image(stamp, lambda shade=shade: np.full((480, 640, 3), shade, np.uint8)) == ([], None)
        assert not t.wants_image(stamp + 1)
    assert t.background()[0, 0, 0] == int(np.median(shades))


def test_intrinsics_from_a_file_a_nominal_model_or_none():
    params = CmcParams()
    t = KeypointTracker(
        camera="c2", source="keypoints", params=params, has_images=False, camera_info=camera_info_yaml(CAMERA, "c2")
    )
    np.testing.assert_allclose(t.camera.K, CAMERA.K)
    assert not t.wants_camera_info
    bad = KeypointTracker(camera="c2", source="keypoints", params=params, has_images=False, camera_info="hello: [1")
    assert bad.camera is None and "camera 'c2': intrinsics file" in bad.problem and not bad.wants_camera_info
    # No intrinsics at all: a nominal model at the first image's size, once.
    nominal = KeypointTracker(camera="c3", source="keypoints", params=params, has_images=True, nominal=True)
    assert not nominal.wants_camera_info
    image = np.zeros((600, 800, 3), np.uint8)
    _, model = nominal.take_image(10**18, lambda: image)
    expected = CameraModel.from_fov(800, 600, params.nominal_hfov_deg)
    assert (model.width, model.height) == (800, 600) and np.allclose(model.K, expected.K)
    assert nominal.camera is model
    assert nominal.take_image(10**18 + 10**9, lambda: image)[1] is None
    blind = KeypointTracker(camera="c4", source="keypoints", params=params, has_images=False, nominal=True)
    assert "image size is unknown" in blind.problem and blind.take_image(10**18, lambda: image)[1] is None


def test_sources_that_need_images_say_so():
    with pytest.raises(ValueError, match="camera 'c5': source images needs the camera's images"):
        KeypointTracker(camera="c5", source="images", params=CmcParams(), has_images=False)
    with pytest.raises(ValueError, match="unknown source 'magic'"):
        KeypointTracker(camera="c5", source="magic", params=CmcParams(), has_images=True)
    t = KeypointTracker(camera="c5", source="images", params=CmcParams(), has_images=True)
    assert t.detector is not None and t.wants_image(0) and t.wants_camera_info
