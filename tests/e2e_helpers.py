"""Helpers shared by the end-to-end tests: recordings built from synthetic tracks,
and running the yowo CLI in its own process."""

import contextlib
import subprocess
import sys
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Header

from cmc_synthetic import ceiling_camera, loop_walk, observe
from yowo_common.ros.bag import BagWriter
from yowo_common.rosconv import matrix_to_pose, model_to_camera_info, ns_to_time
from yowo_msgs.msg import AgentKeypoints, Keypoint2D


def write_keypoint_bag(path, cams, tracks):
    with BagWriter(path) as bag:
        t0 = min(int(t.stamps_ns.min()) for ct in tracks for t in ct.tracks.values())
        for name, (_, T) in cams.items():
            bag.write(
                f"/gt/cmc/{name}/pose",
                PoseStamped(header=Header(stamp=ns_to_time(t0), frame_id="map"), pose=matrix_to_pose(T)),
                t0,
            )
        frames = []
        for ct in tracks:
            stamps = np.unique(np.concatenate([t.stamps_ns for t in ct.tracks.values()]))
            for s in stamps:
                frames.append((int(s), ct))
        for s, ct in sorted(frames, key=lambda f: (f[0], f[1].name)):
            h = Header(stamp=ns_to_time(s), frame_id=f"{ct.name}_optical_frame")
            kps = [
                Keypoint2D(id=i, x=float(t.uv[k, 0]), y=float(t.uv[k, 1]), confidence=0.9)
                for i, t in ct.tracks.items()
                for k in np.flatnonzero(t.stamps_ns == s)
            ]
            bag.write(f"/cmc/{ct.name}/camera_info", model_to_camera_info(ct.camera, h), s)
            bag.write(
                f"/cmc/{ct.name}/agent_keypoints", AgentKeypoints(header=h, camera_name=ct.name, keypoints=kps), s
            )


def three_camera_recording(path, seed=0, duration_s=20.0, tamper=None, layout=0):
    """A one-room recording with three CMCs (c1, c2, c3, mounted after `layout` 0 or 1);
    `tamper(cams, tracks)` may damage it first."""
    cams = (
        {
            "c1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
            "c2": ceiling_camera(4.7, 0.3, (2.5, 2.5), z=3.3),
            "c3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
        }
        if layout == 0
        else {
            "c1": ceiling_camera(4.7, 4.7, (2.3, 2.5), z=2.8),
            "c2": ceiling_camera(0.3, 2.5, (2.7, 2.5)),
            "c3": ceiling_camera(4.7, 1.0, (2.0, 3.0), z=3.5),
        }
    )
    tracks = observe(cams, loop_walk((2.5, 2.5), (1.5, 1.2), 10.0), duration_s, sigma_px=0.5, seed=seed)
    if tamper is not None:
        tamper(cams, tracks)
    write_keypoint_bag(path, cams, tracks)
    return cams, tracks


def log_tails(out, nodes, lines=25) -> str:
    """The last lines of some nodes' logs in a results directory (for a failure message)."""
    parts = []
    for node in nodes:
        log = out / "logs" / f"{node}.log"
        text = log.read_text(errors="replace").splitlines()[-lines:] if log.exists() else ["(no log)"]
        parts.append(f"--- {log} ---\n" + "\n".join(text))
    return "\n".join(parts)


def yowo(*args, env, timeout=300, cwd=None):
    """The yowo CLI in its own process. Graph verbs get their own --timeout inside ours,
    so a hung graph is stopped (and its nodes reaped) by the supervisor, not orphaned.
    Started in `cwd`, it is the installed `yowo` command, as a user starts it there."""
    args = [str(a) for a in args]
    if args[0] in ("run", "calibrate-cmc") and "--timeout" not in args:
        args += ["--timeout", str(max(timeout - 60, timeout // 2))]
    cmd = [str(Path(sys.executable).parent / "yowo")] if cwd else [sys.executable, "-m", "yowo_bringup.cli"]
    return subprocess.run([*cmd, *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout)


@contextlib.contextmanager
def yowo_background(*args, env):
    """The yowo CLI started in its own process (output captured); stopped at exit if it
    still runs, so a failing test leaves no graph behind."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "yowo_bringup.cli", *map(str, args)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=30)


def kill_when_playing(out, node, after_s):
    """SIGKILL one node of a running graph (by its pid file) `after_s` seconds after the
    replay started playing (its log says so)."""
    import os
    import signal
    import time

    replay_log, pid_file = out / "logs" / "replay.log", out / "logs" / f"{node}.pid"
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and not (replay_log.exists() and "playing" in replay_log.read_text()):
        time.sleep(0.1)
    time.sleep(after_s)
    os.kill(int(pid_file.read_text()), signal.SIGKILL)
