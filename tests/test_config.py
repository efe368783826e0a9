"""One configuration tree: YAML + dotted overrides, validated with the key named; every
section reaches its nodes and params.yaml; the offline API given the same tree computes
what `yowo run` computes, byte for byte."""

import dataclasses

import pytest
import yaml

from e2e_helpers import three_camera_recording, yowo
from yowo_bringup.config import YowoConfig, fusion_upstream, load_config, node_config
from yowo_common.config import ConfigError, dump, load
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset


def test_tree_from_yaml_and_dotted_overrides(tmp_path):
    f = tmp_path / "site.yaml"
    f.write_text("ego:\n  odometry:\n    scale: 1\ncmc:\n  sfm:\n    ransac_px: 3\n")
    cfg = load_config(
        f, ["ego.odometry.iterations=[4, 2]", "fusion.ok_rmse_px=4", "fusion.joint.relative_error_tol=1e-10"]
    )
    assert cfg.ego.odometry.scale == 1 and cfg.ego.odometry.iterations == (4, 2)
    assert cfg.fusion.joint.relative_error_tol == 1e-10  # YAML 1.1 reads 1e-10 as a string
    assert cfg.cmc.sfm.ransac_px == 3.0 and isinstance(cfg.cmc.sfm.ransac_px, float)
    assert cfg.fusion.ok_rmse_px == 4.0
    assert cfg.ego.odometry.depth_max_m == YowoConfig().ego.odometry.depth_max_m  # the rest: defaults
    assert load(YowoConfig, dump(cfg)) == cfg  # what `yowo config` prints


def section_types(section) -> set[type]:
    """The dataclass types anywhere in a section of the tree."""
    out = set()
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        if dataclasses.is_dataclass(value):
            out |= {type(value)} | section_types(value)
    return out


def test_each_setting_has_one_home_and_reaches_the_fusion_from_there():
    """The fusion cleans the CMC tracks as the group SfM does and rebuilds the ego stage's
    cloud and layout: it reads those stages' settings, it holds no copy of them."""
    cfg = YowoConfig()
    others = section_types(cfg.ego) | section_types(cfg.cmc) | section_types(cfg.replay)
    assert not section_types(cfg.fusion) & others
    cfg = load_config(None, ["cmc.sfm.tracks.gate_px=20", "ego.cloud.voxel_m=0.05", "ego.layout.wall_min_points=7"])
    upstream = fusion_upstream(cfg)
    assert (upstream.tracks.gate_px, upstream.cloud.voxel_m, upstream.layout.wall_min_points) == (20.0, 0.05, 7)
    params = node_config(cfg, "fusion")
    assert load(type(upstream.tracks), params["tracks"]) == cfg.cmc.sfm.tracks
    assert load(type(upstream.cloud), params["cloud"]) == cfg.ego.cloud
    assert load(type(upstream.layout), params["layout"]) == cfg.ego.layout
    assert load(type(cfg.fusion), params["config"]) == cfg.fusion
    assert set(node_config(cfg, "group_sfm")) == {"config"}


@pytest.mark.parametrize(
    "item, message",
    [
        ("ego.odometry.scal=1", "unknown key ego.odometry.scal (did you mean ego.odometry.scale?)"),
        ("egg.odometry.scale=1", "unknown key egg"),
        ("ego.odometry.scale=fast", "ego.odometry.scale: expected int, got 'fast'"),
        ("ego.odometry.scale=1e3", "ego.odometry.scale: expected int, got '1e3'"),
        ("fusion.ok_rmse_px=3 px", "fusion.ok_rmse_px: expected float, got '3 px'"),
        ("ego.odometry=3", "ego.odometry: is a section of keys, got 3"),
        ("ego.odometry.scale", "expected section.key=value"),
    ],
)
def test_bad_keys_and_values_are_named(item, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("?", r"\?")):
        load_config(None, [item])


def test_bad_configuration_file_is_named(tmp_path, ros_env):
    f = tmp_path / "bad.yaml"
    f.write_text("cmc:\n  sfm:\n    min_matchs: 5\n")
    r = yowo("run", tmp_path / "nope", "-o", tmp_path / "out", "--config", f, env=ros_env)
    assert r.returncode == 2 and f"{f}: unknown key cmc.sfm.min_matchs" in r.stderr and "Traceback" not in r.stderr


def test_set_reaches_every_section_and_the_detector(tmp_path, ros_env):
    three_camera_recording(tmp_path / "rec", duration_s=20.0)
    out = tmp_path / "out"
    r = yowo(
        "calibrate-cmc",
        tmp_path / "rec",
        "-o",
        out,
        "--set",
        "cmc.sfm.min_matches=100000",
        "--set",
        "replay.ack_window=4",
        "--set",
        "supervisor.max_restarts=0",
        env=ros_env,
    )
    # No camera pair has 100000 matches: nothing is calibrated, and the run says why.
    assert r.returncode == 1, r.stderr
    doc = yaml.safe_load((out / "cameras.yaml").read_text())["cameras"]
    assert all(c["status"] == "failed" for c in doc), doc
    params = yaml.safe_load((out / "params.yaml").read_text())
    assert params["config"]["cmc"]["sfm"]["min_matches"] == 100000 and params["config"]["replay"]["ack_window"] == 4
    assert params["config"]["supervisor"]["max_restarts"] == 0
    assert params["versions"]["gtsam"] and params["versions"]["numpy"]
    assert params["nodes"]["keypoint_tracker_c1"]["camera"] == "c1"
    assert "configuration: cmc.sfm.min_matches=100000" in (out / "logs" / "group_sfm.log").read_text()
    assert "configuration: replay.ack_window=4" in (out / "logs" / "replay.log").read_text()


def test_offline_api_and_graph_agree_with_the_same_tree(tmp_path, ros_env):
    from yowo_bringup.offline import process
    from yowo_bringup.results import write_cameras_yaml

    bag = tmp_path / "tiny_s5"
    generate(get_preset("tiny"), 5, bag)
    # One key of every section the recorded keypoints go through.
    sets = [
        "ego.odometry.polish_iterations=2",
        "cmc.sfm.ransac_px=2.5",
        "cmc.background_period_s=0.5",
        "fusion.ok_rmse_px=4",
        "replay.ack_window=8",
        "supervisor.max_restarts=1",
        "cmc.sfm.tracks.gate_px=6",
    ]
    out = tmp_path / "graph"
    r = yowo("run", bag, "-o", out, *[a for s in sets for a in ("--set", s)], env=ros_env, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    logs = {n: (out / "logs" / f"{n}.log").read_text() for n in ("ego_mapper", "keypoint_tracker_cam00", "fusion")}
    assert "ego.odometry.polish_iterations=2" in logs["ego_mapper"]
    assert "cmc.background_period_s=0.5" in logs["keypoint_tracker_cam00"]
    assert "fusion.ok_rmse_px=4.0" in logs["fusion"]
    assert "cmc.sfm.tracks.gate_px=6.0" in logs["fusion"]  # the group SfM's setting, read by the fusion too
    offline = process(bag, load_config(None, sets))
    write_cameras_yaml(tmp_path / "offline.yaml", offline.fusion.cameras, offline.grouping.groups)
    assert (tmp_path / "offline.yaml").read_text() == (out / "cameras.yaml").read_text()
    # ... and the keys changed what was computed: the default tree gives another result.
    default = process(bag, YowoConfig())
    write_cameras_yaml(tmp_path / "default.yaml", default.fusion.cameras, default.grouping.groups)
    assert (tmp_path / "default.yaml").read_text() != (out / "cameras.yaml").read_text()
    # The detector's section reaches the trackers: blobs larger than the largest allowed
    # are never the agent, so no camera sees it.
    r = yowo(
        "calibrate-cmc",
        bag,
        "-o",
        tmp_path / "blind",
        "--cmc-source",
        "images",
        "--set",
        "cmc.detector.min_area=0.6",
        env=ros_env,
        timeout=300,
    )
    stages = yaml.safe_load((tmp_path / "blind" / "run_log.yaml").read_text())["stages"]
    assert all("agent in 0" in stages[f"keypoint_tracker_cam0{i}"] for i in range(3)), stages


def test_every_key_has_a_description_and_every_number_a_unit():
    """`yowo config` shows each key's one-line description and unit, read from the comment
    of its dataclass field; a key added without one fails here."""
    from yowo_common.config import leaf_docs

    leaves = leaf_docs(YowoConfig())
    undescribed = [k for k, (_, doc) in leaves.items() if doc is None or not doc.description]
    unitless = [
        k
        for k, (v, doc) in leaves.items()
        if doc and not doc.unit and isinstance(v, (int, float)) and not isinstance(v, bool)
    ]
    assert not undescribed, f"keys without a comment: {undescribed}"
    assert not unitless, f"numbers without a unit (name suffix or a trailing [unit]): {unitless}"


def test_yowo_config_prints_a_file_that_config_takes_back(tmp_path):
    from yowo_common.config import dump_described

    cfg = load_config(None, ["ego.odometry.iterations=[7, 3]", "replay.exclude_prefixes=[/gt/, /x/]"])
    text = dump_described(cfg)
    assert "# image downsampling" in text.split("scale:")[1].splitlines()[0]
    path = tmp_path / "c.yaml"
    path.write_text(text)
    assert load_config(path) == cfg
