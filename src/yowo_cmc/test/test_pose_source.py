"""The pose-model source on rendered video (the real model, never mocked): the
simulator's agent is found in every camera, its head top and ground point land near
their true projections, and a camera showing nobody falls back to the model-free
detector."""

import numpy as np
import pytest

from yowo_bringup.offline import read_cmc_tracks
from yowo_bringup.run import cmc_source
from yowo_cmc.params import DetectorParams, PeopleParams, PoseModelParams
from yowo_cmc.pose_source import PoseOrDetectorSource
from yowo_common.camera import CameraModel
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import camera_info_to_model, points_to_array, pose_to_matrix, stamp_to_ns
from yowo_common.topics import GT_AGENT_KEYPOINTS, parse_cmc_topic, parse_gt_cmc_pose_topic
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset


@pytest.fixture(scope="module")
def video_only(tmp_path_factory):
    """A tiny recording with CMC images and no recorded keypoints."""
    bag = tmp_path_factory.mktemp("pose") / "tiny_video"
    generate(get_preset("tiny", cmc_keypoints=False), 2, bag)
    return bag


def true_projections(bag):
    """camera -> {stamp: (2, 2) pixels of keypoints 0 and 1}, from the ground truth."""
    poses, models, agent, stamps = {}, {}, {}, {}
    for topic, _, msg in read_messages(bag):
        if topic == GT_AGENT_KEYPOINTS:
            agent[stamp_to_ns(msg.header.stamp)] = points_to_array([p.position for p in msg.poses])[:2]
        elif parse_gt_cmc_pose_topic(topic):
            poses[parse_gt_cmc_pose_topic(topic)] = pose_to_matrix(msg.pose)
        elif (parse_cmc_topic(topic) or ("", ""))[1] == "camera_info":
            name = parse_cmc_topic(topic)[0]
            models.setdefault(name, camera_info_to_model(msg))
            stamps.setdefault(name, []).append(stamp_to_ns(msg.header.stamp))
    return {n: {s: models[n].project_world(poses[n], agent[s])[0] for s in stamps[n] if s in agent} for n in models}


def test_auto_uses_the_pose_model_when_no_keypoints_were_recorded():
    images = {"/cmc/a/image_raw/compressed", "/cmc/a/camera_info"}
    assert cmc_source("a", images)[0] == "pose"
    assert cmc_source("a", images | {"/cmc/a/agent_keypoints"})[0] == "keypoints"
    assert cmc_source("a", images, "images")[0] == "images"


def keypoint_errors(bag, k: int) -> dict[str, np.ndarray]:
    """camera -> pixel errors of keypoint k (0 head top, 1 ground point) the pose source emitted."""
    tracks = {t.name: t for t in read_cmc_tracks(bag, "pose")}
    truth = true_projections(bag)
    assert tracks.keys() == truth.keys()
    for name, cam in tracks.items():
        assert any(i >= 2 for i in cam.tracks), f"{name}: no body joints"
    return {
        name: np.array(
            [np.linalg.norm(uv - truth[name][s][k]) for s, uv in zip(cam.tracks[k].stamps_ns, cam.tracks[k].uv)]
        )
        for name, cam in tracks.items()
    }


def test_the_agent_is_found_in_every_camera_near_its_true_ground_point(video_only):
    # The ground point, derived from the ankles, is up to 10 px off in one view of these
    # 320 x 240 images of a person ~100 px tall; a wrong joint table or a flipped axis gives tens.
    for name, err in keypoint_errors(video_only, 1).items():
        assert len(err) >= 10 and np.median(err) < 12.0, (name, len(err), np.median(err))


# Known regression (tracked in #17): on the human-looking agent (769c1f1) the model puts
# the shoulders' midpoint 2.6 % of the projected height too high and the ears' 2.8 % too
# low on cam00, so the derived head top is 7.7 % (10 px) low there (cam01 4.7 %, cam02
# 1.4 %); the capsule agent gave 3-5 px. Strict: this fails once the head top is right again.
@pytest.mark.xfail(strict=True, reason="head top 10 px off on cam00 with the human-looking agent (#17)")
def test_the_head_top_lands_near_its_true_projection(video_only):
    for name, err in keypoint_errors(video_only, 0).items():
        assert len(err) >= 10 and np.median(err) < 6.0, (name, len(err), np.median(err))


def test_a_camera_showing_nobody_falls_back_to_the_model_free_detector():
    cam = CameraModel.from_fov(320, 240, 70.0)
    source = PoseOrDetectorSource("empty", PoseModelParams(), 5, DetectorParams(), 300, PeopleParams())
    assert source.set_camera(cam) == []
    rng = np.random.default_rng(0)
    wall = rng.integers(90, 110, (240, 320, 3), dtype=np.uint8)
    for i in range(30):
        assert source.push(1_000_000_000 + i * 100_000_000, wall) == []
    assert not source.uses_pose
    source.flush()
    assert source.summary().startswith("source: model-free detector (pose model movenet: people in 0 of 30")


def test_an_unusable_pose_model_is_named_and_the_model_free_detector_serves():
    source = PoseOrDetectorSource(
        "c9", PoseModelParams(model="no_such_model"), 5, DetectorParams(), 300, PeopleParams()
    )
    assert source.pose is None and "camera 'c9': pose model unavailable" in source.problem
    assert "no_such_model" in source.problem
    source.set_camera(CameraModel.from_fov(320, 240, 70.0))
    assert source.push(1_000_000_000, np.zeros((240, 320, 3), np.uint8)) == []
    assert source.summary().startswith("source: model-free detector (camera 'c9': pose model unavailable")
