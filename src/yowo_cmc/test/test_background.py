import numpy as np

from yowo_cmc.background import BackgroundSampler


def test_median_removes_a_moving_agent_and_memory_stays_bounded():
    rng = np.random.default_rng(0)
    scene = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    bg = BackgroundSampler(period_s=1.0, max_frames=21)
    for k in range(200):
        frame = scene.copy()
        x = (k * 3) % 60
        frame[10:40, x : x + 4] = (255, 128, 0)  # the agent, somewhere else each second
        stamp = k * 500_000_000
        if bg.wants(stamp):
            bg.add(stamp, frame)
    assert len(bg.frames) <= 21 and bg.count >= 30
    np.testing.assert_array_equal(bg.image(), scene)


def test_the_background_is_the_per_pixel_median_of_the_samples():
    rng = np.random.default_rng(1)
    for n in (7, 8):  # odd and even counts (the mean of the middle two, truncated)
        bg = BackgroundSampler(period_s=1.0)
        frames = [rng.integers(0, 256, (6, 5, 3), dtype=np.uint8) for _ in range(n)]
        for k, f in enumerate(frames):
            bg.add(k * 1_000_000_000, f)
        expected = np.array(
            [[[int(np.median([f[y, x, c] for f in frames])) for c in range(3)] for x in range(5)] for y in range(6)],
            dtype=np.uint8,
        )
        np.testing.assert_array_equal(bg.image(), expected)
