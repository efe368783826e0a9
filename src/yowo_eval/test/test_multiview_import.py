"""`yowo import-multiview` on a tiny Pose2Sim-style session the test writes (a calibration
TOML, OpenPose BODY_25B JSON frames with a bystander, a short video): K, distortion,
reference poses, stamps, keypoint ids, confidences and the derived ids 0/1 come back from
the recording field by field; bad input is named without a traceback."""

import json
import re

import cv2
import numpy as np
import pytest

from yowo_bringup.cli import main
from yowo_cmc.params import PoseModelParams
from yowo_cmc.pose_keypoints import ground_point, head_top
from yowo_common import topics
from yowo_common.geometry import inv_se3, se3
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import camera_info_to_model, decode_color, stamp_to_ns
from yowo_eval.ground_truth import read_ground_truth
from yowo_eval.multiview_import import START_NS, import_multiview
from yowo_eval.multiview_readers import FORMATS, joint_ids

W, H = 160, 120
CAMS = {
    "cam_01": dict(
        K=[[150.0, 0, 79.5], [0, 151.0, 60.25], [0, 0, 1]],
        D=[-0.05, 0.01, 0.001, -0.002],
        rvec=[1.7, 0.2, -0.3],
        tvec=[0.3, 0.9, 2.9],
    ),
    "cam_02": dict(
        K=[[140.0, 0, 81.0], [0, 139.5, 58.0], [0, 0, 1]],
        D=[0.02, -0.03, 0.0, 0.0005],
        rvec=[1.3, 1.6, -1.2],
        tvec=[-0.1, 0.8, 3.1],
    ),
}
JOINTS = FORMATS["BODY_25B"]


def toml_text() -> str:
    out = []
    for name, c in CAMS.items():
        out += [
            f"[{name}]",
            f'name = "{name}"',
            f"size = [ {W}.0, {H}.0]",
            f"matrix = {c['K']}",
            f"distortions = {c['D']}",
            f"rotation = {c['rvec']}",
            f"translation = {c['tvec']}",
            "fisheye = false",
            "",
        ]
    return "\n".join(out + ["[metadata]", "adjusted = false", "error = 0.0", ""])


def skeleton(x0: float, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """A standing person's BODY_25B joints (uv, confidence) around column x0; the left
    small toe is not found (OpenPose's 0, 0, 0)."""
    rel = {
        "nose": (0, 12),
        "left_eye": (2, 10),
        "right_eye": (-2, 10),
        "left_ear": (4, 11),
        "right_ear": (-4, 11),
        "left_shoulder": (8, 25),
        "right_shoulder": (-8, 25),
        "left_elbow": (10, 40),
        "right_elbow": (-10, 40),
        "left_wrist": (11, 52),
        "right_wrist": (-11, 52),
        "left_hip": (5, 55),
        "right_hip": (-5, 55),
        "left_knee": (5, 78),
        "right_knee": (-5, 78),
        "left_ankle": (5, 100),
        "right_ankle": (-5, 100),
        "neck": (0, 22),
        "head_top": (0, 3),
        "left_big_toe": (8, 106),
        "left_small_toe": (0, 0),
        "left_heel": (4, 104),
        "right_big_toe": (-8, 106),
        "right_small_toe": (-10, 105),
        "right_heel": (-4, 104),
    }
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
                people.append({"person_id": [-1], "pose_keypoints_2d": []})  # OpenPose: a body not estimated
            (d / f"{cam}.{f:04d}.json").write_text(json.dumps({"version": 1.3, "people": people}))
    if video:
        (root / "videos").mkdir()
        for cam in ("cam01", "cam02"):
            out = cv2.VideoWriter(str(root / "videos" / f"{cam}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (W, H))
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
            uv, conf = skeleton(80.0, f)  # always the agent, never the bystander at x0 = 20
            got = {k.id: (k.x, k.y, k.confidence) for k in msg.keypoints}
            assert ids["left_small_toe"] not in got  # not found: left out
            for j, n in enumerate(JOINTS):
                if n != "left_small_toe":
                    assert np.allclose(got[ids[n]], (*uv[j], conf[j]), atol=1e-4), (name, f, n)
            assert [ids[n] for n in ("nose", "right_ankle", "neck", "right_heel")] == [2, 18, 19, 27]
            joints = dict(zip(JOINTS, zip(uv, conf)))
            top = head_top(joints, p.joint_score)
            assert np.allclose(got[0], top, atol=1e-4)  # ears' rule: above the ears' midpoint
            assert got[0][1] < uv[JOINTS.index("left_ear")][1]
            joints |= {"left_foot_index": joints["left_big_toe"], "right_foot_index": joints["right_big_toe"]}
            ground = ground_point(joints, p.joint_score, p.ankle_to_ground)
            assert np.allclose(got[1], ground, atol=1e-4)  # the feet's contact points' mean
            assert np.isclose(got[1][1], np.mean([104, 104, 106, 106]) + 5.0, atol=1e-3)


def test_videos_become_cmc_images(tmp_path):
    write_session(tmp_path / "s", frames=3, video=True)
    bag = tmp_path / "bag"
    s = import_multiview(tmp_path / "s", bag, videos=True)
    assert s.fps == pytest.approx(30.0)  # from the videos (no Config.toml)
    images = [(topic, msg) for topic, _, msg in read_messages(bag, [topics.cmc_image_topics("cam_01")[1]])]
    assert len(images) == 3
    for f, (_, msg) in enumerate(images):
        rgb = decode_color(msg)
        assert (
            rgb.shape == (H, W, 3) and abs(float(rgb.mean()) - (40 + 60 * f)) < 10
        )  # mp4v and JPEG are lossy; frames are 60 apart
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
    (tmp_path / "s" / "calibration" / "Calib_test.toml").write_text(
        toml_text().replace("matrix = [[150.0", "matrix = [[-1")
    )
    code, err = run_cli(capsys, tmp_path / "s", "-o", tmp_path / "b4", "--fps", "30")
    assert code == 2 and "[cam_01]" in err and "focal lengths" in err


def write_caliscope(root, cams: dict | None = None) -> tuple:
    """A caliscope session: config.toml ([cam_N]: 3x3 rotation, world -> camera) and
    recordings/r/HOLISTIC/xy_HOLISTIC.csv with two frames per camera at its own capture
    times: pose landmarks 0 (nose), 7/8 (ears), 11/12 (shoulders), 29-32 (heels, foot indices), a hand point
    (101) and a face point (502)."""
    cams = cams or {0: CAMS["cam_01"], 3: CAMS["cam_02"]}
    lines = ["CreationDate = 2023-05-06T11:12:27", "fps_recording = 24", ""]
    for port, c in cams.items():
        R = cv2.Rodrigues(np.array(c["rvec"]))[0]
        lines += [
            f"[cam_{port}]",
            f"port = {port}",
            f"size = [ {W}, {H},]",
            f"matrix = {c['K']}",
            f"distortions = {c['D'] + [0.001]}",
            f"translation = {c['tvec']}",
            f"rotation = {R.tolist()}",
            "ignore = false",
            "",
        ]
    lines += ["[cam_7]", "port = 7", "ignore = false", ""]  # not posed yet: left out
    (root / "recordings" / "r" / "HOLISTIC").mkdir(parents=True)
    (root / "config.toml").write_text("\n".join(lines))
    points = {
        0: (80, 20),
        7: (84, 19),
        8: (76, 19),
        11: (88, 30),
        12: (72, 30),
        29: (84, 104),
        30: (76, 104),
        31: (88, 106),
        32: (72, 106),
        101: (95, 60),
        502: (81, 22),
    }
    times = {0: (100.000, 100.041), 3: (100.013, 100.055)}
    rows = ["sync_index,port,frame_index,frame_time,point_id,img_loc_x,img_loc_y,obj_loc_x,obj_loc_y"]
    for port in cams:
        for f, t in enumerate(times[port]):
            rows += [f"{f},{port},{f},{t},{pid},{x + f},{y},," for pid, (x, y) in points.items()]
    csv = root / "recordings" / "r" / "HOLISTIC" / "xy_HOLISTIC.csv"
    csv.write_text("\n".join(rows) + "\n")
    return csv, points, times


def test_caliscope_round_trip(tmp_path, capsys):
    csv, points, times = write_caliscope(tmp_path / "cs")
    bag = tmp_path / "bag"
    code, err = run_cli(capsys, csv, "-o", bag)  # the calibration found above the table
    assert code == 0, err
    gt = read_ground_truth(bag)
    assert sorted(gt.cameras) == ["cam_0", "cam_3"]
    for name, c in (("cam_0", CAMS["cam_01"]), ("cam_3", CAMS["cam_02"])):
        T_cam_world = se3(cv2.Rodrigues(np.array(c["rvec"]))[0], np.array(c["tvec"]))
        assert np.allclose(gt.cameras[name], inv_se3(T_cam_world), atol=1e-9)
    ids = joint_ids("BLAZEPOSE")
    msgs = {}
    for topic, _, msg in read_messages(bag):
        msgs.setdefault((topic, msg.header.frame_id), []).append(msg)
    for name, port in (("cam_0", 0), ("cam_3", 3)):
        (info, *_), kps = (
            msgs[(topics.cmc_info_topic(name), f"{name}_optical_frame")],
            msgs[(topics.cmc_keypoints_topic(name), f"{name}_optical_frame")],
        )
        cam = camera_info_to_model(info)
        assert np.allclose(cam.D[:5], CAMS["cam_01" if port == 0 else "cam_02"]["D"] + [0.001])
        # stamped by each camera's own capture times, from the earliest of all
        assert [stamp_to_ns(m.header.stamp) for m in kps] == [START_NS + round((t - 100.0) * 1e9) for t in times[port]]
        for f, m in enumerate(kps):
            got = {k.id: (k.x, k.y) for k in m.keypoints}
            assert got[ids["nose"]] == (80.0 + f, 20.0) and got[ids["left_ear"]] == (84.0 + f, 19.0)
            assert got[103] == (95.0 + f, 60.0) and got[504] == (81.0 + f, 22.0)  # hand, face: id + 2
            assert got[0][1] < 19.0 and 104.0 < got[1][1] < 107.0  # head top, ground point
            assert len(got) == len(points) + 2


def test_caliscope_bad_input_is_named(tmp_path, capsys):
    csv, _, _ = write_caliscope(tmp_path / "cs")
    text = csv.read_text()
    csv.write_text(text.replace("img_loc_x", "x"))
    code, err = run_cli(capsys, csv, "-o", tmp_path / "b0")
    assert code == 2 and "xy_HOLISTIC.csv: no column img_loc_x" in err
    csv.write_text(text.replace("\n1,3,", "\n1,5,", 1))
    code, err = run_cli(capsys, csv, "-o", tmp_path / "b1")
    assert code == 2 and "keypoints of camera(s) [5]" in err and "config.toml does not pose" in err
    assert not (tmp_path / "b1").exists()
    csv.write_text(text)
    cfg = tmp_path / "cs" / "config.toml"
    cfg.write_text(
        re.sub(r"rotation = \[\[.*\]\]", "rotation = [[2.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]", cfg.read_text(), count=1)
    )
    code, err = run_cli(capsys, csv, "-o", tmp_path / "b2")
    assert code == 2 and "[cam_0]" in err and "rotation" in err


def test_as_a_detector_publishes_them_and_a_declared_skeleton_restores_the_derived_points(tmp_path):
    """--as-detector writes BODY_25B's own numbering + 2 without ids 0 and 1; a tracker that
    declares body25b derives from them the same head top and ground point the importer does."""
    from yowo_cmc.keypoint_input import frame_from_msg
    from yowo_cmc.skeletons import load_skeleton

    write_session(tmp_path / "s", frames=2)
    import_multiview(tmp_path / "s", tmp_path / "derived", fps=25.0)
    import_multiview(tmp_path / "s", tmp_path / "raw", fps=25.0, as_detector=True)

    def frames(bag):
        return [frame_from_msg(m) for t, _, m in read_messages(bag) if t.endswith("/agent_keypoints")]

    skeleton, p = load_skeleton("body25b", "test"), PoseModelParams()
    for derived, raw in zip(frames(tmp_path / "derived"), frames(tmp_path / "raw"), strict=True):
        assert 0 not in raw.ids and 1 not in raw.ids
        names = [skeleton.joints[int(i) - 2] for i in raw.ids]
        assert names == [n for n in JOINTS if n != "left_small_toe"]  # the detector's order, unfound left out
        done = skeleton.complete(raw, p)
        for k in (0, 1):
            np.testing.assert_allclose(done.uv[done.ids == k], derived.uv[derived.ids == k], atol=1e-4)
