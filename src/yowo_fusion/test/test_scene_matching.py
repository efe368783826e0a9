import numpy as np
import pytest

from yowo_fusion import hloc_style, scene_matching


@pytest.mark.parametrize("detect", [lambda rgb: scene_matching.detect_features(rgb, "SIFT", 100)[0],
                                    lambda rgb: hloc_style.extract(rgb, 100).uv], ids=["scene", "hloc"])
def test_sift_keypoints_are_unbiased(detect):
    """SIFT keypoints of Gaussian blobs sit at the blob centres (pixel centres at integer
    coordinates): OpenCV's default upscaling shifts them by +0.25 px."""
    v, u = np.mgrid[0:240, 0:320].astype(float)
    centres = np.array([(60.3, 50.7), (150.0, 120.0), (250.5, 180.25), (200.2, 60.6)])
    img = np.full(u.shape, 60.0)
    for cx, cy in centres:
        img += 150 * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * 3.0 ** 2))
    uv = detect(np.repeat(img.astype(np.uint8)[..., None], 3, axis=2))
    nearest = np.array([uv[np.argmin(np.linalg.norm(uv - c, axis=1))] for c in centres])
    assert np.abs(nearest - centres).max() < 0.05
