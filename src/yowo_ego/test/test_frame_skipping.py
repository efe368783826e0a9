"""Motion-adaptive frame rate (OdometryParams.skip, issue #19): on the tiny simulator walk
with its IMU, dense odometry leaves frames out where the gyro sees a slow head and tracks
every frame of a fast turn; every frame keeps its stamp with an interpolated pose, and the
trajectory stays as accurate as tracking all; a skipped frame is tracked after all when
the frame after it does not track, or when it ends the walk. Without the IMU every frame
is tracked. Real tracking throughout (no mocks)."""

from dataclasses import replace

import numpy as np
import pytest

from yowo_common.geometry import inv_se3, rotation_angle_deg
from yowo_common.trajectory import Trajectory
from yowo_ego.config import EgoParams
from yowo_ego.imu import ImuBuffer
from yowo_ego.odometry import INTERPOLATED, SKIPPED, TRACKED
from yowo_ego.pipeline import EgoMapper, map_recording
from yowo_ego.recording import EgoRecording, find_ego_topics, read_ego_frames
from yowo_eval.ground_truth import read_ground_truth
from yowo_eval.metrics import associate, ate


def _params(skip: bool) -> EgoParams:
    p = EgoParams()
    return replace(p, odometry=replace(p.odometry, skip=replace(p.odometry.skip, enabled=skip)))


@pytest.fixture(scope="module")
def walk(tiny_bag):
    """The tiny walk's frames with its IMU, its ground truth per frame, and per frame the
    true rotation [deg] from the frame before."""
    recording = EgoRecording(find_ego_topics(tiny_bag))
    recording.imu = ImuBuffer()
    frames = list(read_ego_frames(tiny_bag, recording))
    gt = read_ground_truth(tiny_bag).ego
    i_est, i_ref = associate(np.array([f[0] for f in frames]), gt.stamps_ns, 1_000_000)
    assert len(i_est) == len(frames)
    T_true = gt.T_world_cam[i_ref]
    turn = np.r_[0.0, [rotation_angle_deg(a, b) for a, b in zip(T_true[:-1, :3, :3], T_true[1:, :3, :3])]]
    return recording, frames, gt, T_true, turn


def _map(walk, skip: bool, imu: bool = True):
    recording, frames, gt, _, _ = walk
    recording.imu.bias = np.zeros(3)  # the tracker's running estimate starts afresh
    r = map_recording(frames, recording.camera, _params(skip), imu=recording.imu if imu else None)
    return (
        r,
        ate(Trajectory(r.stamps_ns, r.trajectories["odometry"]), gt).rmse_m,
        ate(Trajectory(r.stamps_ns, r.T_world_cam), gt).rmse_m,
    )


@pytest.fixture(scope="module")
def runs(walk):
    """(result, ATE of the odometry stage, of the final trajectory) with the IMU, frames
    skipped and all tracked."""
    return {skip: _map(walk, skip) for skip in (True, False)}


def test_slow_stretches_skip_frames_and_fast_turns_track_every_one(walk, runs):
    turn = walk[4]
    result = runs[True][0]
    skipped = result.tracking == INTERPOLATED
    assert result.stats["skipped_frames"] == skipped.sum() and SKIPPED not in result.tracking
    # Slow stretches (under 1 deg a frame) leave a good share of their frames out ...
    slow = turn < 1.0
    assert slow.sum() > 20 and skipped[slow].mean() > 0.3, (slow.sum(), skipped[slow].mean())
    # ... at most every other one (max_frames = 1), never the first. Fewer frames through
    # dense odometry (its CPU time varies too much between runs to compare on a walk this short).
    assert not skipped[0] and not (skipped[1:] & skipped[:-1]).any()
    assert skipped.sum() >= 0.2 * len(skipped)
    assert result.stats["keyframes"] <= runs[False][0].stats["keyframes"] + 2
    # A fast turn is tracked frame by frame: the gyro sees it coming, so no skipped frame
    # turned more than the threshold (plus the gyro's noise) since the frame before.
    limit = EgoParams().odometry.skip.max_rotation_deg
    assert (turn > limit + 0.5).sum() >= 5  # the walk turns its head
    assert not (skipped & (turn > limit + 0.5)).any(), np.flatnonzero(skipped & (turn > limit + 0.5))


def test_every_frame_keeps_its_stamp_and_the_trajectory_its_accuracy(walk, runs):
    frames, T_true = walk[1], walk[3]
    (skipping, odo_skip, final_skip), (every, odo_every, final_every) = runs[True], runs[False]
    assert np.array_equal(skipping.stamps_ns, [f[0] for f in frames])
    assert np.array_equal(skipping.stamps_ns, every.stamps_ns)
    assert skipping.stats["breaks"] == every.stats["breaks"] == 0
    # Measured (tiny s0, skipping / every frame): odometry 2.4 / 2.6 mm, final 4.3 / 4.5 mm. A
    # skipped frame's pose off its tracked neighbours' path, or a lost fast turn, costs centimetres.
    for stage_skip, stage_every in ((odo_skip, odo_every), (final_skip, final_every)):
        assert stage_skip < 0.012 and stage_skip < 1.3 * stage_every + 0.002, (stage_skip, stage_every)
    # Interpolated frames lie on the path between their neighbours: the step from the tracked
    # frame before is a millimetre off the true one (a cubic through four tracked frames;
    # linear between two: 2.2 mm), where holding the last tracked pose would be off by the
    # whole step.
    T_est = skipping.trajectories["odometry"]
    k = np.flatnonzero(skipping.tracking == INTERPOLATED)
    d_est = np.array([inv_se3(T_est[j - 1]) @ T_est[j] for j in k])
    d_true = np.array([inv_se3(T_true[j - 1]) @ T_true[j] for j in k])
    error_m = np.linalg.norm(d_est[:, :3, 3] - d_true[:, :3, 3], axis=1)
    step_m = np.linalg.norm(d_true[:, :3, 3], axis=1)
    assert step_m.mean() > 0.015  # measured 3.4 cm (errors 0.7 mm, at most 5.0)
    assert error_m.mean() < 0.0015 and error_m.max() < 0.008, (error_m.mean(), error_m.max())
    # The gyro shapes the turn in between: 0.02 deg on average, 0.21 at most (a slerp: 1.8).
    error_deg = [rotation_angle_deg(a[:3, :3], b[:3, :3]) for a, b in zip(d_est, d_true)]
    assert np.mean(error_deg) < 0.1 and np.max(error_deg) < 0.5, (np.mean(error_deg), np.max(error_deg))


def test_without_the_imu_every_frame_is_tracked(walk):
    result, _, final = _map(walk, skip=True, imu=False)
    assert result.stats["skipped_frames"] == 0 and INTERPOLATED not in result.tracking
    assert final < 0.012


def _until_skipped(walk):
    """An EgoMapper fed the walk until it skips a frame (not among the first two): (mapper,
    the skipped frame's result)."""
    recording, frames = walk[0], walk[1]
    recording.imu.bias = np.zeros(3)
    mapper = EgoMapper(recording.camera, imu=recording.imu)
    for stamp, rgb, depth in frames:
        result = mapper.add(stamp, rgb, depth)
        if result.status == SKIPPED and result.frame_index >= 2:
            return mapper, result
    pytest.fail("no frame skipped")


def test_a_skipped_frame_is_tracked_when_the_next_one_does_not_track(walk, darken):
    """The frame after a skipped one carries nothing to track (dark noise): the skipped frame
    is tracked after all, from its own images, with its measured pose."""
    mapper, skipped = _until_skipped(walk)
    i = skipped.frame_index
    mapper.add(*darken(walk[1][i + 1], np.random.default_rng(0)))
    tr, T_true = mapper.tracker, walk[3]
    assert tr.backfilled == 1 and tr.results[i].status == TRACKED
    assert len(tr.results) == i + 2 and tr.results[i + 1].status != TRACKED
    d_est = inv_se3(tr.results[i - 1].T_odom_cam) @ tr.results[i].T_odom_cam
    d_true = inv_se3(T_true[i - 1]) @ T_true[i]
    assert np.linalg.norm(d_est[:3, 3] - d_true[:3, 3]) < 0.003
    assert rotation_angle_deg(d_est[:3, :3], d_true[:3, :3]) < 0.2


def test_a_skipped_frame_that_ends_the_walk_is_tracked(walk):
    mapper, skipped = _until_skipped(walk)
    before = mapper.tracker.skipped
    result = mapper.finish()
    assert len(result.stamps_ns) == skipped.frame_index + 1 and result.tracking[-1] == TRACKED
    assert result.stats["skipped_frames"] == before - 1 and result.stats["backfilled_frames"] == 1
