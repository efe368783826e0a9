"""`yowo bench` end to end on the tiny preset, one seed (the harness's correctness:
every table is written from real cases; not a speed or accuracy benchmark)."""

import json

from e2e_helpers import yowo


def test_bench_on_tiny_writes_every_table(tmp_path, ros_env):
    out = tmp_path / "bench"
    r = yowo(
        "bench",
        "--preset",
        "tiny",
        "--seeds",
        "0",
        "-o",
        out,
        "--markdown",
        tmp_path / "B.md",
        env=ros_env,
        timeout=1200,
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    results = json.loads((out / "results.json").read_text())
    (case,) = results["cases"]
    assert set(case["relative"]) == {
        "YOWO",
        "YOWO, image detector",
        "YOWO, pose model",
        "YOWO, left-over pairs",
        "ECCMP-style",
        "OMECC-style",
    }
    yowo_rel = case["relative"]["YOWO"]
    assert yowo_rel["calibrated"] == 3 and yowo_rel["summary"]["pos_max"] < 0.10, yowo_rel  # a 7 s walk: ~4 cm
    assert case["detector"]["frames_full_view"] > 0 and 0 < case["detector"]["detection_rate"] <= 1
    reg = case["full"]["registration"]
    assert {
        "YOWO",
        "YOWO without joint optimisation",
        "Hloc-style",
        "Hloc-style with YOWO prior",
        "YOWO, cameras outside groups",
    } <= set(reg)
    assert reg["YOWO, cameras outside groups"]["cameras"] == 0  # tiny: one group of three
    assert 0.5 < case["full"]["layout_iou_joint"] <= 1.0
    # Seed 0 walks a straight line (a degenerate geometry for the alignment): ~0.3 m.
    assert reg["YOWO"]["registered"] == 3 and reg["YOWO"]["pos_max"] < 0.5, reg
    assert case["full"]["ate"]["joint"] < 0.10 and case["peak_memory_mb"] > 50
    assert case["bound"]["cameras"] == 3, case["bound"]  # one well-conditioned group of three
    text = (tmp_path / "B.md").read_text()
    assert text == (out / "BENCHMARKS.md").read_text()
    for title in (
        "relative_pose_eval",
        "Image detector",
        "register_pose_eval",
        "scene_map",
        "Table ablation",
        "Speed and scale",
        "Cramer-Rao",
        "efficient avg eps_rot",
    ):
        assert title in text, title
    assert "yowo bench --preset tiny --seeds 0" in text

    # A resumed run reuses the case and recomputes only a bound stored by an older bound version.
    stale = dict(case, bound={"cameras": 0, "position_m": {}, "rotation_deg": {}})
    (out / "cases.jsonl").write_text(json.dumps(stale) + "\n")
    r = yowo("bench", "--preset", "tiny", "--seeds", "0", "-o", out, "--resume", env=ros_env, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "reused" in r.stdout + r.stderr and "recomputing the stored bound" in r.stdout + r.stderr
    (resumed,) = json.loads((out / "results.json").read_text())["cases"]
    assert resumed["bound"] == case["bound"] and resumed["relative"] == case["relative"]


def test_a_failed_case_keeps_its_traceback_and_the_run_goes_on(tmp_path):
    from yowo_eval.bench import run_bench

    bag = tmp_path / "bags" / "tiny_normal_s0"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("not: a rosbag2 metadata file\n")  # the case's reader fails in the worker
    logged = []
    result = run_bench(["tiny"], [0], ["normal"], tmp_path, log=logged.append)
    (failure,) = result["failures"]
    assert result["cases"] == [] and failure["preset"] == "tiny" and failure["seed"] == 0
    assert "run_case" in failure["traceback"], failure  # the worker's frames, not only the message
    assert any("FAILED" in line and "run_case" in line for line in logged)
