"""Frame-to-frame RGB-D odometry on noise-free frames rendered by the simulator."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_common.geometry import look_at, rotation_angle_deg, se3
from yowo_ego.frames import RgbdFrame, make_frame
from yowo_ego.keyframe_tracker import KeyframeTracker
from yowo_ego.odometry import (
    LOST,
    MAP_RELOCALISED,
    Keyframe,
    OdometryEdge,
    OdometryParams,
    TrackResult,
    frames_between_keyframes,
)
from yowo_ego.rgbd_odometry import OdometryImages, RgbdOdometry, downsample, orthonormalize

# Looking across the room at two walls, the floor and a box.
T_START = look_at((0.8, 0.9, 1.6), (3.5, 3.2, 0.7))
FRAME_NS = 66_666_667  # 15 Hz


def _motion(euler_deg, t):
    return se3(Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix(), t)


def _track_step(renderer, ego_camera, motion):
    """Track one rendered frame after another taken `motion` later."""
    a = renderer.render(ego_camera, T_START)
    b = renderer.render(ego_camera, T_START @ motion)
    tracker = KeyframeTracker(ego_camera.K)
    tracker.track(make_frame(0, a.rgb, a.depth, ego_camera))
    return tracker.track(make_frame(FRAME_NS, b.rgb, b.depth, ego_camera))


@pytest.mark.parametrize(
    "motion",
    [
        _motion([0.0, 1.5, 0.0], [0.04, 0.0, 0.0]),  # side step while turning
        _motion([1.0, 0.0, 0.0], [0.0, 0.01, 0.067]),  # a walking step (1 m/s at 15 Hz) with a nod
        _motion([1.0, 4.0, 0.5], [0.0, 0.0, 0.0]),  # head turn, no translation
        _motion([-2.0, 3.0, 1.0], [0.03, -0.02, 0.05]),
    ],
    ids=["sidestep", "walk", "turn", "mixed"],
)
def test_noise_free_frame_to_frame_motion(renderer, ego_camera, motion):
    result = _track_step(renderer, ego_camera, motion)
    assert result.status != LOST
    T = result.T_odom_cam
    assert np.linalg.norm(T[:3, 3] - motion[:3, 3]) < 0.002
    assert rotation_angle_deg(T[:3, :3], motion[:3, :3]) < 0.1


def test_fast_turn_is_recovered_by_features(renderer, ego_camera):
    """35 deg between frames is outside the dense odometry's basin; the SIFT + PnP
    fall-back finds it and the dense refinement still lands on the true motion."""
    motion = _motion([0.0, 35.0, 0.0], [0.02, 0.0, 0.03])
    result = _track_step(renderer, ego_camera, motion)
    assert result.status != LOST
    assert np.linalg.norm(result.T_odom_cam[:3, 3] - motion[:3, 3]) < 0.01
    assert rotation_angle_deg(result.T_odom_cam[:3, :3], motion[:3, :3]) < 0.3


def test_blank_view_breaks_instead_of_inventing_motion(renderer, ego_camera):
    """Frames with nothing in common (a turn of 120 deg between them) must not be
    registered: the tracker starts a new segment and says so."""
    a = renderer.render(ego_camera, T_START)
    b = renderer.render(ego_camera, T_START @ _motion([0.0, 120.0, 0.0], [0.0, 0.0, 0.0]))
    tracker = KeyframeTracker(ego_camera.K)
    tracker.track(make_frame(0, a.rgb, a.depth, ego_camera))
    result = tracker.track(make_frame(FRAME_NS, b.rgb, b.depth, ego_camera))
    assert result.status == LOST and tracker.breaks == 1
    assert tracker.keyframes[-1].segment == 1 and tracker.edges[-1].kind == "break"


def test_downsampled_depth_ignores_dropouts_and_edges():
    depth = np.full((4, 4), 2.0, np.float32)
    depth[0, 0] = np.nan  # an isolated dropout: the block keeps its depth
    depth[2:, 2] = 1.0  # a depth edge inside the bottom-right block
    _, mm = downsample(RgbdFrame(0, np.zeros((4, 4, 3), np.uint8), depth), 2)
    assert mm[0, 0] == 2000 and mm[0, 1] == 2000 and mm[1, 0] == 2000
    assert mm[1, 1] == 0


def test_orthonormalize_keeps_chained_poses_rigid():
    rng = np.random.default_rng(0)
    T = np.eye(4)
    step = _motion([0.3, 1.0, -0.2], [0.01, 0.0, 0.05])
    for _ in range(2000):
        noisy = step.copy()
        noisy[:3, :3] += rng.normal(0, 1e-6, (3, 3)).astype(np.float32)  # float32-level noise, as Open3D returns
        T = orthonormalize(T @ noisy)
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)


def test_frames_between_keyframes_share_the_keyframe_correction():
    """Keyframe b was tracked 0.1 m / 2 deg off; after optimisation the frames
    between a and b take the correction in proportion to their time."""
    step = _motion([0.0, 2.0, 0.0], [0.0, 0.0, 0.5])
    tracked_b = _motion([0.0, 4.0, 0.0], [0.1, 0.0, 1.0])  # what tracking said
    true_b = step @ step  # what the optimisation found
    kfs = [Keyframe(i, 2 * i, 2 * i, np.eye(4), None, None, 0) for i in range(2)]
    results = [
        TrackResult(
            frame_index=i,
            stamp_ns=i,
            keyframe=k,
            T_kf_cam=T_kf,
            T_odom_cam=T,
            fitness=1.0,
            status="tracked",
            new_keyframe=new,
        )
        for i, k, T_kf, T, new in (
            (0, 0, np.eye(4), np.eye(4), True),
            (1, 0, step, step, False),  # midway, tracked right
            (2, 1, np.eye(4), tracked_b, True),
        )
    ]
    edges = [OdometryEdge(source=1, target=0, T_target_source=tracked_b, information=np.eye(6), kind="odometry")]
    T = frames_between_keyframes(results, edges, kfs, [np.eye(4), true_b])
    assert np.allclose(T[2], true_b)
    delta = true_b @ np.linalg.inv(tracked_b)
    half = se3((Rotation.from_matrix(delta[:3, :3]) ** 0.5).as_matrix(), 0.5 * delta[:3, 3])
    assert np.allclose(T[1], half @ step)


def test_low_overlap_result_far_from_the_prediction_is_ambiguous(ego_camera):
    # A whip turn's wrong minimum: 44 deg from the predicted motion at fitness 0.3.
    tracker = KeyframeTracker(ego_camera.K)
    predicted, settled = _motion([0.0, 44.0, 0.0], [0.0, 0.0, 0.0]), np.eye(4)
    assert tracker._ambiguous(settled, 0.3, predicted)
    assert not tracker._ambiguous(settled, 0.5, predicted)  # enough overlap
    assert not tracker._ambiguous(_motion([0.0, 40.0, 0.0], [0, 0, 0]), 0.3, predicted)  # near the prediction
    # Right after a lost frame (whose pose is a guess) no prediction vouches for little overlap.
    tracker._prev_result = TrackResult(
        frame_index=1,
        stamp_ns=FRAME_NS,
        keyframe=1,
        T_kf_cam=np.eye(4),
        T_odom_cam=np.eye(4),
        fitness=0.0,
        status=LOST,
        new_keyframe=True,
    )
    assert tracker._ambiguous(_motion([0.0, 40.0, 0.0], [0, 0, 0]), 0.3, predicted)
    assert not tracker._ambiguous(_motion([0.0, 40.0, 0.0], [0, 0, 0]), 0.5, predicted)


def _heading(h_deg: float, eye=(1.3, 1.7, 1.6)) -> np.ndarray:
    """T_world_cam at `eye` looking along heading h_deg, a little down."""
    h = np.radians(h_deg)
    return look_at(eye, np.asarray(eye) + [np.cos(h), np.sin(h), -0.4])


def _look_around(renderer, ego_camera, params, headings_deg, eye=(1.3, 1.7, 1.6)):
    """Track frames at 15 Hz turning on the spot through `headings_deg`: (the tracker, its
    last result, the last frame's true pose relative to the first's)."""
    tracker = KeyframeTracker(ego_camera.K, params)
    for k, h in enumerate(headings_deg):
        f = renderer.render(ego_camera, _heading(h, eye))
        result = tracker.track(make_frame(k * FRAME_NS, f.rgb, f.depth, ego_camera))
    return tracker, result, np.linalg.inv(_heading(headings_deg[0], eye)) @ _heading(headings_deg[-1], eye)


def test_an_untracked_whip_turn_is_placed_in_the_map_of_the_keyframes_before(renderer, ego_camera):
    """A look around the room, then 120 deg within one frame (nothing in common with the
    frame before): the frame's depth fits the keyframes' clouds at one heading, so it is a
    keyframe joined by a "map" edge at the true pose, not a break at a guess."""
    headings = [*range(0, 360, 10), 350 + 120]
    for enabled in (True, False):
        p = OdometryParams()
        tracker, result, T_true = _look_around(
            renderer, ego_camera, replace(p, maploc=replace(p.maploc, enabled=enabled)), headings
        )
        err_m = np.linalg.norm(result.T_odom_cam[:3, 3] - T_true[:3, 3])
        err_deg = rotation_angle_deg(result.T_odom_cam[:3, :3], T_true[:3, :3])
        if enabled:
            assert result.status == MAP_RELOCALISED and tracker.breaks == 0, tracker.map_failures
            assert tracker.edges[-1].kind == "map" and tracker.keyframes[-1].segment == 0
            assert err_m < 0.02 and err_deg < 0.5, (err_m, err_deg)
        else:
            assert result.status == LOST and tracker.breaks == 1 and err_deg > 30.0


def test_a_whip_turn_in_the_middle_of_a_square_room_is_not_placed_at_a_look_alike_heading(renderer, ego_camera):
    """At the centre of the square room, turned headings 90 deg apart see the same walls at
    the same distances: the map cannot tell them apart, so the frame is a break."""
    tracker, result, _ = _look_around(
        renderer, ego_camera, OdometryParams(), [*range(0, 360, 10), 350 + 120], eye=(2.0, 2.0, 1.6)
    )
    assert result.status == LOST and tracker.map_relocalised == 0
    assert "another heading fits almost as well" in tracker.map_failures[-1]


def test_constant_velocity_is_per_second_not_per_step(renderer, ego_camera):
    """After a step across a gap (frames rejected or missing), the next frame's prediction is
    the velocity over its own interval: a step of 10 frames' time is not replayed per frame."""
    walk = _motion([0.0, 10.0, 0.0], [0.0, 0.0, 0.30])  # 10 frames of 3 cm and 1 deg each, at once
    tracker = KeyframeTracker(ego_camera.K)
    for k, T in ((0, T_START), (10, T_START @ walk)):
        f = renderer.render(ego_camera, T)
        tracker.track(make_frame(k * FRAME_NS, f.rgb, f.depth, ego_camera))
    step = tracker._predicted_step(FRAME_NS * 1e-9)
    assert np.linalg.norm(step[:3, 3]) == pytest.approx(0.03, abs=0.003)
    assert rotation_angle_deg(np.eye(3), step[:3, :3]) == pytest.approx(1.0, abs=0.1)


def test_a_suspect_result_is_checked_by_the_other_cascade(renderer, ego_camera):
    """Hybrid's wrong minima on bare walls come with an RMSE far above the recent frames'.
    Here one frame's Hybrid result is made such a minimum (10 cm off, 10x the RMSE, less
    overlap): the other cascade runs from the same guess and its result is kept; on the
    frames before, whose RMSE is ordinary, it never runs."""
    step = _motion([0.0, 1.0, 0.0], [0.02, 0.0, 0.04])
    tracker = KeyframeTracker(ego_camera.K)
    real, calls, spoil = tracker.odometry.register, [], {"on": False}

    def register(source, target, init, cascade=("Hybrid",)):
        T, fit, rmse = real(source, target, init, cascade)
        calls.append((spoil["on"], cascade))
        if spoil["on"] and cascade == ("Hybrid",):
            return T @ se3(np.eye(3), [0.1, 0.0, 0.0]), fit - 0.1, rmse * 10
        return T, fit, rmse

    tracker.odometry.register = register
    for k in range(9):
        spoil["on"] = k == 8
        T = T_START @ np.linalg.matrix_power(step, k)
        f = renderer.render(ego_camera, T)
        result = tracker.track(make_frame(k * FRAME_NS, f.rgb, f.depth, ego_camera))
    truth = np.linalg.inv(T_START) @ T
    assert np.linalg.norm(result.T_odom_cam[:3, 3] - truth[:3, 3]) < 0.003
    assert tracker.suspect_frames == 1
    assert [c for on, c in calls if not on] == [("Hybrid",)] * 7  # one registration per ordinary frame
    assert ("PointToPlane", "Hybrid") in [c for on, c in calls if on]


def test_keyframe_images_are_packed_losslessly_in_about_half_their_bytes(renderer, ego_camera):
    """The tracker keeps its keyframes' images PNG-compressed; what it reads back is the
    downsampled frame bit for bit, and a moved keyframe shares them."""
    view = renderer.render(ego_camera, T_START)
    frame = make_frame(0, view.rgb, view.depth, ego_camera)
    tracker = KeyframeTracker(ego_camera.K)
    tracker.track(frame)
    kf = tracker.keyframes[0]
    color, depth_mm = downsample(frame, tracker.params.scale)
    assert np.array_equal(kf.color, color) and np.array_equal(kf.depth_mm, depth_mm)
    assert kf.image_bytes < 0.75 * (color.nbytes + depth_mm.nbytes), (kf.image_bytes, color.nbytes + depth_mm.nbytes)
    moved = kf.moved(se3(np.eye(3), [1.0, 0.0, 0.0]))
    assert moved.image_bytes == kf.image_bytes and np.array_equal(moved.depth_mm, depth_mm)
    assert moved.T_odom_cam[0, 3] == 1.0 and np.allclose(kf.T_odom_cam, np.eye(4))  # the first: odom origin
    raw = KeyframeTracker(ego_camera.K, replace(OdometryParams(), compress_keyframes=False))
    raw.track(frame)
    assert raw.keyframes[0].image_bytes == color.nbytes + depth_mm.nbytes


def test_fitness_counts_a_frame_with_little_depth_as_one_with_depth_almost_everywhere(renderer, ego_camera):
    """A Kinect sees depth in ~70 % of its pixels: a frame with depth in half of them,
    registered to itself, reaches the fitness a full frame has (Open3D's own: half of it);
    a frame with depth almost everywhere keeps Open3D's."""
    view = renderer.render(ego_camera, T_START)
    full = OdometryImages.of(make_frame(0, view.rgb, view.depth, ego_camera), 2)
    holed = view.depth.copy()
    holed[:, :320] = np.nan
    half = OdometryImages.of(make_frame(0, view.rgb, holed, ego_camera), 2)
    assert np.mean(full.depth_mm > 0) > 0.99 and np.mean(half.depth_mm > 0) == pytest.approx(0.5, abs=0.01)
    odometry = RgbdOdometry(ego_camera.K)
    fit_full = odometry.register(full.rgbd, full.rgbd, np.eye(4))[1]
    fit_half = odometry.register(half.rgbd, full.rgbd, np.eye(4))[1]
    assert 0.85 < fit_full <= 320 * 240 / (336 * 256)  # Open3D's: the padding cannot match
    assert fit_half == pytest.approx(odometry.params.full_depth_fraction * fit_full, abs=0.02)
