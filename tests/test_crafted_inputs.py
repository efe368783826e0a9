"""The crafted-input catalogue: recordings, files and settings as a hostile or unlucky user
gives them. Every case ends with exit code 0, 1 or 2 and a one-line reason naming the topic,
file, camera or key; no traceback, no hang; every result on disk is the printing run's own.

Cases derive from a three-camera keypoint recording (`calibrate-cmc`) or from the `tiny`
simulation (`run`, ego cases)."""

import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import yaml

from e2e_helpers import three_camera_recording, yowo
from yowo_common.ros.bag import BagWriter, read_messages
from yowo_common.topics import EGO_COLOR, EGO_DEPTH, EGO_INFO


@dataclass(frozen=True, kw_only=True)
class Case:
    name: str
    args: Callable[["Inputs"], list]  # the command line, built from the case's inputs
    rc: tuple[int, ...]
    says: str  # in the console's reason ({tmp} and {rec} filled in)
    recording: str = "keypoints"  # which base recording the case derives from
    edit: Callable | None = None  # (topic, log_ns, msg) -> [(topic, log_ns, msg), ...]
    camera_status: dict = field(default_factory=dict)  # camera -> verdict in cameras.yaml
    none_ok: bool = False  # no camera may be `ok`


@dataclass(frozen=True, kw_only=True)
class Inputs:
    rec: Path  # the (derived) recording
    tmp: Path  # the case's folder
    out: Path  # its results folder

    def file(self, name: str, text: str | bytes) -> Path:
        path = self.tmp / name
        (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
        return path


def _cmc(i, *extra):
    return ["calibrate-cmc", i.rec, "-o", i.out, *extra]


def _run(i, *extra):
    return ["run", i.rec, "-o", i.out, *extra]


def _on(topic: str, change: Callable):
    """An edit that applies `change(msg)` to every message of `topic`."""

    def edit(t, log_ns, msg):
        if t == topic:
            change(msg)
        return [(t, log_ns, msg)]

    return edit


def _setattr(**values):
    def change(msg):
        for k, v in values.items():
            setattr(msg, k, v)

    return change


def _kp_each(change):
    def per_message(msg):
        for kp in msg.keypoints:
            change(kp)

    return per_message


def _renamed(names: dict):
    def edit(t, log_ns, msg):
        for old, new in names.items():
            if t.startswith(f"/cmc/{old}/"):
                t = t.replace(f"/cmc/{old}/", f"/cmc/{new}/", 1)
                if hasattr(msg, "camera_name"):
                    msg.camera_name = new
        return [(t, log_ns, msg)]

    return edit


def _only_first(topic: str, n: int):
    seen = [0]

    def edit(t, log_ns, msg):
        if t != topic:
            return [(t, log_ns, msg)]
        seen[0] += 1
        return [(t, log_ns, msg)] if seen[0] <= n else []

    return edit


def _swap_top_and_ground(kp):
    kp.id = {0: 1, 1: 0}.get(kp.id, kp.id)  # the head top's id and the ground point's exchanged


def _on_every_camera(change):
    def edit(t, log_ns, msg):
        if t.startswith("/cmc/") and t.endswith("/agent_keypoints"):
            change(msg)
        return [(t, log_ns, msg)]

    return edit


def _twice(t, log_ns, msg):
    return [(t, log_ns, msg), (t, log_ns, msg)]


def _zero_stamp(msg):
    msg.header.stamp.sec, msg.header.stamp.nanosec = 0, 0


def _depth(change):
    """An edit that gives every ego depth image as a raw Image: `change(millimetres)` ->
    (array, encoding)."""
    from yowo_common.rosconv import decode_depth, depth_to_mm, encode_raw

    def edit(t, log_ns, msg):
        if t not in EGO_DEPTH:
            return [(t, log_ns, msg)]
        arr, encoding = change(depth_to_mm(decode_depth(msg)))
        return [(EGO_DEPTH[0], log_ns, encode_raw(arr, encoding, msg.header))]

    return edit


def _zero_depth(mm):
    return np.zeros_like(mm), "16UC1"


def _half_size_depth(mm):
    return np.ascontiguousarray(mm[::2, ::2]), "16UC1"


def _float_millimetres(mm):
    return mm.astype(np.float32), "32FC1"  # the driver's millimetres, as 32FC1 "metres"


LONG_NAME = "c" * 300
GOOD_CONFIG = "ego:\n  depth_max_m: 5.0\n"
OK3 = {"c1": "ok", "c2": "ok", "c3": "ok"}

CASES = [
    # The recording itself.
    Case(
        name="no_such_recording",
        args=lambda i: ["calibrate-cmc", i.tmp / "nope", "-o", i.out],
        rc=(2,),
        says="{tmp}/nope: no such recording",
    ),
    Case(name="empty_recording", recording="empty", args=_cmc, rc=(2,), says="holds no messages"),
    Case(
        name="not_a_recording",
        args=lambda i: _cmc(Inputs(rec=i.file("x.mcap", b"\x89PNG" + bytes(300)), tmp=i.tmp, out=i.out)),
        rc=(2,),
        says="{tmp}/x.mcap",
    ),
    Case(name="metadata_not_yaml", recording="bad_metadata", args=_cmc, rc=(2,), says="{rec}"),
    Case(
        name="wrong_option",
        args=lambda i: _cmc(i, "--no-such-option"),
        rc=(2,),
        says="yowo calibrate-cmc: error: unrecognized arguments: --no-such-option",
    ),
    # Configuration files and settings.
    Case(
        name="config_with_yaml_tags",
        rc=(2,),
        says="{tmp}/c.yaml",
        args=lambda i: _cmc(i, "--config", i.file("c.yaml", "ego: !!python/object/apply:os.system ['echo x']\n")),
    ),
    Case(
        name="config_not_a_mapping",
        rc=(2,),
        says="{tmp}/c.yaml",
        args=lambda i: _cmc(i, "--config", i.file("c.yaml", "- ego\n- cmc\n")),
    ),
    Case(
        name="config_unknown_key",
        rc=(2,),
        says="ego.no_such_key",
        args=lambda i: _cmc(i, "--config", i.file("c.yaml", "ego:\n  no_such_key: 1\n")),
    ),
    Case(
        name="config_missing_file",
        rc=(2,),
        says="{tmp}/none.yaml",
        args=lambda i: _cmc(i, "--config", i.tmp / "none.yaml"),
    ),
    Case(name="set_unknown_key", rc=(2,), says="unknown key nosuch", args=lambda i: _cmc(i, "--set", "nosuch.key=1")),
    Case(name="set_without_value", rc=(2,), says="ego.depth_max_m", args=lambda i: _cmc(i, "--set", "ego.depth_max_m")),
    Case(
        name="set_wrong_type", rc=(2,), says="ego.depth_max_m", args=lambda i: _cmc(i, "--set", "ego.depth_max_m=abc")
    ),
    Case(
        name="set_list_key_to_a_number",
        rc=(2,),
        says="ego.odometry.iterations",
        args=lambda i: _cmc(i, "--set", "ego.odometry.iterations=5x"),
    ),
    Case(
        name="set_negative_depth",
        rc=(2,),
        says="ego.depth_max_m",
        args=lambda i: _cmc(i, "--set", "ego.depth_max_m=-5"),
    ),
    Case(
        name="set_nan",
        rc=(2,),
        says="fusion.joint.relative_error_tol",
        args=lambda i: _cmc(i, "--set", "fusion.joint.relative_error_tol=nan"),
    ),
    Case(name="negative_rate", rc=(2,), says="replay.rate", args=lambda i: _cmc(i, "--rate", "-1")),
    Case(name="tiny_rate", rc=(2,), says="replay.rate", args=lambda i: _cmc(i, "--rate", "1e-300")),
    Case(
        name="negative_tracker_processes",
        rc=(2,),
        says="supervisor.tracker_processes",
        args=lambda i: _cmc(i, "--set", "supervisor.tracker_processes=-1"),
    ),
    Case(name="infinite_rate", rc=(2,), says="replay.rate", args=lambda i: _cmc(i, "--set", "replay.rate=.inf")),
    Case(
        name="negative_tolerance",
        rc=(2,),
        says="fusion.joint.relative_error_tol",
        args=lambda i: _cmc(i, "--set", "fusion.joint.relative_error_tol=-1e-6"),
    ),
    Case(
        name="absurd_scale",
        rc=(2,),
        says="ego.odometry.scale",
        args=lambda i: _cmc(i, "--set", "ego.odometry.scale=1e26"),
    ),
    # Input options.
    Case(
        name="remap_to_a_missing_topic",
        rc=(2,),
        says="/nope",
        args=lambda i: _cmc(i, "-r", "/cmc/c1/agent_keypoints:=/nope"),
    ),
    Case(name="remap_without_target", rc=(2,), says="nothing_to_map", args=lambda i: _cmc(i, "-r", "nothing_to_map")),
    Case(
        name="intrinsics_missing_file",
        rc=(2,),
        says="{tmp}/k.yaml",
        args=lambda i: _cmc(i, "--intrinsics", f"c1={i.tmp / 'k.yaml'}"),
    ),
    Case(
        name="intrinsics_unreadable",
        rc=(2,),
        says="{tmp}/k.yaml",
        args=lambda i: _cmc(i, "--intrinsics", f"c1={i.file('k.yaml', 'hello: [1, 2')}"),
    ),
    Case(
        name="intrinsics_without_camera",
        rc=(2,),
        says="--intrinsics",
        args=lambda i: _cmc(i, "--intrinsics", str(i.file("k.yaml", "x: 1\n"))),
    ),
    Case(
        name="video_missing_file",
        rc=(2,),
        says="{tmp}/v.mp4",
        args=lambda i: _cmc(i, "--cmc-video", f"c9={i.tmp / 'v.mp4'}"),
    ),
    Case(
        name="video_undecodable",
        rc=(2,),
        says="{tmp}/v.mp4",
        args=lambda i: _cmc(i, "--cmc-video", f"c9={i.file('v.mp4', bytes(range(256)) * 40)}"),
    ),
    Case(
        name="video_list_not_a_list",
        rc=(2,),
        says="{tmp}/v.yaml",
        args=lambda i: _cmc(i, "--cmc-videos", i.file("v.yaml", "name: c9\n")),
    ),
    # Results folders.
    Case(
        name="output_is_a_file", rc=(2,), says="{tmp}/out", args=lambda i: (i.file("out", "not a folder"), _cmc(i))[1]
    ),
    Case(
        name="output_of_somebody_else_replaced",
        rc=(2,),
        says="not a YOWO run's results",
        args=lambda i: ((i.tmp / "out").mkdir(), i.file("out/holiday.jpg", b"\xff\xd8"), _cmc(i, "--replace"))[2],
    ),
    # One camera's damage stays that camera's.
    Case(
        name="camera_info_K_zero",
        rc=(0,),
        says="c3: no usable CameraInfo: K has focal lengths fx=0",
        args=_cmc,
        edit=_on("/cmc/c3/camera_info", _setattr(k=[0.0] * 9)),
        camera_status={"c3": "failed", "c1": "ok", "c2": "ok"},
    ),
    Case(
        name="camera_info_D_nan",
        rc=(0,),
        says="c3: no usable CameraInfo: D has non-finite",
        args=_cmc,
        edit=_on("/cmc/c3/camera_info", _setattr(d=[0.1, math.nan, 0.0, 0.0, 0.0])),
        camera_status={"c3": "failed", "c1": "ok", "c2": "ok"},
    ),
    Case(
        name="camera_info_D_of_seven",
        rc=(0,),
        says="c2: no usable CameraInfo: D has 7 coefficients",
        args=_cmc,
        edit=_on("/cmc/c2/camera_info", _setattr(d=[0.01] * 7)),
        camera_status={"c2": "failed", "c1": "ok", "c3": "ok"},
    ),
    Case(
        name="camera_info_K_last_row",
        rc=(0,),
        says="c1: no usable CameraInfo: K is not an upper-triangular",
        args=_cmc,
        edit=_on("/cmc/c1/camera_info", lambda m: setattr(m, "k", [*m.k[:6], 0.0, 1.0, 1.0])),
        camera_status={"c1": "failed", "c2": "ok", "c3": "ok"},
    ),
    Case(
        name="camera_info_zero_size",
        rc=(0,),
        says="c1: no usable CameraInfo: image size 0x0",
        args=_cmc,
        edit=_on("/cmc/c1/camera_info", _setattr(width=0, height=0)),
        camera_status={"c1": "failed", "c2": "ok", "c3": "ok"},
    ),
    Case(
        name="keypoints_nan",
        rc=(0,),
        says="c2",
        args=_cmc,
        edit=_on("/cmc/c2/agent_keypoints", _kp_each(lambda kp: setattr(kp, "x", math.nan))),
        camera_status={"c2": "failed", "c1": "ok", "c3": "ok"},
    ),
    Case(
        name="keypoints_outside_the_image",
        rc=(0,),
        says="c2",
        args=_cmc,
        edit=_on("/cmc/c2/agent_keypoints", _kp_each(lambda kp: setattr(kp, "x", kp.x + 1e5))),
        camera_status={"c2": "failed", "c1": "ok", "c3": "ok"},
    ),
    Case(
        name="keypoints_of_no_confidence",
        rc=(0,),
        says="c3",
        args=_cmc,
        edit=_on("/cmc/c3/agent_keypoints", _kp_each(lambda kp: setattr(kp, "confidence", 0.0))),
        camera_status={"c3": "failed", "c1": "ok", "c2": "ok"},
    ),
    Case(
        name="keypoint_stamps_zero",
        rc=(0,),
        says="c1",
        args=_cmc,
        edit=_on("/cmc/c1/agent_keypoints", _zero_stamp),
        camera_status={"c1": "failed", "c2": "ok", "c3": "ok"},
    ),
    Case(
        name="three_frames_of_a_camera",
        rc=(0,),
        says="c3",
        args=_cmc,
        edit=_only_first("/cmc/c3/agent_keypoints", 3),
        camera_status={"c3": "failed", "c1": "ok", "c2": "ok"},
    ),
    Case(
        name="camera_info_without_keypoints",
        rc=(0,),
        says="c3",
        args=_cmc,
        edit=_only_first("/cmc/c3/agent_keypoints", 0),
        camera_status={"c1": "ok", "c2": "ok"},
    ),
    Case(name="every_message_twice", rc=(0,), says="", args=_cmc, edit=_twice, camera_status=OK3),
    Case(
        name="odd_camera_names",
        rc=(2,),
        says="'9cam' cannot be a camera name",
        args=_cmc,
        edit=_renamed({"c1": "9cam", "c2": LONG_NAME, "c3": "kamera_ü"}),
    ),
    Case(
        name="one_odd_camera_name",
        rc=(0,),
        says="-r /cmc/kamera/agent_keypoints:=/cmc/kamera_ü/agent_keypoints",
        args=_cmc,
        edit=_renamed({"c1": "kamera_ü"}),
        camera_status={"c2": "ok", "c3": "ok"},
    ),
    # The ego camera (the tiny simulation, a full run).
    Case(
        name="ego_K_zero",
        recording="ego",
        rc=(1,),
        says=f"{EGO_INFO}: K has focal lengths fx=0, fy=0",
        args=_run,
        edit=_on(EGO_INFO, _setattr(k=[0.0] * 9)),
    ),
    Case(
        name="ego_D_nan",
        recording="ego",
        rc=(1,),
        says=EGO_INFO,
        args=_run,
        edit=_on(EGO_INFO, _setattr(d=[math.nan] * 5)),
    ),
    Case(name="ego_depth_zero", recording="ego", rc=(1,), says=EGO_DEPTH[0], args=_run, edit=_depth(_zero_depth)),
    Case(
        name="ego_depth_half_size",
        recording="ego",
        rc=(1,),
        says=EGO_DEPTH[0],
        args=_run,
        edit=_depth(_half_size_depth),
    ),
    Case(
        name="ego_depth_millimetres_as_float",
        recording="ego",
        rc=(0, 1),
        says=EGO_DEPTH[0],
        args=_run,
        edit=_depth(_float_millimetres),
    ),
    Case(
        name="keypoint_ids_swapped",
        recording="ego",
        rc=(0, 1),
        says="rejected:",
        args=_run,
        edit=_on_every_camera(_kp_each(_swap_top_and_ground)),
        none_ok=True,
    ),
    Case(
        name="ego_stamps_zero",
        recording="ego",
        rc=(1,),
        says=EGO_COLOR[0],
        args=_run,
        edit=lambda t, n, m: (_zero_stamp(m) if t.startswith("/ego/") and hasattr(m, "header") else None, [(t, n, m)])[
            1
        ],
    ),
]


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    """The base recordings, made once: name -> folder (the ego one on first use)."""
    root = tmp_path_factory.mktemp("bases")
    three_camera_recording(root / "keypoints", duration_s=12.0)
    with BagWriter(root / "empty"):
        pass
    (root / "bad_metadata").mkdir()
    (root / "bad_metadata" / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    made = {"keypoints": root / "keypoints", "empty": root / "empty", "bad_metadata": root / "bad_metadata"}

    def get(name):
        if name == "ego" and name not in made:
            from yowo_sim.capture import generate
            from yowo_sim.presets import get_preset

            generate(get_preset("tiny"), 1, root / "ego")
            made["ego"] = root / "ego"
        return made[name]

    return get


def _derive(src: Path, dst: Path, edit) -> Path:
    with BagWriter(dst) as bag:
        for topic, log_ns, msg in read_messages(src):
            for t, n, m in edit(topic, log_ns, msg):
                bag.write(t, m, n)
    return dst


def _console_run_id(stdout: str) -> str | None:
    m = re.search(r"\brun (\w+) of ", stdout)
    return m.group(1) if m else None


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_crafted_input(case, bases, tmp_path, ros_env):
    rec = bases(case.recording)
    if case.edit is not None:
        rec = _derive(rec, tmp_path / "rec", case.edit)
    inputs = Inputs(rec=rec, tmp=tmp_path, out=tmp_path / "out")
    args = case.args(inputs)
    existed = inputs.out.exists()
    before = {p: p.stat().st_mtime_ns for p in inputs.out.rglob("*")} if inputs.out.is_dir() else {}
    started = time.time_ns()
    r = yowo(*args, env=ros_env, timeout=400)
    said = " ".join((r.stdout + "\n" + r.stderr).split())
    assert r.returncode in case.rc, f"exit {r.returncode}\n{r.stdout}\n{r.stderr}"
    assert "Traceback" not in r.stdout + r.stderr, r.stdout + r.stderr
    expected = case.says.format(tmp=tmp_path, rec=rec)
    assert expected in said, f"{expected!r} not in:\n{r.stdout}\n{r.stderr}"
    if r.returncode == 2 or not (inputs.out / "run_log.yaml").exists():
        # Refused: a folder it found is as it was.
        assert existed or not inputs.out.exists(), "a refused run made a results folder"
        assert all(p.stat().st_mtime_ns == t for p, t in before.items()), "a refused run touched the results folder"
        return
    # Ran: every result is this run's (its id, written after it started), failure said in the log.
    log = yaml.safe_load((inputs.out / "run_log.yaml").read_text())
    assert log["run_id"] == _console_run_id(r.stdout), (log["run_id"], r.stdout)
    assert all(p.stat().st_mtime_ns >= started for p in inputs.out.rglob("*") if p.is_file())
    if r.returncode == 1:  # failed, or ran and registered no camera: each camera's reason is said
        cameras = inputs.out / "cameras.yaml"
        assert log["failure"] or all(c["reason"] for c in yaml.safe_load(cameras.read_text())["cameras"]), log
    if case.camera_status or case.none_ok:
        doc = yaml.safe_load((inputs.out / "cameras.yaml").read_text())["cameras"]
        status = {c["name"]: c["status"] for c in doc}
        assert {n: status.get(n) for n in case.camera_status} == case.camera_status, doc
        assert not (case.none_ok and "ok" in status.values()), doc
