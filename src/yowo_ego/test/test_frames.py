"""Bad ego input gives clear errors that name the topic; colour/depth pairing."""
import numpy as np
import pytest

from yowo_common.camera import CameraModel
from yowo_ego.frames import FrameError, StampPairer, Undistorter, make_frame
from yowo_ego.pipeline import EgoMapper

CAM = CameraModel(64, 48, [[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
RGB = np.full((48, 64, 3), 100, np.uint8)
DEPTH = np.full((48, 64), 2.0, np.float32)


def test_zero_K_is_rejected_naming_the_topic():
    with pytest.raises(ValueError, match=r"/ego/color/camera_info.*focal"):
        EgoMapper(CameraModel(64, 48, np.zeros((3, 3))), topic="/ego/color/camera_info")


@pytest.mark.parametrize("color, depth, topic, what", [
    (RGB, np.full((48, 64), np.nan, np.float32), "/d", "valid depth"),
    (RGB, np.zeros((48, 64), np.float32), "/d", "valid depth"),
    (RGB, np.full((24, 32), 2.0, np.float32), "/d", "registered"),
    (np.full((24, 32, 3), 1, np.uint8), np.full((24, 32), 2.0, np.float32), "/c", "CameraInfo"),
    (RGB[..., 0], DEPTH, "/c", "H x W x 3"),
])
def test_unusable_frames_name_topic_and_problem(color, depth, topic, what):
    with pytest.raises(FrameError, match=rf"^{topic}: .*{what}"):
        make_frame(0, color, depth, CAM, color_topic="/c", depth_topic="/d")


def test_mapper_counts_rejected_frames_and_keeps_going():
    mapper = EgoMapper(CAM)
    with pytest.raises(FrameError):
        mapper.add(1, RGB, np.full((48, 64), np.nan, np.float32), "/c", "/d")
    mapper.add(2, RGB, DEPTH)
    with pytest.raises(FrameError, match="not after"):
        mapper.add(2, RGB, DEPTH)
    assert sum(mapper.rejected.values()) == 2 and mapper.frames == 1
    with pytest.raises(ValueError, match="1 usable RGB-D frame"):
        mapper.finish()


def test_pairer_matches_stamps_and_drops_orphans():
    p = StampPairer(tolerance_ns=1000)
    assert p.add_color(10_000, "c0") == []
    assert p.add_depth(10_400, "d0") == [(10_000, "c0", "d0")]
    assert p.add_depth(20_000, "d1") == []          # its colour never comes
    assert p.add_color(30_000, "c2") == []
    assert p.add_depth(30_000, "d2") == [(30_000, "c2", "d2")]
    assert p.dropped == 1                            # d1 is older than the last pair


def test_undistortion_moves_depth_without_blending():
    cam = CameraModel(64, 48, CAM.K, [0.3, 0.1, 0, 0, 0])   # pincushion: corners come from outside
    depth = np.full((48, 64), 3.0, np.float32)
    depth[:, 32:] = 1.0
    _, out = Undistorter(cam)(RGB, depth)
    values = np.unique(out[np.isfinite(out)])
    assert set(values.tolist()) <= {1.0, 3.0}        # nearest-neighbour: no mixed depths at the edge
    assert np.isnan(out[0, 0])                       # pulled in from outside the image
