"""Bad ego input gives clear errors that name the topic and the frame's stamp;
colour/depth pairing."""

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from yowo_common.camera import CameraModel
from yowo_common.geometry import inv_se3, look_at, se3
from yowo_common.ros.bag import BagWriter
from yowo_common.rosconv import encode_color_jpeg, encode_depth_png
from yowo_ego.frames import FrameError, StampPairer, Undistorter, make_frame
from yowo_ego.odometry import MAP_RELOCALISED, TRACKED
from yowo_ego.pipeline import EgoMapper
from yowo_ego.recording import EgoRecording, find_ego_topics, read_ego_frames

CAM = CameraModel(64, 48, [[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
RGB = np.random.default_rng(0).integers(0, 256, (48, 64, 3)).astype(np.uint8)  # textured
DEPTH = np.full((48, 64), 2.0, np.float32)


def test_zero_K_is_rejected_naming_the_topic():
    with pytest.raises(ValueError, match=r"/ego/color/camera_info.*focal"):
        EgoMapper(CameraModel(64, 48, np.zeros((3, 3))), topic="/ego/color/camera_info")


@pytest.mark.parametrize(
    "color, depth, topic, what",
    [
        (RGB, np.full((48, 64), np.nan, np.float32), "/d", "valid depth"),
        (RGB, np.zeros((48, 64), np.float32), "/d", "valid depth"),
        (RGB, np.full((24, 32), 2.0, np.float32), "/d", "registered"),
        (np.full((24, 32, 3), 1, np.uint8), np.full((24, 32), 2.0, np.float32), "/c", "CameraInfo"),
        (RGB[..., 0], DEPTH, "/c", "H x W x 3"),
    ],
)
def test_unusable_frames_name_topic_stamp_and_problem(color, depth, topic, what):
    with pytest.raises(FrameError, match=rf"^{topic} @ 123 ns: .*{what}"):
        make_frame(123, color, depth, CAM, color_topic="/c", depth_topic="/d")


def test_frames_without_texture_are_tracked_by_depth_and_counted():
    # A blank and a smoothly shaded image (covered lens, a bare wall close up) with the depth
    # of a room corner: used, not rejected, and the run says how many there were.
    v, u = np.mgrid[0:48, 0:64]
    corner = np.where(u < 32, 1.5 + 0.02 * (32 - u), 1.5 + 0.02 * (u - 32)).astype(np.float32)
    blank = np.full((48, 64, 3), 100, np.uint8)
    shaded = np.tile(np.linspace(100, 140, 64).astype(np.uint8)[None, :, None], (48, 1, 3))
    mapper = EgoMapper(CAM)
    for k, color in enumerate((RGB, blank, shaded, RGB)):
        mapper.add(k + 1, color, corner)
    assert mapper.frames == 4 and not mapper.rejected and mapper.untextured == 2
    result = mapper.finish()
    assert result.stats["untextured_frames"] == 2
    assert any("2 frame(s) without texture" in w for w in result.warnings), result.warnings


def test_mapper_counts_rejected_frames_and_keeps_going():
    mapper = EgoMapper(CAM)
    with pytest.raises(FrameError):
        mapper.add(1, RGB, np.full((48, 64), np.nan, np.float32), "/c", "/d")
    mapper.add(2, RGB, DEPTH)
    with pytest.raises(FrameError, match="not after"):
        mapper.add(2, RGB, DEPTH)
    assert sum(mapper.rejected.values()) == 2 and mapper.frames == 1
    assert mapper.first_rejection["/d: too few valid depth pixels (need 5 %)"].startswith("/d @ 1 ns: ")
    with pytest.raises(ValueError, match="1 usable RGB-D frame"):
        mapper.finish()


def test_pairer_matches_stamps_and_drops_orphans():
    p = StampPairer(tolerance_ns=1000)
    assert p.add_color(10_000, "c0") == []
    assert p.add_depth(10_400, "d0") == [(10_000, "c0", "d0")]
    assert p.add_depth(20_000, "d1") == []  # its colour never comes
    assert p.add_color(30_000, "c2") == []
    assert p.add_depth(30_000, "d2") == [(30_000, "c2", "d2")]
    assert p.dropped == 1  # d1 is older than the last pair
    assert (
        p.problem("/c", "/d")
        == "1 /c / /d image(s) without a partner within 0.001 ms dropped, the first: /d @ 20000 ns"
    )
    assert StampPairer().problem("/c", "/d") == ""


def test_undistortion_moves_depth_without_blending():
    cam = CameraModel(64, 48, CAM.K, [0.3, 0.1, 0, 0, 0])  # pincushion: corners come from outside
    depth = np.full((48, 64), 3.0, np.float32)
    depth[:, 32:] = 1.0
    _, out = Undistorter(cam)(RGB, depth)
    values = np.unique(out[np.isfinite(out)])
    assert set(values.tolist()) <= {1.0, 3.0}  # nearest-neighbour: no mixed depths at the edge
    assert np.isnan(out[0, 0])  # pulled in from outside the image


def test_textureless_frame_is_tracked_by_depth_and_tracking_continues(renderer, ego_camera):
    """A uniform frame in the middle of a walk (covered lens): placed by its depth
    alone (the photometric term cannot match a blank image, so the map of the recent
    keyframes places it and the frame after it), counted, and the motion of it and of
    the frames after it stays right."""
    T0 = look_at((0.8, 0.9, 1.6), (3.5, 3.2, 0.7))
    step = se3(Rotation.from_euler("xyz", [0.0, 1.0, 0.0], degrees=True).as_matrix(), [0.02, 0.0, 0.04])
    mapper = EgoMapper(ego_camera)
    truth, results = [], []
    for i in range(8):
        T = T0 @ np.linalg.matrix_power(step, i)
        f = renderer.render(ego_camera, T)
        rgb = np.full_like(f.rgb, 128) if i == 4 else f.rgb
        results.append(mapper.add(i * 66_666_667, rgb, f.depth, "/c", "/d"))
        truth.append(inv_se3(T0) @ T)
    assert all(r.status in (TRACKED, MAP_RELOCALISED) for r in results) and mapper.tracker.breaks == 0
    assert mapper.untextured == 1 and not mapper.rejected
    for r, T in zip(results, truth):
        assert np.linalg.norm(r.T_odom_cam[:3, 3] - T[:3, 3]) < 0.003


def _write_bag(path, depth_missing_at=(), with_depth_topic=True):
    with BagWriter(path) as w:
        for i in range(5):
            h = Header(stamp=Time(sec=1, nanosec=i * 66_666_667), frame_id="ego")
            w.write("/ego/color/camera_info", CameraInfo(header=h, width=64, height=48, k=CAM.K.ravel().tolist()), i)
            w.write("/ego/color/image_raw/compressed", encode_color_jpeg(RGB, h), i)
            if with_depth_topic and i not in depth_missing_at:
                w.write("/ego/depth/image_raw/compressedDepth", encode_depth_png(DEPTH, h), i)


def test_colour_frame_without_depth_is_dropped_and_named(tmp_path):
    _write_bag(tmp_path / "bag", depth_missing_at=(2,))
    recording = EgoRecording(find_ego_topics(tmp_path / "bag"))
    stamps = [s for s, _, _ in read_ego_frames(tmp_path / "bag", recording)]
    assert stamps == [1_000_000_000 + i * 66_666_667 for i in (0, 1, 3, 4)]
    assert recording.problems == [
        f"1 /ego/color/image_raw/compressed / /ego/depth/image_raw/compressedDepth "
        f"image(s) without a partner within 5 ms dropped, the first: "
        f"/ego/color/image_raw/compressed @ {1_000_000_000 + 2 * 66_666_667} ns"
    ]


def test_recording_without_depth_names_the_missing_topic(tmp_path):
    _write_bag(tmp_path / "bag", with_depth_topic=False)
    with pytest.raises(ValueError, match=r"no ego camera: missing depth /ego/depth/image_raw"):
        find_ego_topics(tmp_path / "bag")
