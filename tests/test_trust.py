"""Untrusted recordings: what a recording holds never selects code to run."""
import yaml
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Writer
from sensor_msgs.msg import Imu

from e2e_helpers import three_camera_recording, yowo
from yowo_common.ros.bag import read_raw, typestore

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
        for topic, msgtype in (("/cmc/c1/imu", "redmod/msg/Imu"), ("/planted", "this_is_planted/msg/Imu"),
                               ("/shadow", "rclpy/msg/Imu")):
            conn = writer.add_connection(topic, msgtype, msgdef=imu_def, rihs01=store.hash_rihs01("sensor_msgs/msg/Imu"))
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
    said = " ".join(r.stdout.split())          # rich wraps at the terminal's width
    assert "/cmc/c1/imu: skipped, 'redmod/msg/Imu' is not from an interface package YOWO reads" in said, said
    r = yowo("calibrate-cmc", "rec", "-o", "out", env=ros_env, cwd=work)
    assert r.returncode == 0, r.stderr
    assert not (work / "PLANTED").exists(), (work / "PLANTED").read_text()
    # The foreign topics were skipped with the reason; the cameras were calibrated without them.
    replay_log = (work / "out" / "logs" / "replay.log").read_text()
    assert "/cmc/c1/imu: skipped" in replay_log and "/planted: skipped" in replay_log, replay_log
    cams = {c["name"]: c for c in yaml.safe_load((work / "out" / "cameras.yaml").read_text())["cameras"]}
    assert all(cams[n]["status"] == "ok" for n in ("c1", "c2", "c3")), cams
