import numpy as np

from yowo_cmc.background import BackgroundSampler


def test_median_removes_a_moving_agent_and_memory_stays_bounded():
    rng = np.random.default_rng(0)
    scene = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    bg = BackgroundSampler(period_s=1.0, max_frames=21)
    for k in range(200):
        frame = scene.copy()
        x = (k * 3) % 60
        frame[10:40, x:x + 4] = (255, 128, 0)     # the agent, somewhere else each second
        stamp = k * 500_000_000
        if bg.wants(stamp):
            bg.add(stamp, frame)
    assert len(bg.frames) <= 21 and bg.count >= 30
    np.testing.assert_array_equal(bg.image(), scene)
