"""`yowo import-tum` on a tiny TUM RGB-D folder the test renders (a textured floor seen from
known poses): stamps, colour/depth association, depth scale, intrinsics and ground truth
come back from the recording; bad input is named without a traceback."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from yowo_bringup.cli import main
from yowo_common import topics
from yowo_common.ros.bag import list_topics, read_messages
from yowo_common.rosconv import camera_info_to_model, decode_color, decode_depth, pose_to_matrix, stamp_to_ns
from yowo_eval.ground_truth import read_ground_truth
from yowo_eval.tum_import import INTRINSICS, associate, import_tum

K_FR1 = np.array([[517.3, 0, 318.6], [0, 516.5, 255.3], [0, 0, 1]])


def camera_pose(t: float) -> np.ndarray:
    """T_world_cam (optical frame) 1.5 m above the floor z = 0, looking down at 60 deg, moving along x."""
    a = np.radians(60)
    R = np.column_stack(
        [[0, -1, 0], [-np.sin(a), 0, -np.cos(a)], [np.cos(a), 0, -np.sin(a)]]
    )  # x right, y down, z ahead
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, [0.2 * t, 0.0, 1.5]
    return T


def render_floor(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(RGB checkerboard of the floor, depth [m] along the optical axis) through K_FR1, no distortion."""
    u, v = np.meshgrid(np.arange(640), np.arange(480))
    rays = np.linalg.inv(K_FR1) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])  # z = 1 in the camera
    world = T[:3, :3] @ rays
    scale = -T[2, 3] / world[2]  # where each ray meets z = 0
    depth = np.where(scale > 0, scale, 0).reshape(480, 640)
    xy = T[:2, 3, None] + world[:2] * scale
    checker = ((np.floor(xy[0] / 0.1) + np.floor(xy[1] / 0.1)) % 2).reshape(480, 640)
    rgb = np.stack([checker * 200 + 30, checker * 100 + 60, 255 - checker * 200], axis=2).astype(np.uint8)
    return rgb, depth


RGB_STAMPS = ["1305031102.175304", "1305031102.211214", "1305031102.243211", "1305031102.275326"]
# depth 0 pairs with rgb 0 (15 ms), depth 1 with rgb 1 (12 ms), depth 2 with rgb 2 (7 ms; it is
# also 25 ms from rgb 3); rgb 3's other depth is 30 ms away: left out at the 0.02 s default.
DEPTH_STAMPS = ["1305031102.160407", "1305031102.223001", "1305031102.250000", "1305031102.305400"]


def write_sequence(folder, rgb_stamps=RGB_STAMPS, depth_stamps=DEPTH_STAMPS):
    (folder / "rgb").mkdir(parents=True)
    (folder / "depth").mkdir()
    t0 = float(rgb_stamps[0])
    for s in rgb_stamps:
        cv2.imwrite(
            str(folder / "rgb" / f"{s}.png"),
            cv2.cvtColor(render_floor(camera_pose(float(s) - t0))[0], cv2.COLOR_RGB2BGR),
        )
    for s in depth_stamps:
        depth = render_floor(camera_pose(float(s) - t0))[1]
        cv2.imwrite(str(folder / "depth" / f"{s}.png"), np.round(depth * 5000).astype(np.uint16))
    header = "# color images\n# file: 'rgbd_dataset_freiburg1_test.bag'\n# timestamp filename\n"
    (folder / "rgb.txt").write_text(header + "".join(f"{s} rgb/{s}.png\n" for s in rgb_stamps))
    (folder / "depth.txt").write_text(
        header.replace("color images", "depth maps") + "".join(f"{s} depth/{s}.png\n" for s in depth_stamps)
    )
    lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    gt = {}
    for k in range(12):  # 100 Hz mocap, from before the first image to after the last
        s = f"{1305031102.16 + 0.01 * k:.4f}"
        T = camera_pose(float(s) - t0)
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        lines.append(f"{s} {T[0, 3]:.4f} {T[1, 3]:.4f} {T[2, 3]:.4f} {q[0]:.6f} {q[1]:.6f} {q[2]:.6f} {q[3]:.6f}")
        gt[int(round(float(s) * 1e4)) * 100_000] = T
    (folder / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    return gt


def test_associate_is_tums_greedy_rule():
    ns = [int(round(float(s) * 1e9)) for s in RGB_STAMPS], [int(round(float(s) * 1e9)) for s in DEPTH_STAMPS]
    assert associate(*ns) == [(0, 0), (1, 1), (2, 2)]
    assert associate(*ns, max_difference_s=0.04) == [(0, 0), (1, 1), (2, 2), (3, 3)]
    # closest first: b=10 is 1 from a=11 and 2 from a=8, so 8 goes without a partner within 3
    assert associate([8, 11], [10, 13], max_difference_s=3e-9) == [(1, 0)]


def test_import_round_trips(tmp_path):
    seq = tmp_path / "rgbd_dataset_freiburg1_test"
    gt = write_sequence(seq)
    s = import_tum(seq, tmp_path / "bag")
    assert (s.frames, s.rgb_unmatched, s.depth_unmatched, s.gt_poses, s.camera) == (3, 1, 1, 12, "fr1")
    by_topic = {}
    for topic, log_ns, msg in read_messages(tmp_path / "bag"):
        by_topic.setdefault(topic, []).append((log_ns, msg))
    assert set(by_topic) == {topics.EGO_COLOR[1], topics.EGO_DEPTH[1], topics.EGO_INFO, topics.GT_EGO_POSE}
    # Stamps exact to the nanosecond (decimal seconds, no float rounding); the depth of a
    # pair carries its colour frame's stamp, so the ego mapper's stamp pairing joins them.
    want = [1305031102_175304000, 1305031102_211214000, 1305031102_243211000]
    for topic in (topics.EGO_COLOR[1], topics.EGO_DEPTH[1], topics.EGO_INFO):
        assert [stamp_to_ns(m.header.stamp) for _, m in by_topic[topic]] == want, topic
        assert [t for t, _ in by_topic[topic]] == want
    t0 = float(RGB_STAMPS[0])
    for k, ((_, color), (_, depth), (_, info)) in enumerate(
        zip(*(by_topic[t] for t in (topics.EGO_COLOR[1], topics.EGO_DEPTH[1], topics.EGO_INFO)))
    ):
        assert bytes(color.data) == (seq / "rgb" / f"{RGB_STAMPS[k]}.png").read_bytes()  # lossless
        rgb, _ = render_floor(camera_pose(float(RGB_STAMPS[k]) - t0))
        assert np.array_equal(decode_color(color), rgb)
        # Depth in metres: the depth file of the pair (DEPTH_STAMPS[k]), 1/5000 m per unit,
        # stored in mm by the compressedDepth encoding.
        _, true_depth = render_floor(camera_pose(float(DEPTH_STAMPS[k]) - t0))
        got = decode_depth(depth)
        valid = true_depth > 0
        assert np.array_equal(np.isfinite(got), valid)
        assert np.abs(got[valid] - true_depth[valid]).max() < 0.0006
        cam = camera_info_to_model(info)
        assert (cam.width, cam.height, cam.distortion_model) == (640, 480, "plumb_bob")
        assert np.allclose(cam.K, K_FR1) and np.allclose(cam.D, INTRINSICS["fr1"][1])
    # Ground truth: every mocap pose at its own stamp, as groundtruth.txt has it.
    poses = {stamp_to_ns(m.header.stamp): pose_to_matrix(m.pose) for _, m in by_topic[topics.GT_EGO_POSE]}
    assert sorted(poses) == sorted(gt)
    for stamp, T in gt.items():
        assert np.allclose(poses[stamp][:3, 3], T[:3, 3], atol=1e-4) and np.allclose(
            poses[stamp][:3, :3], T[:3, :3], atol=1e-5
        )
    # The evaluation reads it as the ego trajectory; the pose is the optical frame's: the
    # imported depth back-projected through the CameraInfo's K and the ground-truth pose
    # at the frame's stamp lands on the rendered floor (z = 0).
    truth = read_ground_truth(tmp_path / "bag")
    assert truth.ego is not None and len(truth.ego.stamps_ns) == 12 and not truth.cameras
    _, depth_msg = by_topic[topics.EGO_DEPTH[1]][0]
    d = decode_depth(depth_msg)
    v, u = np.nonzero(np.isfinite(d))
    P = np.linalg.inv(K_FR1) @ np.stack([u, v, np.ones(len(u))]) * d[v, u]
    T = poses[min(poses, key=lambda g: abs(g - stamp_to_ns(depth_msg.header.stamp)))]
    world_z = (T[:3, :3] @ P + T[:3, 3:])[2]
    assert np.abs(world_z).max() < 0.005
    assert {t.name for t in list_topics(tmp_path / "bag") if t.latched} == set()


def test_camera_choice_and_overrides(tmp_path):
    seq = tmp_path / "rgbd_dataset_freiburg3_test"
    write_sequence(seq, RGB_STAMPS[:2], DEPTH_STAMPS[:2])
    s = import_tum(seq, tmp_path / "fr3")
    assert s.camera == "fr3"
    s = import_tum(seq, tmp_path / "ros", camera="ros", intrinsics=(500, 501, 320, 240), max_frames=1)
    info = [m for t, _, m in read_messages(tmp_path / "ros") if t == topics.EGO_INFO]
    assert s.frames == 1 and len(info) == 1 and s.camera == "ros with overrides"
    cam = camera_info_to_model(info[0])
    assert np.allclose(cam.K, [[500, 0, 320], [0, 501, 240], [0, 0, 1]]) and not cam.D.any()


def run_cli(capsys, *args):
    code = main(["import-tum", *map(str, args)])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def test_bad_input_is_named(tmp_path, capsys):
    code, err = run_cli(capsys, tmp_path / "nope", "-o", tmp_path / "b0")
    assert code == 2 and "nope: no such folder" in err
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"x")
    code, err = run_cli(capsys, tmp_path / "photos", "-o", tmp_path / "b1")
    assert code == 2 and "not a TUM RGB-D sequence folder" in err

    seq = tmp_path / "rgbd_dataset_freiburg1_bad"
    write_sequence(seq)
    (seq / "depth.txt").rename(seq / "depth.old")
    code, err = run_cli(capsys, seq, "-o", tmp_path / "b2")
    assert code == 2 and "missing depth.txt" in err
    (seq / "depth.old").rename(seq / "depth.txt")

    (seq / "rgb" / f"{RGB_STAMPS[1]}.png").write_bytes(b"not a png")
    code, err = run_cli(capsys, seq, "-o", tmp_path / "b3")
    assert code == 2 and f"rgb/{RGB_STAMPS[1]}.png: not a readable image" in err
    assert not (tmp_path / "b3").exists()  # no half recording left behind
    (seq / "rgb" / f"{RGB_STAMPS[1]}.png").unlink()
    code, err = run_cli(capsys, seq, "-o", tmp_path / "b4")
    assert code == 2 and f"rgb/{RGB_STAMPS[1]}.png: missing (listed in rgb.txt)" in err

    cv2.imwrite(str(seq / "depth" / f"{DEPTH_STAMPS[0]}.png"), np.zeros((480, 640), np.uint8))
    code, err = run_cli(capsys, seq, "-o", tmp_path / "b5")
    assert code == 2 and "16-bit single-channel PNG" in err and DEPTH_STAMPS[0] in err

    with open(seq / "groundtruth.txt", "a") as f:
        f.write("1305031102.3 1 2 3\n")
    code, err = run_cli(capsys, seq, "-o", tmp_path / "b6")
    assert code == 2 and "groundtruth.txt:15: expected 'timestamp tx ty tz qx qy qz qw'" in err

    other = tmp_path / "my_walk"
    write_sequence(other)
    code, err = run_cli(capsys, other, "-o", tmp_path / "b7")
    assert code == 2 and "cannot tell the Kinect from the folder name" in err and "--camera" in err
    assert run_cli(capsys, other, "-o", tmp_path / "b8", "--camera", "fr2")[0] == 0
    code, err = run_cli(capsys, other, "-o", tmp_path / "b8", "--camera", "fr2")
    assert code == 2 and "already exists" in err


@pytest.mark.parametrize(
    "name,kinect", [("rgbd_dataset_freiburg2_pioneer_360", "fr2"), ("fr1_desk", "fr1"), ("tum_fr3_office", "fr3")]
)
def test_kinect_from_the_sequence_name(tmp_path, name, kinect):
    from yowo_eval.tum_import import camera_for

    (tmp_path / name).mkdir()
    assert camera_for(tmp_path / name)[0] == kinect


def test_yowo_bench_keeps_the_tum_section():
    from yowo_eval.bench_report import keep_sections

    old = (
        "# BENCHMARKS\n\nold tables\n\n<!-- graph-speed:begin -->\nspeed\n<!-- graph-speed:end -->\n\n"
        "<!-- tum-rgbd:begin -->\n## TUM\nATE\n<!-- tum-rgbd:end -->\n"
    )
    new = keep_sections(old, "# BENCHMARKS\n\nnew tables\n")
    assert "old tables" not in new and new.startswith("# BENCHMARKS\n\nnew tables\n")
    assert new.count("<!-- tum-rgbd:begin -->\n## TUM\nATE\n<!-- tum-rgbd:end -->") == 1
    assert new.index("speed") < new.index("## TUM")
    assert keep_sections("no sections", "fresh") == "fresh"


def test_bench_tum_table_sits_beside_published_numbers_in_its_own_section(tmp_path):
    from pathlib import Path

    from yowo_eval.graph_bench import replace_section
    from yowo_eval.tum_bench import published_cell, short_name, tum_markdown

    assert short_name(Path("/data/rgbd_dataset_freiburg1_desk")) == "fr1_desk"
    assert short_name(Path("my_walk")) == "my_walk"
    assert published_cell("fr1_desk") == "0.021 DVO-SLAM<br>0.020 ElasticFusion<br>0.016 ORB-SLAM2 RGB-D"
    assert published_cell("my_walk") == "-"
    case = {
        "sequence": "fr1_desk",
        "frames": 573,
        "recording_s": 23.4,
        "ego_ate_m": 0.0291,
        "ego_ate_max_m": 0.07,
        "ratio": 3.1,
        "exit": 0,
        "resources": {"ego_mapper": {"cpu_s": 95.2, "wall_s": 80.0, "peak_rss_mb": 1500.0}},
    }
    row = next(line for line in tum_markdown([case], "c").splitlines() if line.startswith("| fr1_desk"))
    assert row.startswith("| fr1_desk | 573 | 23.4 | 0.0291 | 0.0700 | 0.021 DVO-SLAM") and row.endswith(
        "| 3.10 | 95 / 1500 |"
    )
    failed = tum_markdown([{**case, "ego_ate_m": None, "ego_ate_max_m": None, "exit": 1, "resources": {}}], "c")
    assert "| - (exit 1) | - |" in failed
    doc = tmp_path / "BENCHMARKS.md"
    doc.write_text("# B\n\n<!-- graph-speed:begin -->\nspeed\n<!-- graph-speed:end -->\n")
    replace_section(doc, tum_markdown([case], "first"), "tum-rgbd")
    replace_section(doc, tum_markdown([{**case, "ego_ate_m": 0.02}], "second"), "tum-rgbd")
    text = doc.read_text()
    assert text.count("<!-- tum-rgbd:begin -->") == 1 and "second" in text and "first" not in text
    assert "| 0.0200 |" in text and text.index("speed") < text.index("tum-rgbd:begin")


def test_bench_tum_names_a_missing_sequence_folder_and_runs_nothing(tmp_path, capsys):
    code = main(["bench-tum", str(tmp_path / "nope"), "-o", str(tmp_path / "out")])
    assert code == 2 and f"no such sequence folder: {tmp_path / 'nope'}" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
