"""Lint as a test: ruff (pycodestyle errors, pyflakes, import order, bugbear) is clean and its formatter applied."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_is_clean():
    r = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--output-format", "concise", "src", "tests"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr


def test_ruff_format_is_applied():
    """One layout for the whole tree (`ruff format src tests scripts` fixes it)."""
    r = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", "src", "tests", "scripts"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stdout + r.stderr


RUNTIME = ("yowo_common", "yowo_ego", "yowo_cmc", "yowo_fusion", "yowo_bringup")


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def test_runtime_packages_never_import_the_evaluation():
    """Benchmark, metrics and baselines live in yowo_eval; the runtime finds it only
    through entry points (yowo_bringup.plugins), so an install without it still runs."""
    offenders = [
        f"{p.relative_to(ROOT)}: {m}"
        for pkg in RUNTIME
        for p in (ROOT / "src" / pkg / pkg).rglob("*.py")
        for m in imported_modules(p)
        if m.split(".")[0] in ("yowo_eval", "yowo_sim")
    ]
    assert not offenders, offenders


# The rosdep key of each third-party import (rosdistro rosdep/python.yaml and base.yaml;
# gtsam is a package of the Jazzy distribution); None: no key exists, requirements.txt
# installs it (said in the package.xml).
ROSDEP = {
    "cv2": "python3-opencv",
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "gtsam": "gtsam",
    "rosbags": "python3-rosbags-pip",
    "mcap": "mcap-ros2-support",
    "shapely": "python3-shapely",
    "open3d": "python3-open3d-pip",
    "networkx": "python3-networkx",
    "matplotlib": "python3-matplotlib",
    "rich": "python3-rich",
    "dacite": None,
    "lz4": None,
    "ai_edge_litert": None,
    "zstandard": None,
    "av": "python3-av",
}
ROS_PACKAGES = {
    "rclpy",
    "builtin_interfaces",
    "geometry_msgs",
    "nav_msgs",
    "sensor_msgs",
    "std_msgs",
    "tf2_msgs",
    "visualization_msgs",
    "rosgraph_msgs",
    "yowo_msgs",
    "yowo_common",
    "yowo_ego",
    "yowo_cmc",
    "yowo_fusion",
    "yowo_bringup",
    "yowo_sim",
    "yowo_eval",
    "launch",
    "launch_ros",
    "ament_index_python",
}
PYTHON_PACKAGES = RUNTIME + ("yowo_sim", "yowo_eval")


def test_package_xml_declares_what_the_code_imports():
    import xml.etree.ElementTree as ET

    problems = []
    for pkg in PYTHON_PACKAGES:
        declared = {e.text for e in ET.parse(ROOT / "src" / pkg / "package.xml").getroot().iter("exec_depend")}
        # the package's modules and its launch files (installed with it)
        sources = [*(ROOT / "src" / pkg / pkg).rglob("*.py"), *(ROOT / "src" / pkg / "launch").glob("*.py")]
        imported = {m.split(".")[0] for p in sources for m in imported_modules(p)}
        imported -= set(sys.stdlib_module_names) | {pkg}
        unknown = sorted(m for m in imported if m not in ROSDEP and m not in ROS_PACKAGES)
        needed = {ROSDEP.get(m, m) for m in imported if m not in unknown} - {None}
        if any((ROOT / "src" / pkg / pkg).glob("*_node.py")):
            needed.add("rclpy")  # its nodes run on rclpy (through yowo_common's StageNode)
        if unknown:
            problems.append(f"{pkg}: no rosdep key known for {unknown} (add it to ROSDEP)")
        if needed - declared:
            problems.append(f"{pkg}/package.xml: missing exec_depend {sorted(needed - declared)}")
        if declared - needed:
            problems.append(f"{pkg}/package.xml: exec_depend {sorted(declared - needed)} is never imported")
    assert not problems, "\n".join(problems)


def test_every_python_package_has_the_setup_cfg_ros2_run_needs():
    import configparser

    for pkg in PYTHON_PACKAGES:
        cfg = configparser.ConfigParser()
        cfg.read(ROOT / "src" / pkg / "setup.cfg")
        assert cfg.get("develop", "script_dir") == f"$base/lib/{pkg}", pkg
        assert cfg.get("install", "install_scripts") == f"$base/lib/{pkg}", pkg


# Libraries a keypoint tracker never uses and that took most of its start-up (2.2-2.7 CPU s
# of each tracker's ~4, issue #19): the group SfM's and the track smoothing's.
SFM_ONLY = ("gtsam", "scipy.signal", "networkx")


def heavy_imports(module: str) -> list[str]:
    code = f"import sys, {module}; print(' '.join(m for m in {SFM_ONLY!r} if m in sys.modules))"
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return r.stdout.split()


def test_the_tracker_modules_import_no_sfm_library():
    """What a keypoint tracker runs on (the parameters, the keypoint input, the pose model)
    stays light; the SfM's libraries are imported where tracks are smoothed or solved."""
    for module in ("yowo_cmc.params", "yowo_cmc.keypoint_input", "yowo_cmc.pose_model", "yowo_cmc.background"):
        assert heavy_imports(module) == [], module


def test_the_keypoint_tracker_node_imports_no_sfm_library():
    assert heavy_imports("yowo_cmc.keypoint_tracker_node") == []
