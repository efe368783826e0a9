"""Separate gyro and accelerometer streams united as one IMU stream."""

import numpy as np

from yowo_ego.imu import ImuUniter


def test_accelerometer_is_interpolated_at_each_gyro_stamp_in_any_arrival_order():
    rng = np.random.default_rng(0)
    gyro_ns = np.arange(0, 2_000_000_000, 5_000_000)  # 200 Hz
    accel_ns = np.arange(1_000_000, 2_000_000_000, 16_000_000)  # 62.5 Hz, offset
    accel = lambda t: np.array([np.sin(t * 1e-9), 9.81 + 0.1 * t * 1e-9, np.cos(2 * t * 1e-9)])  # noqa: E731

    # A driver's two streams arrive interleaved, each in order, up to a few samples late.
    def arrival(ns):
        return np.maximum.accumulate(ns + rng.integers(0, 12_000_000, len(ns)))

    events = sorted(
        [(a, t, "g") for a, t in zip(arrival(gyro_ns), gyro_ns)]
        + [(a, t, "a") for a, t in zip(arrival(accel_ns), accel_ns)],
        key=lambda e: (e[0], e[2]),
    )
    events = [(t, kind) for _, t, kind in events]
    uniter, out = ImuUniter(), []
    for t, kind in events:
        out += uniter.add_gyro(int(t), (t, 0, 0)) if kind == "g" else uniter.add_accel(int(t), tuple(accel(t)))
    stamps = np.array([s for s, _, _ in out])
    assert np.all(np.diff(stamps) > 0)
    # Gyro samples before the first accelerometer sample pair with nothing; after the last, they wait.
    inside = gyro_ns[(gyro_ns >= accel_ns[0]) & (gyro_ns <= accel_ns[-1])]
    assert np.array_equal(stamps, inside) and uniter.unpaired == 1
    for s, w, a in out:
        assert w[0] == s
        # Linear between 16 ms samples of a slow signal: within a few 1e-4.
        assert np.allclose(a, accel(s), atol=3e-4), (s, a, accel(s))
