"""Declared keypoint skeletons: formats by name or table, ids 0 and 1 derived from the named
joints, the noise classes of the group SfM, and declarations refused with the reason."""

from dataclasses import replace

import numpy as np
import pytest

from yowo_cmc.config import CmcParams
from yowo_cmc.group_bundle import residual_sigmas
from yowo_cmc.keypoint_input import KeypointFrame
from yowo_cmc.keypoint_tracker import KeypointTracker
from yowo_cmc.params import KeypointFormatParams, PoseModelParams
from yowo_cmc.pose_keypoints import derive_top_and_ground
from yowo_cmc.scene_graph import MAX_IDS
from yowo_cmc.skeletons import BODY_25, FORMATS, declared_skeletons, load_skeleton
from yowo_common.bundle import Observations
from yowo_common.camera import CameraModel

# An upright person in BODY_25 order (image y down): head at the top, feet at the bottom.
BODY_25_UV = {
    "nose": (320, 100),
    "neck": (320, 140),
    "right_shoulder": (300, 140),
    "left_shoulder": (340, 140),
    "right_elbow": (295, 190),
    "left_elbow": (345, 190),
    "right_wrist": (293, 235),
    "left_wrist": (347, 235),
    "mid_hip": (320, 240),
    "right_hip": (308, 240),
    "left_hip": (332, 240),
    "right_knee": (308, 320),
    "left_knee": (332, 320),
    "right_ankle": (308, 400),
    "left_ankle": (332, 400),
    "right_eye": (315, 95),
    "left_eye": (325, 95),
    "right_ear": (310, 100),
    "left_ear": (330, 100),
    "left_big_toe": (336, 412),
    "left_small_toe": (340, 410),
    "left_heel": (330, 405),
    "right_big_toe": (304, 412),
    "right_small_toe": (300, 410),
    "right_heel": (310, 405),
}


def _body25_frame(stamp_ns: int = 10**18) -> KeypointFrame:
    """As a detector publishes it: OpenPose's ids offset by 2, no ids 0 and 1."""
    ids = np.arange(len(BODY_25)) + 2
    uv = np.array([BODY_25_UV[n] for n in BODY_25], float)
    return KeypointFrame(stamp_ns, ids, uv, np.full(len(ids), 0.9))


def test_formats_by_name_alias_or_table_and_unknown_ones_refused(tmp_path):
    assert load_skeleton("BODY_25", "cam").name == "body25"
    assert load_skeleton("movenet", "cam") is FORMATS["coco17"]
    assert load_skeleton("mediapipe-holistic", "cam").noise_class(2 + 105) == "hand"
    assert load_skeleton("holistic", "cam").noise_class(2 + 504) == "face"
    assert load_skeleton("holistic", "cam").noise_class(2 + 11) == "body"
    assert load_skeleton("holistic", "cam").noise_class(0) == "head_top"
    with pytest.raises(ValueError, match="camera 'c7': unknown keypoint skeleton 'body26'"):
        load_skeleton("body26", "camera 'c7'")
    table = tmp_path / "robot.yaml"
    table.write_text("0: {name: left_shoulder, class: body}\n1: {name: beacon, class: antenna}\n")
    with pytest.raises(ValueError, match="id 1: class 'antenna' is not one of body, hand, face"):
        load_skeleton(str(table), "camera 'c7'")
    table.write_text("0: {name: left_shoulder}\n5: {name: left_thumb_tip, class: hand}\n")
    custom = load_skeleton(str(table), "camera 'c7'")
    assert custom.joints == {0: "left_shoulder", 5: "left_thumb_tip"} and custom.noise_class(7) == "hand"


def test_a_detectors_frame_gets_the_head_top_and_ground_point_its_joints_give():
    params = PoseModelParams()
    frame = _body25_frame()
    done = load_skeleton("body25", "cam").complete(frame, params)
    top, ground = derive_top_and_ground({n: (np.array(BODY_25_UV[n], float), 0.9) for n in BODY_25}, params)
    assert list(done.ids[:2]) == [0, 1] and list(done.ids[2:]) == list(frame.ids)
    np.testing.assert_allclose(done.uv[0], top[:2])
    np.testing.assert_allclose(done.uv[1], ground[:2])
    # Above the ears, and between the feet on the floor line of the toes and heels.
    assert done.uv[0][1] < 100 and abs(done.uv[0][0] - 320) < 1
    assert 404 < done.uv[1][1] < 413 and abs(done.uv[1][0] - 320) < 1
    # A detector's own 0 and 1 are kept; ids the skeleton does not know are left out.
    own = KeypointFrame(
        frame.stamp_ns,
        np.concatenate([[0, 99], frame.ids]),
        np.vstack([[[1.0, 2.0], [3.0, 4.0]], frame.uv]),
        np.concatenate([[0.5, 0.5], frame.confidence]),
    )
    kept = load_skeleton("body25", "cam").complete(own, params)
    assert list(kept.ids[:2]) == [1, 0] and 99 not in kept.ids
    np.testing.assert_allclose(kept.uv[1], [1.0, 2.0])
    # Without shoulders no head top is derivable, so none is invented.
    no_shoulders = np.isin(frame.ids - 2, [BODY_25.index("left_shoulder"), BODY_25.index("right_shoulder")])
    partial = KeypointFrame(
        frame.stamp_ns, frame.ids[~no_shoulders], frame.uv[~no_shoulders], frame.confidence[~no_shoulders]
    )
    assert 0 not in load_skeleton("body25", "cam").complete(partial, params).ids


def test_the_tracker_completes_a_declared_cameras_frames_only():
    camera = CameraModel(640, 480, [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
    params = replace(CmcParams(), keypoints=KeypointFormatParams(skeleton="", cameras=("c1=body25",)))
    declared = KeypointTracker(camera="c1", source="keypoints", params=params, has_images=False)
    plain = KeypointTracker(camera="c2", source="keypoints", params=params, has_images=False)
    declared.take_camera(camera)
    plain.take_camera(camera)
    assert {0, 1} <= set(declared.take_keypoints(_body25_frame()).ids.tolist())
    assert not {0, 1} & set(plain.take_keypoints(_body25_frame()).ids.tolist())


def test_declarations_that_cannot_work_are_refused_with_the_cameras_named():
    both = KeypointFormatParams(skeleton="coco17", cameras=("c2=body25",))
    with pytest.raises(ValueError, match=r"different keypoint skeletons \(c1: coco17, c2: body25, c3: coco17\)"):
        declared_skeletons(both, ["c1", "c2", "c3"])
    with pytest.raises(ValueError, match="'c9=body25': no camera 'c9'"):
        declared_skeletons(KeypointFormatParams(cameras=("c9=body25",)), ["c1", "c2"])
    with pytest.raises(ValueError, match="'c1:body25': expected CAMERA=SKELETON"):
        declared_skeletons(KeypointFormatParams(cameras=("c1:body25",)), ["c1", "c2"])
    assert set(declared_skeletons(KeypointFormatParams(skeleton="halpe26"), ["c1", "c2"])) == {"c1", "c2"}


def test_the_noise_classes_come_from_the_declared_skeleton():
    """Holistic hands (ids from 102) and body joints pool apart; undeclared, the id ranges
    put a BODY_25 foot (id 21) with the body and would do the same for any id below 100."""
    rng = np.random.default_rng(0)
    ids = np.repeat([2 + 11, 2 + 12, 2 + 105, 2 + 206], 200)  # two shoulders, a left and a right hand joint
    scale = np.where(ids < 100, 1.0, 6.0)
    residuals = rng.normal(size=(ids.size, 2)) * scale[:, None]
    ba = {
        "keys": np.arange(ids.size) * MAX_IDS + ids,
        "obs": Observations(np.zeros(ids.size, int), np.arange(ids.size), np.zeros((ids.size, 2)), np.ones(ids.size)),
        "residuals": residuals,
    }
    sigma = residual_sigmas(ba, (1, 2, 100, 500), load_skeleton("holistic", "cam"))
    assert sigma[13] == sigma[14] and sigma[107] == sigma[208]
    assert 4 < sigma[107] / sigma[13] < 9
