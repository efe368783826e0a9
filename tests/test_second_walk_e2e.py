"""A second walk added to the first (issue #48, part 4): a run suggests a second walk
(second_walk.yaml); the simulated walker follows it in the same building, with the same cameras
and clocks, a minute after the first recording ends; `yowo run FIRST SECOND` reads both as one
recording. The ego map joins the two walks, the cameras see the walker where the suggestion
sent it, and the run names both recordings."""

import json

import yaml

from e2e_helpers import yowo
from yowo_common.ros.bag import recording_span
from yowo_common.trajectory import read_tum
from yowo_sim.capture import generate
from yowo_sim.follow import follow_walk, map_to_world
from yowo_sim.presets import get_preset


def coverage(out):
    cams = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    return {c["name"]: c.get("coverage", {}) for c in cams}


def test_a_second_walk_that_follows_the_suggestion_joins_the_first(tmp_path, ros_env):
    preset = get_preset("tiny", cmc_images=False)
    first, second = tmp_path / "first", tmp_path / "second"
    generate(preset, 5, first)
    run1 = tmp_path / "run1"
    r = yowo("run", first, "-o", run1, "--rate", "0", env=ros_env, timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    plan = yaml.safe_load((run1 / "second_walk.yaml").read_text())
    assert plan["waypoints"], plan

    # The plan is put on the building by the first run's map (an ego trajectory this good
    # places the waypoints within centimetres of where the run meant them).
    _, _, rms = map_to_world(run1, first)
    assert rms < 0.05, rms
    follow = follow_walk(run1, first, gap_s=60.0)
    summary = generate(preset, 5, second, follow=follow)
    start1, end1 = recording_span(first)
    start2, _ = recording_span(second)
    assert start2 - end1 >= 59e9 and summary.duration_s > 5.0

    run2 = tmp_path / "run2"
    r = yowo("run", first, second, "-o", run2, "--rate", "0", env=ros_env, timeout=900)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    log = yaml.safe_load((run2 / "run_log.yaml").read_text())
    assert log["bag"] == f"{first} + {second}"

    # One map of both walks: the ego trajectory covers each, and against the truth (both
    # recordings' ground truth read as one) it is as good as the first walk's alone.
    traj = read_tum(run2 / "ego_trajectory.tum")
    assert (traj.stamps_ns < end1).sum() > 50 and (traj.stamps_ns > start2).sum() > 50
    m1 = json.loads((run1 / "metrics.json").read_text())
    m2 = json.loads((run2 / "metrics.json").read_text())
    assert m2["ego"]["ate_rmse_m"] < max(0.02, 2 * m1["ego"]["ate_rmse_m"]), (m1["ego"], m2["ego"])
    # Every camera registered after the first walk still is, as well; each saw the walker more.
    reg1 = {c["name"]: c for c in m1["registration"]["cameras"]}
    reg2 = {c["name"]: c for c in m2["registration"]["cameras"]}
    assert set(reg1) <= set(reg2)
    for name, c in reg1.items():
        assert reg2[name]["eps_pos_m"] < max(0.02, 1.5 * c["eps_pos_m"]), (name, c, reg2[name])
    # The ego camera tracked the second walk's first frames against the first walk's map: the
    # join is no break in the ego map, so no camera turns weak for it.
    status1, status2 = (
        {c["name"]: c["status"] for c in yaml.safe_load((r / "cameras.yaml").read_text())["cameras"]}
        for r in (run1, run2)
    )
    assert all(status2[n] == "ok" for n, s in status1.items() if s == "ok"), (status1, status2)
    before, after = coverage(run1), coverage(run2)
    served = {c for w in plan["waypoints"] for c in w["cameras"]}
    assert served
    for name in served:
        assert after[name]["agent_observations"] > before[name]["agent_observations"], name
