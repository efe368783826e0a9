"""YOWO's one configuration tree. Each section is the dataclass its stage already uses,
so defaults live in exactly one place (the dataclass field); `yowo run --config FILE
--set section.key=value`, the nodes (each gets its section as YAML in its `config`
parameter), the offline API and the benchmark all take a YowoConfig, and every run
records the resolved tree with the software versions in results/params.yaml."""

from __future__ import annotations

import platform
import subprocess
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import yaml

from yowo_cmc.config import CmcParams
from yowo_common import topics
from yowo_common.config import ConfigError, dump, load, to_dict
from yowo_ego.config import EgoParams
from yowo_fusion.config import UPSTREAM_HOMES, FusionParams, UpstreamParams

from .layouts import InputParams
from .replay import ReplayParams

__all__ = ["ConfigError", "YowoConfig", "SupervisorParams", "fusion_upstream", "load_config", "node_config", "versions"]


@dataclass(frozen=True)
class SupervisorParams:
    max_restarts: int = 2  # restarts per node; a node that dies more often ends the run [count]
    profile_rate_hz: int = 50  # py-spy samples per second of each node (yowo run --profile)
    # Added to the niceness of the stages that read no recorded or live topic (group SfM, fusion)
    # [niceness]. 0 by default: on a machine busy with other jobs a lowered stage also discovers
    # its peers late (DDS runs in its threads), and its statuses count fewer strays of other runs.
    downstream_niceness: int = 0
    # Threads of each node process's numeric libraries (OpenMP, OpenBLAS, MKL); 0: their
    # defaults, every core [count]. The graph is parallel across its processes: library pools
    # in each of them only spin against each other (docs/notes/speed.md).
    library_threads: int = 1
    # The trackers of this host run in at most this many processes; 0: one process per camera
    # [count]. A process per camera costs memory and a DDS participant each, and Fast DDS's
    # localhost-only discovery (a private run's) reaches the first 32 participants of a host
    # only: on a large floor some stages never heard the replay.
    tracker_processes: int = 8


@dataclass(frozen=True)
class YowoConfig:
    inputs: InputParams = field(default_factory=InputParams)
    replay: ReplayParams = field(default_factory=ReplayParams)
    ego: EgoParams = field(default_factory=EgoParams)
    cmc: CmcParams = field(default_factory=CmcParams)
    fusion: FusionParams = field(default_factory=FusionParams)
    supervisor: SupervisorParams = field(default_factory=SupervisorParams)


# Which section each node reads (trackers are keypoint_tracker_<camera>).
NODE_SECTIONS = {
    topics.REPLAY_STAGE: "replay",
    topics.EGO_STAGE: "ego",
    topics.TRACKER_STAGE: "cmc",
    topics.GROUP_SFM_STAGE: "cmc",
    topics.FUSION_STAGE: "fusion",
}


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> YowoConfig:
    """The tree from a YAML file (sections of keys, any subset) and dotted overrides."""
    text = None
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: no such configuration file")
        text = path.read_text()
        try:
            yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not YAML: {exc}") from exc
    try:
        return load(YowoConfig, text, overrides)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}" if path is not None else str(exc)) from exc


def _value(config: YowoConfig, dotted: str):
    value = config
    for key in dotted.split("."):
        value = getattr(value, key)
    return value


def fusion_upstream(config: YowoConfig) -> UpstreamParams:
    """The other stages' settings the fusion applies again (one home each, not a copy)."""
    return UpstreamParams(**{field: _value(config, home) for field, home in UPSTREAM_HOMES.items()})


# Values of the tree that a node reads besides its section (`config`), each in a parameter.
NODE_EXTRAS = {"fusion": UPSTREAM_HOMES}

# The node parameters that carry the tree (params.yaml records the tree once, not per node).
CONFIG_PARAMETERS = {"config", *(k for extras in NODE_EXTRAS.values() for k in extras)}


def node_config(config: YowoConfig, node: str) -> dict[str, str]:
    """A node's configuration parameters: its section's YAML in `config`, and the YAML of any
    other value of the tree it reads (NODE_EXTRAS)."""
    kind = topics.TRACKER_STAGE if node.startswith(topics.TRACKER_STAGE) else node
    return {
        "config": dump(getattr(config, NODE_SECTIONS[kind])),
        **{name: dump(_value(config, home)) for name, home in NODE_EXTRAS.get(kind, {}).items()},
    }


def versions() -> dict[str, str]:
    """The software a run used, for params.yaml and the benchmark."""
    out = {"python": platform.python_version()}
    for dist in (
        "yowo_bringup",
        "ros-jazzy-rclpy",
        "gtsam",
        "open3d-cpu",
        "opencv-python-headless",
        "numpy",
        "scipy",
        "rosbags",
        "mcap",
        "dacite",
    ):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    try:
        out["git"] = (
            subprocess.run(
                ["git", "describe", "--always", "--dirty"],
                cwd=Path(__file__).parent,
                capture_output=True,
                text=True,
                timeout=5,
            ).stdout.strip()
            or "unknown"
        )
    except (OSError, subprocess.TimeoutExpired):
        out["git"] = "unknown"
    return out


def params_document(config: YowoConfig, nodes: dict[str, dict]) -> dict:
    """results/params.yaml: the resolved tree, the software, each node's wiring."""
    return {"config": to_dict(config), "versions": versions(), "nodes": nodes}
