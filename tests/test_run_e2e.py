"""The full product path on a generated recording: `yowo run` through the real
multi-process graph (replay, ego mapper, one tracker per CMC, group SfM, fusion),
then `yowo eval`, checked against the simulator's ground truth."""

import base64
import json
import subprocess
import sys
import time
from html.parser import HTMLParser

import yaml
from conftest import GRAPH

from e2e_helpers import kill_when_playing, log_tails, yowo, yowo_background
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset


def test_yowo_run_registers_cameras_on_tiny(tmp_path, ros_env):
    bag = tmp_path / "tiny_s5"
    generate(get_preset("tiny"), 5, bag)
    out = tmp_path / "results"
    cache = tmp_path / "cache"  # the history of the stages' final steps (the next runs' ETA)
    r = yowo("run", bag, "-o", out, env={**ros_env, "XDG_CACHE_HOME": str(cache)}, timeout=700)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    history = yaml.safe_load((cache / "yowo" / "final_steps.yaml").read_text())
    assert set(history) == {"keypoint_tracker", "ego_mapper", "group_sfm", "fusion"}, history
    assert all(len(v) == 1 and 0 <= v[0] < 1.0 for v in history.values()), history
    for name in (
        "cameras.yaml",
        "ego_trajectory.tum",
        "map.ply",
        "layout.json",
        "report.html",
        "metrics.json",
        "ego_trajectory_ego.tum",
        "map_ego.ply",
        "layout_ego.json",
        "weak_places.yaml",
    ):
        assert (out / name).exists(), name
    # The walk's weak places: tiny's 10 s walk never returns to where it went.
    weak = yaml.safe_load((out / "weak_places.yaml").read_text())["weak_places"]
    assert "walked once" in {w["kind"] for w in weak}, weak
    assert all(w["why"] and w["end_s"] >= w["start_s"] >= 0 for w in weak), weak
    assert "Weak places of the walk" in (out / "report.html").read_text()
    check_result_bag(out / "result.mcap")
    check_report(out / "report.html", ["cam00", "cam01", "cam02"])
    check_exports(out)
    metrics = json.loads((out / "metrics.json").read_text())
    reg = metrics["registration"]["summary"]
    # Only a working pipeline lands every camera within 15 cm / 2 deg in the map frame.
    assert reg["count"] == 3 and reg["pos_max"] < 0.15 and reg["rot_max"] < 2.0, metrics
    assert metrics["ego"]["ate_rmse_m"] < 0.10
    # The same recording run again gives the same cameras, trajectory, layout and map, byte
    # for byte, even though its ego mapper is killed mid-replay (restarted, sent what it
    # missed); this run lingers (on the test's domain: --linger shares the graph), and a
    # subscriber started after the results are written gets every camera on /tf_static.
    again = tmp_path / "again"
    with yowo_background(
        "run", bag, "-o", again, "--linger", "30", "--timeout", "600", "--rate", "0.5", env=ros_env
    ) as run:
        kill_when_playing(again, "ego_mapper", 3.0)
        deadline = time.monotonic() + 600
        while not (again / "report.html").exists() and run.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
        late = subprocess.run(
            [sys.executable, str(GRAPH / "tf_static_late.py"), "sub", "15"],
            env=ros_env,
            capture_output=True,
            text=True,
            timeout=60,
        )
        stdout, stderr = run.communicate(timeout=120)
    assert run.returncode == 0, stdout[-3000:] + stderr[-3000:] + log_tails(again, ["replay", "ego_mapper"])
    for name in (
        "cameras.yaml",
        "ego_trajectory.tum",
        "layout.json",
        "map.ply",
        "ego_trajectory_ego.tum",
        "weak_places.yaml",
    ):
        assert (again / name).read_bytes() == (out / name).read_bytes(), name
    log_again = yaml.safe_load((again / "run_log.yaml").read_text())
    assert log_again["restarts"] == {"ego_mapper": [-9]} and log_again["replay_resent"] > 0, log_again["restarts"]
    cams = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    assert late.returncode == 0, late.stderr
    got = {line.split()[0]: float(line.split()[1]) for line in late.stdout.splitlines()}
    assert got.keys() == {f"{c['name']}_optical_frame" for c in cams}, late.stdout
    for c in cams:
        assert abs(got[f"{c['name']}_optical_frame"] - c["T_world_camera"]["position"][0]) < 1e-5
    log = yaml.safe_load((out / "run_log.yaml").read_text())
    # Each node's CPU time, lifetime and peak memory (the real graph's profile, #19).
    assert set(log["resources"]) == set(log["graph"]["processes"])
    for node, r in log["resources"].items():
        assert 0.5 < r["cpu_s"] and 1.0 < r["wall_s"] and 40.0 < r["peak_rss_mb"] < 4000.0, (node, r)
    # The graph's memory (PSS summed at one sample) lies below the sum of the peak RSS, which
    # counts each shared library once per process, and above the largest single process.
    rss = [r["peak_rss_mb"] for r in log["resources"].values()]
    assert max(rss) < log["peak_memory_mb"] < sum(rss), (log["peak_memory_mb"], rss)
    # ... and says which process held how much of it at that sample.
    parts = log["peak_memory_by_process_mb"]
    assert "supervisor" in parts and set(parts) <= set(log["graph"]["processes"]) | {"supervisor"}, parts
    assert abs(sum(parts.values()) - log["peak_memory_mb"]) < 0.5 and min(parts.values()) > 5.0, parts
    # The replay's start-up in order: created, every stage announced, subscribers matched (playing), done.
    replay = log["timing"]["replay"]
    assert 0 < replay["created_s"] <= replay["announced_s"] <= replay["playing_s"] < replay["played_s"], replay
    for topic, n in log["replay_published"].items():  # lossless: every message reached every stage
        assert log["received"][topic] and all(v == n for v in log["received"][topic].values()), topic


def check_exports(out):
    """A real run's exports read back: the COLMAP model by pycolmap (CMC centres as in
    cameras.yaml, ego keyframes at ego_trajectory.tum's poses, landmarks reprojecting onto
    their observations), ego_trajectory.tum by evo, a camera_info YAML per camera."""
    import numpy as np
    import pycolmap
    from evo.tools import file_interface

    from yowo_common.trajectory import read_tum

    cams = {c["name"]: c for c in yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]}
    rec = pycolmap.Reconstruction(str(out / "export" / "colmap"))
    images = {im.name: im for im in rec.images.values()}
    for name, c in cams.items():
        info = yaml.safe_load((out / "export" / "camera_info" / f"{name}.yaml").read_text())
        np.testing.assert_allclose(info["camera_matrix"]["data"], np.ravel(c["K"]), atol=1e-6)  # cameras.yaml: 6 digits
        np.testing.assert_allclose(
            images[f"cmc/{name}.png"].projection_center(), c["T_world_camera"]["position"], atol=1e-6
        )
    tum = read_tum(out / "ego_trajectory.tum")
    evo_traj = file_interface.read_tum_trajectory_file(str(out / "ego_trajectory.tum"))
    np.testing.assert_allclose(evo_traj.positions_xyz, tum.positions, atol=1e-9)
    np.testing.assert_allclose(evo_traj.timestamps, tum.stamps_ns / 1e9, atol=1e-6)
    at = dict(zip(tum.stamps_ns.tolist(), tum.positions))
    ego = [im for n, im in images.items() if n.startswith("ego/")]
    assert len(ego) == len(tum.stamps_ns) and len(rec.points3D) > 100
    for im in ego:
        np.testing.assert_allclose(im.projection_center(), at[int(im.name[4:-4])], atol=1e-6)
    rec.update_point_3d_errors()
    assert rec.compute_mean_reprojection_error() < 3.0  # the ego map's landmarks at the refined poses


def check_report(path, cameras, panels=None):
    """report.html parses, embeds a real PNG top view, has a table row per camera and a
    panel (a real PNG) per grouped camera (`panels`, default every camera)."""

    class Report(HTMLParser):
        def __init__(self):
            super().__init__()
            self.images, self.cells, self._cell = [], [], None

        def handle_starttag(self, tag, attrs):
            if tag == "img":
                self.images.append((dict(attrs)["alt"], dict(attrs)["src"]))
            elif tag == "td":
                self._cell = ""

        def handle_data(self, data):
            if self._cell is not None:
                self._cell += data

        def handle_endtag(self, tag):
            if tag == "td" and self._cell is not None:
                self.cells.append(self._cell.strip())
                self._cell = None

    report = Report()
    report.feed(path.read_text())
    images = dict(report.images)
    assert set(images) == {"top view"} | {f"{n} agent fit" for n in (cameras if panels is None else panels)}, (
        images.keys()
    )
    for src in images.values():
        png = base64.b64decode(src.split("base64,", 1)[1])
        assert png.startswith(b"\x89PNG") and len(png) > 20_000  # a drawn figure, not a blank one
    assert all(name in report.cells for name in cameras), report.cells


def check_result_bag(path):
    """result.mcap is one file, opens with rosbags and with the mcap library, holds every
    output topic, the latched ones with their transient-local QoS."""
    from mcap.reader import make_reader

    from yowo_common import topics
    from yowo_common.ros.bag import list_topics

    wanted = {
        topics.TF_STATIC,
        topics.CMC_POSES,
        topics.LAYOUT_MARKERS,
        topics.EGO_MAP,
        topics.LAYOUT,
        topics.MAP_POINTS,
        topics.EGO_PATH,
        topics.GROUPS,
        topics.REFINED_MAP_POINTS,
        topics.REFINED_LAYOUT,
        topics.REFINED_EGO_PATH,
    }
    assert path.is_file()
    found = list_topics(path)
    assert {t.name for t in found if t.count == 1} >= wanted  # rosbags
    assert all(t.latched for t in found if t.name in wanted), [t for t in found if not t.latched]
    with open(path, "rb") as f:
        reader = make_reader(f)
        seen = {channel.topic for _, channel, _ in reader.iter_messages()}
    assert seen >= wanted  # mcap
