"""Descriptor matching: mutual nearest neighbours with the ratio test both ways."""

import numpy as np

from yowo_ego.features import KeyframeFeatures, match


def features(desc):
    return KeyframeFeatures(np.zeros((len(desc), 2)), desc.astype(np.float32), np.full(len(desc), np.nan))


def test_match_recovers_a_permutation_and_rejects_ambiguous_and_one_sided_pairs():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 100, (200, 128))
    perm = rng.permutation(200)
    b = a[perm] + rng.normal(0, 1.0, (200, 128))
    # b[0] gets a near-twin: the ratio test in b must drop a's match to it.
    b = np.vstack([b, b[0] + rng.normal(0, 0.5, 128)])
    # a[-1] gets a twin in a: b's best match is ambiguous from b's side.
    a = np.vstack([a, a[perm[1]] + rng.normal(0, 0.5, 128)])
    m = match(features(a), features(b))
    truth = dict(zip(perm, range(200)))
    assert all(truth.get(i) == j for i, j in m)
    matched_a = set(m[:, 0])
    assert perm[0] not in matched_a and perm[1] not in matched_a and 200 not in matched_a
    assert len(m) == 198  # every unambiguous point


def test_keypoint_depth_is_interpolated_and_rejected_on_edges():
    from yowo_ego.features import sample_depth

    v, u = np.mgrid[0:20, 0:30]
    depth = (2.0 + 0.01 * u + 0.005 * v).astype(np.float32)  # a slanted plane: 1 cm per pixel
    depth[:, 20:] = 4.0  # a depth edge at u = 19.5
    uv = np.array([[7.3, 5.6], [12.5, 10.5], [19.6, 5.0], [0.2, 0.2]])
    z = sample_depth(depth, uv, 0.03)
    assert np.allclose(z[:2], 2.0 + 0.01 * uv[:2, 0] + 0.005 * uv[:2, 1], atol=1e-5)
    assert np.isnan(z[2])  # on the edge
    assert np.isfinite(z[3])  # at the border: clamped, no crash


def test_keypoints_are_unbiased():
    """SIFT keypoints of Gaussian blobs sit at the blob centres (pixel centres at
    integer coordinates), within a few hundredths of a pixel."""
    from yowo_ego.features import FeatureExtractor

    v, u = np.mgrid[0:240, 0:320].astype(float)
    centres = np.array([(60.3, 50.7), (150.0, 120.0), (250.5, 180.25), (200.2, 60.6)])
    img = np.full(u.shape, 60.0)
    for cx, cy in centres:
        img += 150 * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2 * 3.0**2))
    f = FeatureExtractor()(img.astype(np.uint8), np.full(u.shape, 2.0, np.float32))
    nearest = np.array([f.uv[np.argmin(np.linalg.norm(f.uv - c, axis=1))] for c in centres])
    assert np.abs(nearest - centres).max() < 0.05
