"""CMC-only calibration through the real multi-process graph: replay -> one keypoint
tracker per camera -> group SfM -> results, checked against ground truth."""

import json
import subprocess
import sys

import numpy as np
import yaml

from cmc_synthetic import ceiling_camera, loop_walk, observe
from e2e_helpers import write_keypoint_bag


def test_calibrate_cmc_graph(tmp_path, ros_env):
    cams = {
        "a1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "a2": ceiling_camera(4.7, 0.3, (2.5, 2.5), z=3.4),
        "a3": ceiling_camera(2.5, 4.7, (2.5, 2.3), D=[-0.15, 0.03, 0, 0, 0]),
        "b1": ceiling_camera(10.3, 0.3, (12.5, 2.5)),
        "b2": ceiling_camera(14.7, 4.7, (12.5, 2.5)),
    }

    def walk(t):
        return loop_walk((2.5 if t < 20 else 12.5, 2.5), (1.5, 1.2), 10.0)(t)

    room = {"a": lambda x: x < 5, "b": lambda x: x > 10}
    tracks = observe(
        cams,
        walk,
        40.0,
        sigma_px=0.7,
        visible=lambda n, xy: room[n[0]](xy[0]),
        seed=4,
        offsets_s=[0.0, 0.03, 0.05, 0.01, 0.07],
    )
    write_keypoint_bag(tmp_path / "rec", cams, tracks)
    out = tmp_path / "results"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "yowo_bringup.cli",
            "calibrate-cmc",
            str(tmp_path / "rec"),
            "-o",
            str(out),
            "--timeout",
            "120",
        ],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    doc = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    groups = {}
    for c in doc:
        groups.setdefault(c["group"], []).append(c["name"])
    assert sorted(map(sorted, groups.values())) == [["a1", "a2", "a3"], ["b1", "b2"]]
    # The intrinsics the group SfM used, as a full run writes them.
    for c in doc:
        model = cams[c["name"]][0]
        assert (c["image_width"], c["image_height"], c["distortion_model"]) == (model.width, model.height, "plumb_bob")
        assert np.allclose(c["K"], model.K, atol=1e-6) and np.allclose(c["distortion_coefficients"], model.D)
        assert c["clock_offset_s"] is None and set(c["keypoint_noise"]["sigma_px_by_keypoint_id"]) == {0, 1}
        # the BA's residual noise of the smoothed tracks: below the 0.7 px put on the raw keypoints
        assert all(0.1 < s < 0.7 for s in c["keypoint_noise"]["sigma_px_by_keypoint_id"].values()), c["keypoint_noise"]
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "yowo_bringup.cli",
            "eval",
            str(out),
            "--bag",
            str(tmp_path / "rec"),
            "--metrics",
            str(out / "metrics.json"),
        ],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    rel = json.loads((out / "metrics.json").read_text())["relative"]["summary"]
    assert rel["count"] == 5 and rel["pos_max"] < 0.03 and rel["rot_max"] < 0.3
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    # Every replayed message reached its stage.
    for topic, n in log["replay_published"].items():
        assert all(v == n for v in log["received"][topic].values()), (topic, n, log["received"][topic])
