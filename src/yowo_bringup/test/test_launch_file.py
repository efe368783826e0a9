"""The launch file starts the graph `yowo run` plans: the same nodes, entry points and
parameters. launch and launch_ros have no wheels here, so the launch file runs against
stand-ins that record what it asks for (they implement nothing of launch itself)."""

import runpy
import sys
import types
from pathlib import Path

import pytest

from e2e_helpers import three_camera_recording
from yowo_bringup.run import CMC, FULL, plan_run

LAUNCH_FILE = Path(__file__).parents[1] / "launch" / "yowo.launch.py"


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _stand_ins(config_dir: Path) -> dict[str, types.ModuleType]:
    mods = {
        name: types.ModuleType(name)
        for name in (
            "launch",
            "launch.actions",
            "launch.substitutions",
            "launch_ros",
            "launch_ros.actions",
            "ament_index_python",
            "ament_index_python.packages",
        )
    }
    mods["launch"].LaunchDescription = _Recorded
    mods["launch.actions"].DeclareLaunchArgument = _Recorded
    mods["launch.actions"].OpaqueFunction = _Recorded
    mods["launch_ros.actions"].Node = _Recorded

    class LaunchConfiguration:
        def __init__(self, name):
            self.name = name

        def perform(self, context):
            return context[self.name]

    mods["launch.substitutions"].LaunchConfiguration = LaunchConfiguration
    mods["ament_index_python.packages"].get_package_share_directory = lambda package: str(config_dir)
    return mods


def _entry_points(package: str) -> set[str]:
    text = (Path(__file__).parents[3] / "src" / package / "setup.py").read_text()
    return {line.split("=")[0].strip().strip('"') for line in text.splitlines() if "_node = " in line}


@pytest.mark.parametrize("mode", [CMC, FULL])
def test_the_launch_file_starts_the_planned_graph(mode, tmp_path, monkeypatch):
    if mode == CMC:
        three_camera_recording(tmp_path / "rec", duration_s=6.0)
    else:
        from yowo_sim.capture import generate
        from yowo_sim.presets import get_preset

        generate(get_preset("tiny"), 1, tmp_path / "rec")
    for name, mod in _stand_ins(tmp_path).items():
        monkeypatch.setitem(sys.modules, name, mod)
    description = runpy.run_path(str(LAUNCH_FILE))["generate_launch_description"]()
    declared = {a.args[0]: a.kwargs.get("default_value") for a in description.args[0] if a.args}
    (opaque,) = [a for a in description.args[0] if "function" in a.kwargs]
    context = {
        **declared,
        "bag": str(tmp_path / "rec"),
        "config_file": None,
        "output": str(tmp_path / "out"),
        "mode": mode,
    }
    launched = [n.kwargs for n in opaque.kwargs["function"](context)]
    plan = plan_run(tmp_path / "rec", tmp_path / "out", mode=mode)
    assert [n["name"] for n in launched] == [n.name for n in plan.nodes]
    for node, spec in zip(launched, plan.nodes):
        assert f"{node['package']}.{node['executable']}" == spec.module
        assert node["executable"] in _entry_points(node["package"]), node
        (params,) = node["parameters"]
        # Every parameter the plan gives (topics, sources, the configuration), the run's id aside.
        assert {k: v for k, v in params.items() if k != "run_id"} == {
            k: v for k, v in spec.parameters.items() if k != "run_id"
        }, spec.name
    trackers = [n for n in launched if n["name"].startswith("keypoint_tracker_")]
    assert trackers and all(n["parameters"][0]["source"] == "keypoints" for n in trackers)
    assert all(n["parameters"][0]["keypoints_topic"] for n in trackers)
    if mode == FULL:
        (ego,) = [n for n in launched if n["name"] == "ego_mapper"]
        assert ego["parameters"][0]["color_topic"] and ego["parameters"][0]["depth_topic"]
