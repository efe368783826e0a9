"""Trust at first contact: what a recording holds never selects code to run, results folders
hold one run, the real reason of a failure is told, bad input and settings are refused up front."""

import yaml
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Writer
from sensor_msgs.msg import Imu

from e2e_helpers import three_camera_recording, yowo
from yowo_common.ros.bag import read_messages, read_raw, typestore

# Imported, each of these writes its own name into the file PLANTED in the working folder.
PLANTED_MODULES = ("redmod", "this_is_planted", "rclpy", "yaml", "sensor_msgs")


def _plant(folder):
    for name in PLANTED_MODULES:
        (folder / f"{name}.py").write_text(f"open({str(folder / 'PLANTED')!r}, 'a').write({name!r} + '\\n')\n")


def _with_foreign_types(src, dst):
    """`src` copied with two more topics whose type names point at planted modules."""
    store = typestore()
    writer = Writer(dst, version=9)
    writer.open()
    conns = {}
    try:
        for raw in read_raw(src):
            if raw.topic not in conns:
                conns[raw.topic] = writer.add_connection(raw.topic, raw.msgtype, typestore=store)
            writer.write(conns[raw.topic], raw.log_time_ns, raw.data)
        imu_def = store.generate_msgdef("sensor_msgs/msg/Imu")[0]
        for topic, msgtype in (
            ("/cmc/c1/imu", "redmod/msg/Imu"),
            ("/planted", "this_is_planted/msg/Imu"),
            ("/shadow", "rclpy/msg/Imu"),
        ):
            conn = writer.add_connection(
                topic, msgtype, msgdef=imu_def, rihs01=store.hash_rihs01("sensor_msgs/msg/Imu")
            )
            writer.write(conn, 1, serialize_message(Imu()))
    finally:
        writer.close()


def test_a_recordings_type_names_import_nothing(tmp_path, ros_env):
    three_camera_recording(tmp_path / "good", duration_s=12.0)
    work = tmp_path / "work"
    work.mkdir()
    _plant(work)
    _with_foreign_types(tmp_path / "good", work / "rec")
    r = yowo("info", "rec", env=ros_env, cwd=work)
    assert r.returncode == 0, r.stderr
    said = " ".join(r.stdout.split())  # rich wraps at the terminal's width
    assert "/cmc/c1/imu: skipped, 'redmod/msg/Imu' is not from an interface package YOWO reads" in said, said
    r = yowo("calibrate-cmc", "rec", "-o", "out", env=ros_env, cwd=work)
    assert r.returncode == 0, r.stderr
    assert not (work / "PLANTED").exists(), (work / "PLANTED").read_text()
    # The foreign topics were skipped with the reason; the cameras were calibrated without them.
    replay_log = (work / "out" / "logs" / "replay.log").read_text()
    assert "/cmc/c1/imu: skipped" in replay_log and "/planted: skipped" in replay_log, replay_log
    cams = {c["name"]: c for c in yaml.safe_load((work / "out" / "cameras.yaml").read_text())["cameras"]}
    assert all(cams[n]["status"] == "ok" for n in ("c1", "c2", "c3")), cams


def test_results_folders_hold_one_run_and_never_an_older_ones(tmp_path, ros_env):
    from yowo_bringup.outdir import claimed_output

    three_camera_recording(tmp_path / "rec", duration_s=12.0)
    out = tmp_path / "out"
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", out, env=ros_env)
    assert r.returncode == 0, r.stderr
    (out / "old_note.txt").write_text("left by the first run's user")
    # Another run into it is refused, and nothing of the first is touched.
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", out, env=ros_env)
    assert r.returncode == 2 and "earlier run's results" in r.stderr and "--replace" in r.stderr, r.stderr
    assert (out / "old_note.txt").exists() and (out / "cameras.yaml").exists()
    first_id = yaml.safe_load((out / "run_log.yaml").read_text())["run_id"]
    # While a run holds the folder, a second one is refused.
    with claimed_output(out, replace=True):
        r = yowo("calibrate-cmc", tmp_path / "rec", "-o", out, "--replace", env=ros_env)
    assert r.returncode == 2 and "another run (pid" in r.stderr, r.stderr
    # --replace: the old results are gone before the new ones appear.
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", out, "--replace", env=ros_env)
    assert r.returncode == 0, r.stderr
    assert not (out / "old_note.txt").exists() and not (out / ".yowo.partial").exists()
    assert yaml.safe_load((out / "run_log.yaml").read_text())["run_id"] != first_id
    # A folder of somebody else's files is never cleared.
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"\xff\xd8")
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", foreign, "--replace", env=ros_env)
    assert r.returncode == 2 and "not a YOWO run's results" in r.stderr and (foreign / "holiday.jpg").exists()


def test_ctrl_c_stops_every_node_and_the_run_log_says_so(tmp_path, ros_env):
    import os
    import signal
    import subprocess
    import sys
    import time

    three_camera_recording(tmp_path / "rec", duration_s=60.0)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "yowo_bringup.cli",
            "calibrate-cmc",
            str(tmp_path / "rec"),
            "-o",
            str(out),
            "--rate",
            "1",
            "--timeout",
            "240",
        ],
        env=ros_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        replay_log = out / "logs" / "replay.log"
        while time.monotonic() < deadline and not (replay_log.exists() and "playing" in replay_log.read_text()):
            time.sleep(0.5)
        time.sleep(2.0)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode != 0 and "interrupted (Ctrl-C)" in stderr and "Traceback" not in stderr, stderr
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    assert log["failure"].startswith("interrupted (Ctrl-C)"), log["failure"]
    for pid_file in (out / "logs").glob("*.pid"):
        pid = int(pid_file.read_text().split()[0])
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            continue
        status = open(f"/proc/{pid}/stat").read().split()[2]
        assert status == "Z", f"{pid_file.stem} (pid {pid}) still runs after Ctrl-C"


def test_a_topic_of_the_wrong_type_is_named_at_start_and_options_get_their_verbs_usage(tmp_path, ros_env):
    from sensor_msgs.msg import CompressedImage

    from yowo_common.ros.bag import BagWriter
    from yowo_common.topics import EGO_COLOR

    cams, _ = three_camera_recording(tmp_path / "good", duration_s=6.0)
    with BagWriter(tmp_path / "rec") as bag:
        for topic, log_ns, msg in read_messages(tmp_path / "good"):
            bag.write(topic, msg, log_ns)
        bag.write(EGO_COLOR[0], CompressedImage(format="jpeg"), log_ns)
        bag.write("/cmc/c1/camera_info", CompressedImage(format="jpeg"), log_ns + 1)
    r = yowo("info", tmp_path / "rec", env=ros_env)
    said = " ".join(r.stdout.split())
    assert (
        f"{EGO_COLOR[0]}: type sensor_msgs/msg/CompressedImage, but as {EGO_COLOR[0]} it must be "
        "sensor_msgs/msg/Image; not used"
    ) in said, said
    r = yowo("run", tmp_path / "rec", "-o", tmp_path / "out", env=ros_env, timeout=120)
    assert r.returncode == 2 and "it must be sensor_msgs/msg/Image" in r.stderr, r.stderr
    r = yowo("calibrate-cmc", tmp_path / "rec", "-o", tmp_path / "out2", "--no-such-option", env=ros_env)
    assert r.returncode == 2 and "yowo calibrate-cmc: error: unrecognized arguments: --no-such-option" in r.stderr
    assert "usage: yowo calibrate-cmc" in r.stderr, r.stderr
