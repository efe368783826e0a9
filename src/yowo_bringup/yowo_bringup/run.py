"""Plan a run from a recording (which nodes, with which parameters) and write the
results directory. No rclpy here: run_node.py executes the plan."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from yowo_cmc.group_sfm import CameraGroupResult

from .contract import (EGO_COLOR, EGO_DEPTH, EGO_INFO, cmc_image_topics, cmc_info_topic, cmc_keypoints_topic,
                       discover_inputs)
from .results import pose_entry
from .supervisor import NodeSpec

STAGE_MODULES = {
    "replay": "yowo_bringup.replay_node",
    "keypoint_tracker": "yowo_cmc.keypoint_tracker_node",
    "group_sfm": "yowo_cmc.group_sfm_node",
    "ego_mapper": "yowo_ego.ego_mapper_node",
    "fusion": "yowo_fusion.fusion_node",
}
CMC, FULL = "cmc", "full"


@dataclass
class RunPlan:
    bag: Path
    out_dir: Path
    mode: str                              # "cmc": relative calibration only; "full": registered in the map
    cameras: list[str]
    nodes: list[NodeSpec]
    final_stage: str
    warnings: list[str] = field(default_factory=list)


def _first_present(candidates, topics: set[str]) -> str:
    return next((t for t in candidates if t in topics), "")


def plan_run(bag, out_dir, mode: str = FULL, rate: float = 0.0, overrides: dict | None = None) -> RunPlan:
    """Nodes for a recording. `overrides`: {node: {param: value}} from a YAML file or the CLI."""
    inputs = discover_inputs(bag)
    topics = {t.name for t in inputs.topics if t.count > 0}
    problems = list(inputs.problems)
    if not topics:
        raise ValueError(f"{bag}: the recording holds no messages")
    if mode == FULL and not inputs.has_ego:
        raise ValueError(f"{bag}: no complete ego camera ({'; '.join(p for p in problems if 'ego' in p)}); "
                         "use 'yowo calibrate-cmc' for the CMC-only relative calibration")
    nodes, played, cameras = [], [], []
    for c in inputs.cmc_names:
        keypoints = cmc_keypoints_topic(c) if cmc_keypoints_topic(c) in topics else ""
        image = _first_present(cmc_image_topics(c), topics)
        if not keypoints:
            problems.append(f"CMC '{c}': no {cmc_keypoints_topic(c)}; the image-based detector is not "
                            "available yet, so the camera is skipped")
            continue
        cameras.append(c)
        nodes.append(NodeSpec(f"keypoint_tracker_{c}", STAGE_MODULES["keypoint_tracker"],
                              {"camera": c, "source": "keypoints", "image_topic": image if mode == FULL else ""}))
        played += [cmc_info_topic(c), keypoints] + ([image] if image and mode == FULL else [])
    if len(cameras) < 2:
        raise ValueError(f"{bag}: {len(cameras)} usable CMC(s) with agent keypoints; needs at least 2")
    nodes.append(NodeSpec("group_sfm", STAGE_MODULES["group_sfm"], {"cameras": cameras}))
    final = "group_sfm"
    if mode == FULL:
        color, depth = _first_present(EGO_COLOR, topics), _first_present(EGO_DEPTH, topics)
        nodes.append(NodeSpec("ego_mapper", STAGE_MODULES["ego_mapper"],
                              {"color_topic": color, "depth_topic": depth, "info_topic": EGO_INFO}))
        nodes.append(NodeSpec("fusion", STAGE_MODULES["fusion"], {"cameras": cameras}))
        played += [color, depth, EGO_INFO]
        final = "fusion"
    nodes.append(NodeSpec("replay", STAGE_MODULES["replay"], {
        "bag": str(bag), "rate": float(rate), "topics": played, "wait_for_topics": played, "linger_s": 1.0}))
    for spec in nodes:
        spec.parameters.update((overrides or {}).get(spec.name, {}))
    return RunPlan(Path(bag), Path(out_dir), mode, cameras, nodes, final, problems)


def read_intrinsics(bag, cameras: list[str]) -> dict[str, np.ndarray]:
    """K of each camera from its first CameraInfo in the recording."""
    from yowo_common.ros.bag import read_messages

    wanted = {cmc_info_topic(c): c for c in cameras}
    K = {}
    for topic, _, msg in read_messages(bag, wanted):
        K.setdefault(wanted[topic], np.asarray(msg.k, dtype=float).reshape(3, 3))
        if len(K) == len(wanted):
            break
    return K


def write_group_calibration(path: Path, groups: list[CameraGroupResult], ungrouped: dict[str, str],
                            intrinsics: dict[str, np.ndarray]) -> None:
    """cameras.yaml of a CMC-only run: per camera its group and T_group_camera
    (pseudo-scale: the group's reference camera is the identity)."""
    cams = []
    for g in groups:
        for n in g.names:
            cams.append({"name": n, "group": g.group_id, "method": "group_sfm", "status": "ok", "reason": "",
                         "frame": f"{g.group_id} (reference camera {g.reference}, arbitrary scale)",
                         "T_group_camera": pose_entry(g.T_local_cam[n]),
                         "K": np.asarray(intrinsics.get(n, np.zeros((3, 3)))).round(6).tolist(),
                         "reprojection_rmse_px": round(float(g.rmse_px[n]), 4),
                         "num_agent_observations": int(g.num_observations[n])})
    for n, why in ungrouped.items():
        cams.append({"name": n, "group": "", "method": "none", "status": "failed", "reason": why})
    path.write_text(yaml.safe_dump({"cameras": sorted(cams, key=lambda c: c["name"])}, sort_keys=False))
