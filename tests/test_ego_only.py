"""An ego-only run is a supported mode: a recording without usable CMCs maps the scene
through the real graph (replay + ego mapper) and says plainly that no camera was
registered and why; `yowo eval` measures its trajectory without tripping over the cameras."""

import json

import pytest
import yaml

from e2e_helpers import log_tails, yowo
from yowo_bringup.run import CMC, EGO, FULL, plan_run
from yowo_common.ros.bag import BagWriter, list_topics, read_messages
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset


def copy_without(src, dst, drop) -> None:
    """The recording `src` without the topics `drop(name)` selects (latched ones stay latched)."""
    kept = {t.name: t.latched for t in list_topics(src) if not drop(t.name)}
    with BagWriter(dst) as out:
        for topic, stamp, msg in read_messages(src, list(kept)):
            out.write(topic, msg, stamp, latched=kept[topic])


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """tiny s5 with keypoints only (no CMC images: fast to render), and the same walk with
    every /cmc/ topic removed, and with only cam00's; ground truth kept in all."""
    root = tmp_path_factory.mktemp("ego_only")
    generate(get_preset("tiny", cmc_images=False), 5, root / "full")
    copy_without(root / "full", root / "no_cmc", lambda t: t.startswith("/cmc/"))
    copy_without(root / "full", root / "one_cmc", lambda t: t.startswith("/cmc/") and not t.startswith("/cmc/cam00/"))
    return root


def test_ego_only_run_through_the_graph(recordings, ros_env):
    bag, out = recordings / "no_cmc", recordings / "results"
    r = yowo("run", bag, "-o", out, env=ros_env, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:] + log_tails(out, ["replay", "ego_mapper"])
    assert "ego-only run" in r.stdout and "no CMC topics" in r.stdout, r.stdout
    for name in (
        "ego_trajectory.tum",
        "map.ply",
        "layout.json",
        "cameras.yaml",
        "run_log.yaml",
        "params.yaml",
        "report.html",
        "result.mcap",
        "metrics.json",
    ):
        assert (out / name).exists(), name
    cams = yaml.safe_load((out / "cameras.yaml").read_text())
    assert cams["registered"] == 0 and cams["cameras"] == [] and "no CMC topics" in cams["note"], cams
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    assert log["mode"] == EGO and log["failure"] == "" and set(log["stages"]) == {"ego_mapper"}
    # The ego camera's topics and its IMU (the simulator records one), nothing of the CMCs.
    assert set(log["replay_published"]) == {
        "/ego/color/image_raw/compressed",
        "/ego/color/camera_info",
        "/ego/depth/image_raw/compressedDepth",
        "/ego/imu",
        "/ego/imu/calibration",
    }
    assert "No camera registered (ego-only run)" in (out / "report.html").read_text()
    # The trajectory against the simulator's ground truth: the full run on this walk reaches
    # ~7 mm; a broken ego graph is off by decimetres.
    r = yowo("eval", out, "--bag", bag, "--metrics", out / "metrics.json", env=ros_env, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["ego"]["matched"] == 133 and metrics["ego"]["ate_rmse_m"] < 0.03, metrics["ego"]
    assert "layout" in metrics and "registration" not in metrics
    assert metrics["cameras"] == {"registered": 0, "not_registered": ["cam00", "cam01", "cam02"], "note": cams["note"]}


def test_modes_by_usable_cmcs(recordings, tmp_path):
    # No usable CMC: the cameras are there but not their keypoints' source; each one's problem is named.
    plan = plan_run(recordings / "full", tmp_path / "a", source="images")
    assert plan.mode == EGO and plan.cameras == [] and [n.name for n in plan.nodes] == ["ego_mapper", "replay"]
    assert len(plan.cmc_problems) == 3 and all("the camera is skipped" in p for p in plan.cmc_problems)
    assert plan.mode_reason.startswith("no usable CMC: CMC 'cam00'")
    # One CMC forms no group; the fusion registers it as an isolated camera from the ego track.
    plan = plan_run(recordings / "one_cmc", tmp_path / "b")
    assert plan.mode == FULL and plan.cameras == ["cam00"] and "fusion" in [n.name for n in plan.nodes]
    assert any("only one usable CMC (cam00)" in w for w in plan.warnings)
    # The CMC-only calibration still needs a group.
    for bag in ("one_cmc", "no_cmc"):
        with pytest.raises(ValueError, match="needs at least 2"):
            plan_run(recordings / bag, tmp_path / "c", mode=CMC)
    # Three usable CMCs: the full graph, as before.
    plan = plan_run(recordings / "full", tmp_path / "d")
    assert plan.mode == FULL and plan.cameras == ["cam00", "cam01", "cam02"] and not plan.mode_reason
