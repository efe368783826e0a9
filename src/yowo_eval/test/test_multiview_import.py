"""`yowo import-multiview` on a tiny Pose2Sim-style session the test writes (a calibration
TOML, OpenPose BODY_25B JSON frames with a bystander, a short video): K, distortion,
reference poses, stamps, keypoint ids, confidences and the derived ids 0/1 come back from
the recording field by field; bad input is named without a traceback."""
import json

import cv2
import numpy as np
import pytest

from yowo_bringup.cli import main
from yowo_cmc.pose_model import PoseModelParams, ground_point, head_top
from yowo_common import topics
from yowo_common.geometry import inv_se3, se3
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import camera_info_to_model, decode_color, stamp_to_ns
from yowo_eval.ground_truth import read_ground_truth
from yowo_eval.multiview_import import FORMATS, START_NS, import_multiview, joint_ids

W, H = 160, 120
CAMS = {
    "cam_01": dict(K=[[150.0, 0, 79.5], [0, 151.0, 60.25], [0, 0, 1]], D=[-0.05, 0.01, 0.001, -0.002],
                   rvec=[1.7, 0.2, -0.3], tvec=[0.3, 0.9, 2.9]),
    "cam_02": dict(K=[[140.0, 0, 81.0], [0, 139.5, 58.0], [0, 0, 1]], D=[0.02, -0.03, 0.0, 0.0005],
                   rvec=[1.3, 1.6, -1.2], tvec=[-0.1, 0.8, 3.1]),
}
JOINTS = FORMATS["BODY_25B"]


def toml_text() -> str:
    out = []
    for name, c in CAMS.items():
        out += [f"[{name}]", f'name = "{name}"', f"size = [ {W}.0, {H}.0]", f"matrix = {c['K']}",
                f"distortions = {c['D']}", f"rotation = {c['rvec']}", f"translation = {c['tvec']}",
                "fisheye = false", ""]
    return "\n".join(out + ["[metadata]", "adjusted = false", "error = 0.0", ""])


def skeleton(x0: float, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """A standing person's BODY_25B joints (uv, confidence) around column x0; the left
    small toe is not found (OpenPose's 0, 0, 0)."""
    rel = {"nose": (0, 12), "left_eye": (2, 10), "right_eye": (-2, 10), "left_ear": (4, 11), "right_ear": (-4, 11),
           "left_shoulder": (8, 25), "right_shoulder": (-8, 25), "left_elbow": (10, 40), "right_elbow": (-10, 40),
           "left_wrist": (11, 52), "right_wrist": (-11, 52), "left_hip": (5, 55), "right_hip": (-5, 55),
           "left_knee": (5, 78), "right_knee": (-5, 78), "left_ankle": (5, 100), "right_ankle": (-5, 100),
           "neck": (0, 22), "head_top": (0, 3), "left_big_toe": (8, 106), "left_small_toe": (0, 0),
           "left_heel": (4, 104), "right_big_toe": (-8, 106), "right_small_toe": (-10, 105), "right_heel": (-4, 104)}
    uv = np.array([(x0 + dx + 0.5 * frame, dy + 5.0) for dx, dy in (rel[n] for n in JOINTS)])
    conf = np.round(np.linspace(0.5, 0.9, len(JOINTS)), 3)
    k = JOINTS.index("left_small_toe")
    uv[k], conf[k] = 0.0, 0.0
    return uv, conf


def write_session(root, frames: int = 3, video: bool = False):
    (root / "calibration").mkdir(parents=True)
    (root / "calibration" / "Calib_test.toml").write_text(toml_text())
    for cam in ("cam01", "cam02"):
        d = root / "pose" / f"{cam}_json"
        d.mkdir(parents=True)
        for f in range(frames):
            people = []
            # A bystander first and scored higher at the far left; the agent must stay the one
            # tracked from frame 0 (which is the higher-scored person there).
            for x0, scale in ((80.0, 1.0), (20.0, 1.05 if f else 0.5)):
                uv, conf = skeleton(x0, f)
                flat = np.column_stack([uv, np.minimum(conf * scale, 1.0)]).ravel()
                people.append({"person_id": [-1], "pose_keypoints_2d": [round(float(v), 4) for v in flat]})
            if f:
                people.reverse()
                people.append({"person_id": [-1], "pose_keypoints_2d": []})   # OpenPose: a body not estimated
            (d / f"{cam}.{f:04d}.json").write_text(json.dumps({"version": 1.3, "people": people}))
    if video:
        (root / "videos").mkdir()
        for cam in ("cam01", "cam02"):
            out = cv2.VideoWriter(str(root / "videos" / f"{cam}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0,
                                  (W, H))
            for f in range(frames):
                out.write(np.full((H, W, 3), 40 + 60 * f, np.uint8))
            out.release()


def test_session_round_trip(tmp_path):
    write_session(tmp_path / "s", frames=3)
    bag = tmp_path / "bag"
    s = import_multiview(tmp_path / "s", bag, fps=25.0)
    assert [c.name for c in s.cameras] == ["cam_01", "cam_02"]
    assert all(c.frames == 3 and c.with_agent == 3 and c.others == 3 for c in s.cameras)

    gt = read_ground_truth(bag)
    for name, c in CAMS.items():
        T_cam_world = se3(cv2.Rodrigues(np.array(c["rvec"]))[0], np.array(c["tvec"]))
        assert np.allclose(gt.cameras[name], inv_se3(T_cam_world), atol=1e-9)

    infos, kps = {}, {}
    for topic, _, msg in read_messages(bag):
        if topic.endswith("/camera_info"):
            infos.setdefault(msg.header.frame_id, []).append(msg)
        elif topic.endswith("/agent_keypoints"):
            kps.setdefault(msg.camera_name, []).append(msg)
    ids = joint_ids("BODY_25B")
    p = PoseModelParams()
    for name, c in CAMS.items():
        assert len(infos[f"{name}_optical_frame"]) == 3
        cam = camera_info_to_model(infos[f"{name}_optical_frame"][0])
        assert (cam.width, cam.height) == (W, H)
        assert np.allclose(cam.K, c["K"]) and np.allclose(cam.D, c["D"]) and cam.distortion_model == "plumb_bob"
        assert [stamp_to_ns(m.header.stamp) for m in kps[name]] == [START_NS + f * 40_000_000 for f in range(3)]
        for f, msg in enumerate(kps[name]):
            uv, conf = skeleton(80.0, f)        # always the agent, never the bystander at x0 = 20
            got = {k.id: (k.x, k.y, k.confidence) for k in msg.keypoints}
            assert ids["left_small_toe"] not in got       # not found: left out
            for j, n in enumerate(JOINTS):
                if n != "left_small_toe":
                    assert np.allclose(got[ids[n]], (*uv[j], conf[j]), atol=1e-4), (name, f, n)
            assert [ids[n] for n in ("nose", "right_ankle", "neck", "right_heel")] == [2, 18, 19, 27]
            joints = dict(zip(JOINTS, zip(uv, conf)))
            top = head_top(joints, p.joint_score)
            assert np.allclose(got[0], top, atol=1e-4)           # ears' rule: above the ears' midpoint
            assert got[0][1] < uv[JOINTS.index("left_ear")][1]
            joints |= {"left_foot_index": joints["left_big_toe"], "right_foot_index": joints["right_big_toe"]}
            ground = ground_point(joints, p.joint_score, p.ankle_to_ground)
            assert np.allclose(got[1], ground, atol=1e-4)        # the feet's contact points' mean
            assert np.isclose(got[1][1], np.mean([104, 104, 106, 106]) + 5.0, atol=1e-3)


def test_videos_become_cmc_images(tmp_path):
    write_session(tmp_path / "s", frames=3, video=True)
    bag = tmp_path / "bag"
    s = import_multiview(tmp_path / "s", bag, videos=True)
    assert s.fps == pytest.approx(30.0)           # from the videos (no Config.toml)
    images = [(topic, msg) for topic, _, msg in read_messages(bag, [topics.cmc_image_topics("cam_01")[1]])]
    assert len(images) == 3
    for f, (_, msg) in enumerate(images):
        rgb = decode_color(msg)
        assert rgb.shape == (H, W, 3) and abs(float(rgb.mean()) - (40 + 60 * f)) < 10   # mp4v and JPEG are lossy; frames are 60 apart
        assert stamp_to_ns(msg.header.stamp) == START_NS + round(f / 30.0 * 1e9)


def run_cli(capsys, *args):
    code = main(["import-multiview", *map(str, args)])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def test_bad_input_is_named(tmp_path, capsys):
    code, err = run_cli(capsys, tmp_path / "nope", "-o", tmp_path / "b0")
    assert code == 2 and "nope: no such folder" in err
    write_session(tmp_path / "s", frames=2)
    code, err = run_cli(capsys, tmp_path / "s", "-o", tmp_path / "b1")
    assert code == 2 and "no frame rate" in err and "--fps" in err
    code, err = run_cli(capsys, tmp_path / "s", "-o", tmp_path / "b2", "--fps", "30", "--keypoint-format", "COCO_17")
    assert code == 2 and "cam01.0000.json: person 0 has 25 joints; COCO_17 has 17" in err
    assert not (tmp_path / "b2").exists()
    (tmp_path / "s" / "pose" / "cam02_json" / "cam02.0001.json").write_text("{nope")
    code, err = run_cli(capsys, tmp_path / "s", "-o", tmp_path / "b3", "--fps", "30")
    assert code == 2 and "cam02.0001.json: not JSON" in err
    (tmp_path / "s" / "calibration" / "Calib_test.toml").write_text(toml_text().replace("matrix = [[150.0", "matrix = [[-1"))
    code, err = run_cli(capsys, tmp_path / "s", "-o", tmp_path / "b4", "--fps", "30")
    assert code == 2 and "[cam_01]" in err and "focal lengths" in err
