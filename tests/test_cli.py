"""The yowo command line itself: --version, and `yowo eval` on missing, empty and real
results (units kept in the tables)."""

from importlib.metadata import version

from e2e_helpers import three_camera_recording, yowo


def test_version(ros_env):
    r = yowo("--version", env=ros_env)
    assert r.returncode == 0 and r.stdout.strip().startswith(f"yowo {version('yowo_bringup')}"), r.stdout + r.stderr


def test_eval_names_missing_and_empty_results_and_keeps_units(tmp_path, ros_env):
    three_camera_recording(tmp_path / "rec")
    r = yowo(
        "eval",
        tmp_path / "nope",
        "--bag",
        tmp_path / "rec",
        "--metrics",
        tmp_path / "nope" / "metrics.json",
        env=ros_env,
    )
    assert r.returncode == 2 and "no such results directory" in r.stderr and "Traceback" not in r.stderr
    (tmp_path / "empty").mkdir()
    r = yowo(
        "eval",
        tmp_path / "empty",
        "--bag",
        tmp_path / "rec",
        "--metrics",
        tmp_path / "empty" / "metrics.json",
        env=ros_env,
    )
    assert (
        r.returncode == 2 and "nothing to evaluate" in r.stderr and not (tmp_path / "empty" / "metrics.json").exists()
    )
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", tmp_path / "out", env=ros_env)
    assert r.returncode == 0, r.stderr
    r = yowo(
        "eval", tmp_path / "out", "--bag", tmp_path / "rec", "--metrics", tmp_path / "out" / "metrics.json", env=ros_env
    )
    assert r.returncode == 0 and "eps_pos [m]" in r.stdout and "eps_rot [deg]" in r.stdout, r.stdout
