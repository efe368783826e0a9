"""Live operation: `yowo live` runs the graph on camera topics with no recording;
a separate process publishes like camera drivers would, `yowo end-walk` ends the walk,
and the CMC groups are calibrated from what arrived, even after a tracker restart."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import yaml
from conftest import GRAPH

from cmc_synthetic import ceiling_camera, loop_walk, observe
from e2e_helpers import write_keypoint_bag, yowo, yowo_background
from yowo_common.ros.bag import list_topics


def test_live_cmc_calibration_ends_on_end_walk(tmp_path, ros_env):
    cams = {
        "a1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "a2": ceiling_camera(4.7, 0.3, (2.5, 2.5), z=3.3),
        "a3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
    }
    tracks = observe(cams, loop_walk((2.5, 2.5), (1.5, 1.2), 10.0), 20.0, sigma_px=0.5, seed=3)
    write_keypoint_bag(tmp_path / "rec", cams, tracks)
    out = tmp_path / "live"
    with yowo_background(
        "live", "--cameras", "a1", "a2", "a3", "--cmc-only", "-o", out, "--timeout", "240", env=ros_env
    ) as live:
        source = subprocess.run(
            [sys.executable, str(GRAPH / "live_source.py"), str(tmp_path / "rec")],
            env=ros_env,
            capture_output=True,
            text=True,
            timeout=180,
        )
        assert source.returncode == 0, source.stderr
        assert live.poll() is None  # nothing finalises before the walk is declared over
        # A tracker dies after the cameras sent everything: live, nobody can send it again,
        # but what it had published before stays with the group SfM.
        pid_file = out / "logs" / "keypoint_tracker_a1.pid"
        killed = int(pid_file.read_text())
        os.kill(killed, signal.SIGKILL)
        deadline = time.monotonic() + 30
        while int(pid_file.read_text()) == killed and time.monotonic() < deadline:
            time.sleep(0.2)
        assert int(pid_file.read_text()) != killed  # restarted
        time.sleep(3.0)
        r = yowo("end-walk", "--linger", "10", env=ros_env, timeout=120)
        assert r.returncode == 0, r.stderr
        stdout, stderr = live.communicate(timeout=240)
    assert live.returncode == 0, stdout[-3000:] + stderr[-3000:]
    assert "(3 of 3 cameras calibrated;" in stdout, stdout[-2000:]  # cameras, not groups
    doc = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    assert sorted(c["name"] for c in doc if c["status"] == "ok") == ["a1", "a2", "a3"], [
        (c["name"], c["status"], c.get("reason")) for c in doc
    ]
    # The intrinsics are the ones the live CameraInfo gave the trackers (the groups carry them).
    for c in doc:
        assert np.allclose(c["K"], cams[c["name"]][0].K, atol=1e-5) and c["image_width"] == 640, c
    r = yowo("eval", out, "--bag", tmp_path / "rec", "--metrics", out / "metrics.json", env=ros_env, timeout=120)
    assert r.returncode == 0, r.stderr
    rel = json.loads((out / "metrics.json").read_text())["relative"]["summary"]
    assert rel["count"] == 3 and rel["pos_max"] < 0.03 and rel["rot_max"] < 0.3
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    assert log["bag"] == "live"
    sent = {t.name: t.count for t in list_topics(tmp_path / "rec")}
    assert log["restarts"] == {"keypoint_tracker_a1": [-9]}
    for c in cams:  # reliable and acknowledged: every message the source sent reached the group SfM
        topic = f"/cmc/{c}/agent_keypoints"
        assert log["received"][topic] == {f"keypoint_tracker_{c}": sent[topic] if c != "a1" else 0}
        assert log["received"][f"/yowo/cmc/{c}/agent_keypoints"]["group_sfm"] == sent[topic]
