"""The results directory of a run from the graph's latched outputs and statuses: written
aside and moved into place, partial when a stage failed, with the run log whatever happens."""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from yowo_cmc.config import CmcParams
from yowo_cmc.coverage import coverage_entry, group_coverage
from yowo_cmc.group_sfm import CameraGroupResult
from yowo_common import topics

from .results import clock_entry, intrinsics_entry, keypoint_noise_entry, pose_entry
from .run import CMC, EGO, FULL, RunPlan


@dataclass(kw_only=True)
class RunOutcome:
    files: list[Path]
    cameras: list  # RegisteredCmc (full) or CameraGroupResult (cmc)
    ungrouped: dict[str, str]
    published: dict[str, int]
    received: dict[str, dict[str, int]]
    mode: str = FULL  # the plan's (a full run without usable CMCs is an ego run)
    failure: str = ""  # why the run failed ('' when it did not)


def write_group_calibration(
    path: Path,
    groups: list[CameraGroupResult],
    ungrouped: dict[str, str],
    cmc: CmcParams = CmcParams(),
    walkers: dict[str, dict] | None = None,
    people: dict | None = None,
) -> None:
    """cameras.yaml of a CMC-only run: per camera its group and T_group_camera
    (pseudo-scale: the group's reference camera is the identity), the intrinsics the group
    SfM used, clock and keypoint noise as a full run writes them, and each camera's coverage
    (yowo_cmc.coverage, from its group's agent points; depths in the group's units).
    `walkers`: per pose-model camera, whom its tracker took for the walker; a camera whose
    walker was a guess among several people is `weak` (the group may join different people),
    unless its people were matched across cameras (`people`: the group SfM's matches,
    yowo_cmc.people_identity.PeopleIdentity.as_dict): then every person it calibrated with is
    the same person in the other cameras, whoever the walker was."""
    coverage = group_coverage(groups, ungrouped, params=cmc.coverage, sfm=cmc.sfm)
    walkers = walkers or {}
    matched = (people or {}).get("people", {})
    cams = []
    for g in groups:
        for n in g.names:
            doubt = "" if n in matched else (walkers.get(n) or {}).get("doubt", "")
            cams.append(
                {
                    "name": n,
                    "group": g.group_id,
                    "method": "group_sfm",
                    "status": "weak" if doubt else "ok",
                    "reason": doubt,
                    "frame": f"{g.group_id} (reference camera {g.reference}, arbitrary scale)",
                    "T_group_camera": pose_entry(g.T_local_cam[n]),
                    **intrinsics_entry(g.cameras.get(n)),
                    **clock_entry(n, g),
                    **keypoint_noise_entry(g),
                    "reprojection_rmse_px": round(float(g.rmse_px[n]), 4),
                    "num_agent_observations": int(g.num_observations[n]),
                    **coverage_entry(coverage.get(n)),
                    **({"walker": walkers[n]} if n in walkers else {}),
                    **({"people": _people_entry(n, people)} if n in matched else {}),
                }
            )
    for n, why in ungrouped.items():
        cams.append(
            {
                "name": n,
                "group": "",
                "method": "none",
                "status": "failed",
                "reason": why,
                **coverage_entry(coverage.get(n)),
            }
        )
    path.write_text(yaml.safe_dump({"cameras": sorted(cams, key=lambda c: c["name"])}, sort_keys=False))


def _people_entry(camera: str, people: dict) -> dict:
    """cameras.yaml: which of the camera's people is which shared person, and the matches'
    evidence with the other cameras."""
    return {
        "shared": people["people"][camera],
        # Copies: YAML would write a match shared by two cameras as an anchor and an alias.
        "matches": [copy.deepcopy(m) for m in people["matches"] if camera in m["cameras"]],
    }


def write_run_results(
    plan: RunPlan, outputs: dict, status: dict, replay, seconds: float, failure: str, graph: dict | None = None
) -> RunOutcome:
    """Everything a run produced into plan.out_dir (partial results when a stage failed),
    written aside and moved into place; `graph`: the run's network, restarts and stray
    messages, for the run log. The run log is written whatever else fails, with the reason."""
    import traceback

    from yowo_cmc.messages import groups_from_msg

    from .outdir import publish_staged, staging_dir

    staged = replace(plan, out_dir=staging_dir(plan.out_dir))
    out, files = staged.out_dir, []
    groups, ungrouped, cameras = [], {}, []
    try:
        groups, ungrouped = groups_from_msg(outputs[topics.GROUPS]) if topics.GROUPS in outputs else ([], {})
        cameras = groups
        if plan.mode == CMC and topics.GROUPS in outputs:
            people = yaml.safe_load(outputs[topics.PEOPLE].data) if topics.PEOPLE in outputs else None
            write_group_calibration(
                out / "cameras.yaml", groups, ungrouped, plan.config.cmc, walkers(plan, outputs), people
            )
            files.append(out / "cameras.yaml")
        if plan.mode in (FULL, EGO):
            cameras = _write_full_results(staged, outputs, files)
    except Exception as exc:  # a result that cannot be written must not hide the run's own outcome
        written = f"writing the results failed ({type(exc).__name__}: {exc}); details in logs/results.log"
        failure = f"{failure}; {written}" if failure else written
        (plan.out_dir / "logs").mkdir(parents=True, exist_ok=True)
        (plan.out_dir / "logs" / "results.log").write_text(traceback.format_exc())
    published = dict(zip(replay.topics, map(int, replay.published_counts))) if replay is not None else {}
    received: dict[str, dict[str, int]] = {}
    for stage, msg in status.items():
        for t, n in zip(msg.input_topics, msg.received_counts):
            received.setdefault(t, {})[stage] = int(n)
    (out / "run_log.yaml").write_text(
        yaml.safe_dump(
            {
                "bag": plan.source,
                "run_id": plan.run_id,
                "mode": plan.mode,
                **({"mode_reason": plan.mode_reason} if plan.mode_reason else {}),
                "seconds": round(seconds, 2),
                "failure": failure,
                "inputs": plan.inputs,
                "warnings": plan.warnings,
                "stages": {s: status[s].message if s in status else "no status received" for s in plan.stages},
                "replay_published": published,
                "received": received,
                "replay_resent": int(replay.resent_messages) if replay is not None else 0,
                "replay_error": replay.error if replay is not None else "no replay status",
                **(graph or {}),
            },
            sort_keys=False,
        )
    )
    files.append(out / "run_log.yaml")
    publish_staged(plan.out_dir)
    files = [plan.out_dir / f.relative_to(out) for f in files]
    return RunOutcome(
        files=files,
        cameras=cameras,
        ungrouped=ungrouped,
        published=published,
        received=received,
        mode=plan.mode,
        failure=failure,
    )


def _write_full_results(plan: RunPlan, outputs: dict, files: list[Path]) -> list:
    from std_msgs.msg import Header

    from yowo_cmc.messages import groups_from_msg
    from yowo_common.ros.bag import BagWriter
    from yowo_common.rosconv import (
        decode_color,
        model_to_camera_info,
        ns_to_time,
        pointcloud2_to_xyz_rgb,
        points_to_array,
        pose_to_matrix,
        stamp_to_ns,
    )
    from yowo_common.trajectory import Trajectory, write_tum
    from yowo_fusion.messages import agent_fits_from_msg, ego_map_from_msg, registered_from_msg, weak_places_from_msg

    from .exports import write_exports
    from .plugins import evaluator
    from .report import wall_segments, write_guidance, write_report
    from .results import (
        write_cameras_yaml,
        write_layout_json,
        write_no_cameras_yaml,
        write_ply,
        write_weak_places_yaml,
    )

    out = plan.out_dir
    cameras = registered_from_msg(outputs[topics.CMC_POSES]) if topics.CMC_POSES in outputs else []
    groups = groups_from_msg(outputs[topics.GROUPS])[0] if topics.GROUPS in outputs else []
    if plan.mode == EGO:
        write_no_cameras_yaml(out / "cameras.yaml", f"ego-only run: {plan.mode_reason}", plan.cmc_problems)
        files.append(out / "cameras.yaml")
    elif cameras:
        write_cameras_yaml(out / "cameras.yaml", cameras, groups, plan.config.cmc, walkers(plan, outputs))
        files.append(out / "cameras.yaml")
        ego = _export_ego_keyframes(outputs)
        files += write_exports(out / "export", cameras, groups, ego, _export_images(plan, outputs, ego))

    def final_and_ego(refined: str, ego_only: str, stem: str, ext: str) -> list[tuple[Path, str]]:
        """The fusion's output (at the jointly optimised ego poses) as stem.ext and the ego
        stage's as stem_ego.ext; the ego stage's as stem.ext when the fusion published none."""
        if refined in outputs:
            return [(out / f"{stem}.{ext}", refined), (out / f"{stem}_ego.{ext}", ego_only)]
        return [(out / f"{stem}.{ext}", ego_only)]

    ego_xy, ego_traj = None, None
    for path, topic in final_and_ego(topics.REFINED_EGO_PATH, topics.EGO_PATH, "ego_trajectory", "tum"):
        if topic in outputs:
            poses = outputs[topic].poses
            traj = Trajectory(
                np.array([stamp_to_ns(p.header.stamp) for p in poses], dtype=np.int64),
                np.array([pose_to_matrix(p.pose) for p in poses]).reshape(-1, 4, 4),
            )
        elif path.stem == "ego_trajectory" and topics.EGO_MAP in outputs:
            ego = ego_map_from_msg(outputs[topics.EGO_MAP])
            traj = Trajectory(ego.stamps_ns, ego.T_world_ego)
        else:
            continue
        write_tum(path, traj)
        files.append(path)
        if ego_xy is None:
            ego_xy, ego_traj = traj.positions[:, :2], traj
    for path, topic in final_and_ego(topics.REFINED_MAP_POINTS, topics.MAP_POINTS, "map", "ply"):
        if topic in outputs:
            write_ply(path, *pointcloud2_to_xyz_rgb(outputs[topic]))
            files.append(path)
    for path, topic in final_and_ego(topics.REFINED_LAYOUT, topics.LAYOUT, "layout", "json"):
        if topic in outputs:
            write_layout_json(path, outputs[topic])
            files.append(path)
    final_layout = outputs.get(topics.REFINED_LAYOUT, outputs.get(topics.LAYOUT))
    floors = [points_to_array(p.points)[:, :2] for p in final_layout.floor_polygons] if final_layout else []
    if plan.mode == EGO and final_layout is not None:
        # The fusion draws the floor for RViz/Foxglove in a full run; here nobody else does.
        from yowo_fusion.messages import layout_markers

        outputs = {**outputs, topics.LAYOUT_MARKERS: layout_markers([], floors, stamp_to_ns(final_layout.header.stamp))}
    import shutil

    result_bag, staging = out / "result.mcap", out / ".result_bag"
    for old in (result_bag, staging):
        if old.is_dir():
            shutil.rmtree(old)
        elif old.exists():
            old.unlink()
    streams = {t: m for t, m in outputs.items() if isinstance(m, list)}
    outputs = {t: m for t, m in outputs.items() if t not in streams}
    stamp = max((stamp_to_ns(m.header.stamp) for m in outputs.values() if hasattr(m, "header")), default=0)
    with BagWriter(staging) as bag:
        for topic, msg in outputs.items():
            bag.write(topic, msg, stamp, latched=True)  # every collected output is latched
        for topic, msgs in streams.items():  # a stream's messages at their own stamps
            for msg in msgs:
                bag.write(topic, msg, stamp_to_ns(msg.header.stamp))
        # Each registered camera's intrinsics in its optical frame: Foxglove / RViz draw its frustum.
        for c in cameras:
            if c.camera is not None and c.T_world_cam is not None:
                info = model_to_camera_info(
                    c.camera, Header(stamp=ns_to_time(stamp), frame_id=f"{c.name}_optical_frame")
                )
                bag.write(topics.cmc_info_topic(c.name), info, stamp, latched=True)
    # One MCAP file (its channels carry the QoS, latched ones transient-local), not a folder.
    (written,) = staging.glob("*.mcap")
    written.rename(result_bag)
    shutil.rmtree(staging)
    files.append(result_bag)
    # With the evaluation installed and ground truth in the recording, the report also
    # shows the errors (a live run has none).
    ev = evaluator()
    evaluated = ev.evaluate_run(out, plan.bag) if ev is not None and plan.bag is not None else None
    metrics, gt_cams = evaluated or (None, None)
    walls = wall_segments(final_layout.planes) if final_layout else []
    fits = agent_fits_from_msg(outputs[topics.AGENT_FIT]) if topics.AGENT_FIT in outputs else []
    weak = weak_places_from_msg(outputs[topics.WEAK_PLACES]) if topics.WEAK_PLACES in outputs else None
    if weak is not None:
        write_weak_places_yaml(out / "weak_places.yaml", weak)
        files.append(out / "weak_places.yaml")
    guidance = streams.get(topics.GUIDANCE)  # the updates during the walk; the last is the final one
    if guidance and cameras:
        files += write_guidance(
            out,
            plan.source,
            cameras,
            guidance[-1],
            ego_xy,
            floors,
            walls,
            weak,
            plan.config.cmc.coverage,
            sightings(streams, [c.name for c in cameras], ego_traj),
        )
    write_report(
        out / "report.html",
        plan.source,
        cameras,
        ego_xy,
        floors,
        metrics,
        gt_cams,
        plan.warnings,
        walls,
        [(f, size, decode_color(bg) if bg is not None else None) for f, size, bg in fits],
        no_cameras=f"No camera registered (ego-only run): {plan.mode_reason}" if plan.mode == EGO else "",
        walkers=walkers(plan, outputs),
        weak_places=weak,
        guidance_page="guidance.html" if guidance and cameras else "",
    )
    files.append(out / "report.html")
    if metrics:
        ev.write_metrics(metrics, out / "metrics.json")
        files.append(out / "metrics.json")
    return cameras


def sightings(streams: dict, names: list[str], traj) -> dict[str, np.ndarray]:
    """Per camera, where on the floor the walker was (the ego trajectory's xy) at each of its
    frames with the walker's keypoints (its tracker's stream; its own clock, near enough here)."""
    from yowo_common.rosconv import stamp_to_ns

    if traj is None or len(traj.stamps_ns) < 2:
        return {}
    out = {}
    for name in names:
        stamps = [stamp_to_ns(m.header.stamp) for m in streams.get(topics.tracker_keypoints(name), []) if m.keypoints]
        inside = [s for s in stamps if traj.stamps_ns[0] <= s <= traj.stamps_ns[-1]]
        if inside:
            xy = traj.positions[:, :2]
            out[name] = np.column_stack([np.interp(inside, traj.stamps_ns, xy[:, k]) for k in range(2)])
    return out


def _export_images(plan: RunPlan, outputs: dict, ego):
    """The pixels the COLMAP export names: each CMC's background (the fusion's agent fits
    carry it) and the ego keyframes' colour images, read again from the recording."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import decode_color, stamp_to_ns
    from yowo_fusion.messages import agent_fits_from_msg

    from .exports import ExportImages

    fits = agent_fits_from_msg(outputs[topics.AGENT_FIT]) if topics.AGENT_FIT in outputs else []
    cmc = {f.name: decode_color(bg) for f, _, bg in fits if bg is not None}
    keyframes, frames = set() if ego is None else {int(s) for s in ego.stamps_ns}, {}
    mapper = next((n for n in plan.nodes if n.name == topics.EGO_STAGE), None)
    if keyframes and mapper is not None and plan.bag is not None:
        for _, _, msg in read_messages(plan.bag, [mapper.parameters["color_topic"]]):
            if stamp_to_ns(msg.header.stamp) in keyframes:
                frames[stamp_to_ns(msg.header.stamp)] = decode_color(msg)
    return ExportImages(cmc=cmc, ego=frames)


def _export_ego_keyframes(outputs: dict):
    """The ego map's keyframes for the exports, at the fusion's jointly optimised poses where
    the run has them (the refined path holds one pose per keyframe stamp)."""
    from dataclasses import replace

    from yowo_common.rosconv import pose_to_matrix, stamp_to_ns
    from yowo_fusion.messages import ego_map_from_msg

    if topics.EGO_MAP not in outputs:
        return None
    ego = ego_map_from_msg(outputs[topics.EGO_MAP])
    if topics.REFINED_EGO_PATH in outputs:
        refined = {stamp_to_ns(p.header.stamp): pose_to_matrix(p.pose) for p in outputs[topics.REFINED_EGO_PATH].poses}
        if all(int(s) in refined for s in ego.stamps_ns):
            ego = replace(ego, T_world_ego=np.array([refined[int(s)] for s in ego.stamps_ns]).reshape(-1, 4, 4))
    return ego


def walkers(plan: RunPlan, outputs: dict) -> dict[str, dict]:
    """Per camera of the pose model, which person its tracker took for the walker and why."""
    return {
        c: yaml.safe_load(outputs[topics.tracker_walker(c)].data)
        for c in plan.cameras
        if topics.tracker_walker(c) in outputs
    }
