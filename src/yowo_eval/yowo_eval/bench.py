"""`yowo bench`: YOWO and the baselines on the same generated recordings, written
to BENCHMARKS.md (tables + the exact command + versions + machine, see
bench_markdown) and results.json. Each case runs in a fresh process so its peak
memory is its own."""

from __future__ import annotations

import json
import multiprocessing
import resource
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from yowo_bringup.config import YowoConfig, fusion_upstream
from yowo_bringup.offline import read_cmc_tracks
from yowo_cmc.group_sfm import calibrate_groups
from yowo_cmc.pipeline import calibrate_cmcs
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset

from .bench_markdown import TRUE_CLOCKS
from .bound import BOUND_VERSION, bound_case
from .ground_truth import read_ground_truth
from .metrics import ErrorSummary, relative_pose_errors
from .omecc_style import calibrate_groups_omecc

# Only scenarios that need CMC images render them (scene keypoints in CMC views, the
# image detector, texture and light): the rest record keypoints only, 3-5x faster.
SCENARIOS = {
    "normal": {"cmc_images": True},
    "texture_poor": {"texture": "poor"},
    "symmetric": {"texture": "symmetric"},
    "dim_light": {"light_intensity": 0.4},
    "stationary": {"long_pause_s": 60.0},
    **{f"kp_noise_{s}px": {"kp_sigma_px": s} for s in (0.5, 1.0, 2.0, 5.0)},
    # The CMC issue's acceptance condition: 1-2 px noise and 5 % outliers. Keypoints
    # only, so it is cheap enough to run on every preset, not just the sweep preset.
    "kp_outliers_5pct": {"kp_sigma_px": 1.0, "outlier_rate": 0.05, "every_preset": True},
    # CMC clocks up to 1 s off the ego clock (yowo_cmc.clock estimates and applies them).
    "clock_offsets": {"cmc_clock_offset_s": 1.0},
    # Other people walking the same rooms (issue #46): images only, for the pose model to find
    # everyone; run by `yowo bench-bystanders`, not by `yowo bench`.
    **{f"bystanders_{n}": {"cmc_images": True, "bystanders": n} for n in (0, 1, 3)},
}
# Presets that only feed the speed/scale table: rendering 42 CMC image streams over the
# long walks of the floor presets would take hours here, so they record keypoints only, run
# the normal scenario on the first seed only, and leave out the relative-pose baselines.
SCALE_ONLY_PRESETS = {"large", "floor50"}

# Relative calibration methods compared in Table "relative_pose_eval": label ->
# (keypoint source, calibration(tracks, the tree's CmcParams)). The baselines are
# labelled reimplementations of the ideas, not the authors' code, and assume
# synchronised clocks.
RELATIVE_METHODS = {
    "YOWO": ("keypoints", calibrate_cmcs),
    "YOWO, image detector": ("images", calibrate_cmcs),
    "YOWO, pose model": ("pose", calibrate_cmcs),
    # Cameras outside the 2-edge-connected groups also pair up along their strongest
    # edge: more cameras calibrated, each pair resting on a single edge.
    "YOWO, left-over pairs": (
        "keypoints",
        lambda tracks, cmc: calibrate_cmcs(tracks, replace(cmc, sfm=replace(cmc.sfm, pair_leftovers=True))),
    ),
    # E-matrix pair with the most inliers, PnP in order of matches, one BA with one
    # sigma; no overlap scores (neither for ordering nor for the edge rule).
    "ECCMP-style": (
        "keypoints",
        lambda tracks, cmc: calibrate_groups(
            tracks, replace(cmc.sfm, overlap_ordering=False, class_sigma=False, min_edge_overlap=0.0)
        ),
    ),
    # Factor graph over the person keypoints from a pairwise initialisation with a
    # person-height scale prior (yowo_eval.omecc_style); YOWO's grouping.
    "OMECC-style": ("keypoints", lambda tracks, cmc: calibrate_groups_omecc(tracks)),
}


def scenario_preset(preset: str, scenario: str):
    spec = SCENARIOS[scenario]
    images = bool({"cmc_images", "texture", "light_intensity"} & spec.keys()) and preset not in SCALE_ONLY_PRESETS
    p = get_preset(preset, cmc_images=images)
    if "texture" in spec or "light_intensity" in spec:
        p = replace(p, scene=replace(p.scene, **{k: v for k, v in spec.items() if k in ("texture", "light_intensity")}))
    if "bystanders" in spec:
        p = replace(p, cmc_keypoints=False, bystanders=replace(p.bystanders, count=spec["bystanders"]))
    if "cmc_clock_offset_s" in spec:
        p = replace(p, cmc_clock_offset_s=spec["cmc_clock_offset_s"])
    if "long_pause_s" in spec:
        p = replace(p, walk=replace(p.walk, long_pause_s=spec["long_pause_s"]))
    if "kp_sigma_px" in spec:
        s = spec["kp_sigma_px"]
        p = replace(
            p,
            detector=replace(
                p.detector,
                sigma_px={0: s, 1: 1.5 * s},
                sigma_body_px=4.0 * s,
                outlier_rate=spec.get("outlier_rate", p.detector.outlier_rate),
            ),
        )
    return p


def bag_for(preset: str, scenario: str, seed: int, bags_dir: Path, log=print) -> Path:
    """The recording of a case, generated once and reused (same seed, same bag). A lock
    per bag lets several runs share `bags_dir` (one generates, the others wait)."""
    import fcntl
    import shutil

    path = bags_dir / f"{preset}_{scenario}_s{seed}"
    bags_dir.mkdir(parents=True, exist_ok=True)
    with open(bags_dir / f".{path.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (path / "metadata.yaml").exists():
            if path.exists():
                shutil.rmtree(path)  # an interrupted generation
            t0 = time.perf_counter()
            summary = generate(scenario_preset(preset, scenario), seed, path)
            log(
                f"generated {path.name}: {summary.duration_s:.0f} s walk, {len(summary.cmcs)} CMCs "
                f"in {time.perf_counter() - t0:.0f} s"
            )
    return path


KEYPOINT_NAMES = {0: "head_top", 1: "ground"}


def has_cmc_images(bag: Path) -> bool:
    from yowo_bringup.contract import cmc_image_topics, discover_inputs

    inputs = discover_inputs(bag)
    counts = {t.name: t.count for t in inputs.topics}
    return any(counts.get(t, 0) for name in inputs.cmc_names for t in cmc_image_topics(name))


def truth_clocked(tracks: list, truth, config: YowoConfig) -> tuple[list, YowoConfig]:
    """The synchronised case of a recording whose CMC clocks are off, on the same data
    (same noise, same frames): each CMC's stamps moved onto the ego clock by the recorded
    truth, clock estimation off. Evaluation only: the pipeline never reads /gt."""
    synced = [t.shifted(truth.clock_offsets_s.get(t.name, 0.0)) for t in tracks]
    off = replace(
        config,
        cmc=replace(config.cmc, estimate_clock_offsets=False),
        fusion=replace(config.fusion, align=replace(config.fusion.align, estimate_clock_offset=False)),
    )
    return synced, off


def relative_pose_case(bag: Path, images: bool, baselines: bool = True, config: YowoConfig = YowoConfig()) -> dict:
    """Table relative_pose_eval's rows for one recording (YOWO alone without `baselines`)."""
    truth = read_ground_truth(bag)
    gt = truth.cameras
    tracks = {"keypoints": read_cmc_tracks(bag, "keypoints", config.cmc)}
    if images:
        tracks["images"] = read_cmc_tracks(bag, "images", config.cmc)
        tracks["pose"] = read_cmc_tracks(bag, "pose", config.cmc)
    out = {}

    def case(tracks_used, calibrate, cmc_params) -> dict:
        t0 = time.perf_counter()
        result = calibrate(tracks_used, cmc_params)
        seconds = time.perf_counter() - t0
        est = {n: T for g in result.groups for n, T in g.T_local_cam.items()}
        groups = {g.group_id: g.names for g in result.groups}
        errs, _ = relative_pose_errors(est, gt, groups)
        entry = {
            "summary": asdict(ErrorSummary.of(errs)),
            "calibrated": len(est),
            "cameras": len(gt),
            "seconds": seconds,
            "errors": {e.name: [e.eps_pos_m, e.eps_rot_deg] for e in errs},
            "groups": groups,
        }
        if truth.clock_offsets_s and cmc_params.estimate_clock_offsets:
            true = truth.clock_offsets_s  # each member's offset to its group's reference against the truth
            entry["clock_errors_ms"] = {
                n: 1e3 * (o - (true.get(n, 0.0) - true.get(g.reference, 0.0)))
                for g in result.groups
                for n, o in g.clock_offsets_s.items()
                if n != g.reference
            }
        return entry

    for method, (source, calibrate) in RELATIVE_METHODS.items():
        if source in tracks and (baselines or method == "YOWO"):
            out[method] = case(tracks[source], calibrate, config.cmc)
    if truth.clock_offsets_s:
        synced, synced_config = truth_clocked(tracks["keypoints"], truth, config)
        out[TRUE_CLOCKS] = case(synced, calibrate_cmcs, synced_config.cmc)
    return out


def detector_case(bag: Path, preset, seed: int, config: YowoConfig = YowoConfig()) -> dict:
    """The built-in image detector against the simulator's agent keypoints (issue: median
    error <= 3 px, >= 90 % of the frames with the whole agent in view detected). The agent
    is in full view when every body keypoint is in the image and not hidden by the static
    scene (the simulated detector's depth test, on the capture rebuilt from its seed); a
    frame counts as detected when it has both the head top and the ground point."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import points_to_array, stamp_to_ns
    from yowo_common.topics import GT_AGENT_KEYPOINTS, parse_cmc_topic
    from yowo_sim.capture import build_capture
    from yowo_sim.detector import visible_points
    from yowo_sim.render import Renderer

    t0 = time.perf_counter()
    tracks = {t.name: t for t in read_cmc_tracks(bag, "images", config.cmc)}
    seconds = time.perf_counter() - t0
    setup = build_capture(preset, seed)
    renderer = Renderer(setup.scene)
    cmcs = {c.name: (c, renderer.render(c.camera, c.T_world_cam)[1]) for c in setup.cmcs}
    agent, frames = {}, {}
    truth = read_ground_truth(bag)  # the agent on the ego clock; each CMC's stamps on its own
    for topic, _, msg in read_messages(bag):
        if topic == GT_AGENT_KEYPOINTS:
            agent[stamp_to_ns(msg.header.stamp)] = points_to_array([p.position for p in msg.poses])
        elif (parse_cmc_topic(topic) or ("", ""))[1] == "camera_info":
            frames.setdefault(parse_cmc_topic(topic)[0], []).append(stamp_to_ns(msg.header.stamp))
    errors = {0: [], 1: []}
    full = detected = 0
    for name, stamps in frames.items():
        cmc, depth = cmcs[name]
        found = (
            {k: dict(zip(tr.stamps_ns.tolist(), tr.uv)) for k, tr in tracks[name].tracks.items()}
            if name in tracks
            else {}
        )
        for s in stamps:
            uv, visible = visible_points(
                cmc.camera,
                cmc.T_world_cam,
                agent[truth.true_time_ns(name, s)],
                depth,
                preset.detector.occlusion_margin_m,
            )
            if not visible.all():
                continue
            full += 1
            detected += all(s in found.get(k, {}) for k in (0, 1))
            for k in (0, 1):
                if s in found.get(k, {}):
                    errors[k].append(float(np.linalg.norm(found[k][s] - uv[k])))
    both = errors[0] + errors[1]
    return {
        "frames_full_view": full,
        "detected": detected,
        "detection_rate": detected / max(full, 1),
        "median_px": float(np.median(both)) if both else float("nan"),
        "median_px_by_id": {KEYPOINT_NAMES[k]: float(np.median(v)) if v else float("nan") for k, v in errors.items()},
        "p90_px_by_id": {
            KEYPOINT_NAMES[k]: float(np.percentile(v, 90)) if v else float("nan") for k, v in errors.items()
        },
        "seconds": seconds,
        "frames": sum(len(v) for v in frames.values()),
    }


def full_case(bag: Path, images: bool, config: YowoConfig = YowoConfig()) -> dict:
    """The whole method (offline API) with and without joint optimisation, the
    Hloc/Kapture-style localisation of each CMC's background against the ego map
    without and with YOWO's poses as prior (Table register_pose_eval_2, when the
    recording has CMC images); ego ATE per stage of the ego pipeline; layout IoU;
    time per stage and the real-time factor."""
    from yowo_bringup.offline import ego_map_data, process
    from yowo_common.trajectory import Trajectory
    from yowo_fusion.pipeline import fuse
    from yowo_fusion.records import ISOLATED_PNP, CmcInput

    from .hloc_style import build_database, localize, read_keyframe_images
    from .metrics import ate, layout_iou, registration_errors

    gt = read_ground_truth(bag)
    r = process(bag, config)
    tracks, backgrounds = r.tracks, r.backgrounds
    no_jo = fuse(
        ego_map_data(r.ego),
        r.grouping.groups,
        r.grouping.ungrouped,
        {t.name: CmcInput(t, backgrounds.get(t.name)) for t in tracks},
        replace(config.fusion, joint_optimisation=False),
        fusion_upstream(config),
    )

    def registration(est: dict, cameras: int = len(gt.cameras)) -> dict:
        errors = registration_errors(est, gt.cameras)
        return asdict(ErrorSummary.of(errors)) | {
            "registered": len(est),
            "cameras": cameras,
            "errors": {e.name: [e.eps_pos_m, e.eps_rot_deg] for e in errors},
        }

    def registered(result) -> dict:
        return {c.name: c.T_world_cam for c in result.cameras if c.T_world_cam is not None}

    reg = {
        "YOWO without joint optimisation": registration(registered(no_jo)),
        "YOWO": registration(registered(r.fusion)) | {"statuses": {c.name: c.status for c in r.fusion.cameras}},
    }
    # Cameras outside every group, registered one by one from the agent track (issue: within 0.2 m).
    outside = [c for c in r.fusion.cameras if not c.group]
    reg["YOWO, cameras outside groups"] = registration(
        {c.name: c.T_world_cam for c in outside if c.method == ISOLATED_PNP and c.T_world_cam is not None}, len(outside)
    )
    if images and backgrounds:
        db = build_database(r.ego.camera, r.ego.T_world_kf, read_keyframe_images(bag, r.ego))
        priors = registered(r.fusion)
        cams = {t.name: t.camera for t in tracks}
        for label, use_prior in (("Hloc-style", False), ("Hloc-style with YOWO prior", True)):
            t0 = time.perf_counter()
            found = {
                n: localize(db, n, bg, cams[n], priors.get(n) if use_prior else None) for n, bg in backgrounds.items()
            }
            reg[label] = registration({n: f.T_world_cam for n, f in found.items() if f.T_world_cam is not None}) | {
                "seconds": time.perf_counter() - t0
            }
    clocks = {}
    if gt.clock_offsets_s:
        synced, synced_config = truth_clocked(tracks, gt, config)
        grouping = calibrate_cmcs(synced, synced_config.cmc)
        reg[TRUE_CLOCKS] = registration(
            registered(
                fuse(
                    ego_map_data(r.ego),
                    grouping.groups,
                    grouping.ungrouped,
                    {t.name: CmcInput(t, backgrounds.get(t.name)) for t in synced},
                    synced_config.fusion,
                    fusion_upstream(synced_config),
                )
            )
        )
        # Each registered camera's offset to the ego clock against the truth.
        clocks = {
            c.name: 1e3 * (c.clock_offset_s - gt.clock_offsets_s.get(c.name, 0.0))
            for c in r.fusion.cameras
            if c.clock_offset_s is not None
        }
    ate_by_stage = {
        stage: ate(Trajectory(r.ego.stamps_ns, T), gt.ego).rmse_m for stage, T in r.ego.trajectories.items()
    }
    ate_by_stage["joint"] = ate(Trajectory(r.ego.stamps_ns, r.fusion.T_world_ego), gt.ego).rmse_m
    duration = (gt.ego.stamps_ns.max() - gt.ego.stamps_ns.min()) / 1e9
    return {
        "registration": reg,
        "ate": ate_by_stage,
        "layout_iou": layout_iou(r.ego.layout.floor_polygons, gt.floor),
        "layout_iou_joint": layout_iou(r.fusion.layout.floor_polygons, gt.floor),
        "seconds": r.seconds,
        "recording_s": duration,
        "realtime_factor": sum(r.seconds.values()) / duration,
        "cmcs": len(gt.cameras),
    } | ({"clock_errors_to_ego_ms": clocks} if gt.clock_offsets_s else {})


def code_version() -> str:
    """The git commit of the source tree this process runs ("+changes" when src/ has
    uncommitted edits), so a resumed run shows which cases ran on which code."""
    import subprocess

    here = Path(__file__).parent

    def git(*args) -> str:
        return subprocess.run(["git", "-C", str(here), *args], capture_output=True, text=True).stdout.strip()

    head = git("rev-parse", "--short", "HEAD")
    if not head:
        return "unknown (not a git checkout)"
    return head + ("+changes" if git("status", "--porcelain", "--", str(here.parents[1])) else "")


def run_case(preset: str, scenario: str, seed: int, bag: Path, full: bool, config: YowoConfig = YowoConfig()) -> dict:
    """One recording: every table's numbers, and this process's peak memory."""
    images = has_cmc_images(bag)
    case = {
        "preset": preset,
        "scenario": scenario,
        "seed": seed,
        "bag": bag.name,
        "code": code_version(),
        # The scale-only presets measure speed and scale: YOWO alone.
        "relative": relative_pose_case(bag, images, preset not in SCALE_ONLY_PRESETS, config),
    }
    case["bound"] = bound_case(case, bag, scenario_preset(preset, scenario))
    if images:
        case["detector"] = detector_case(bag, scenario_preset(preset, scenario), seed, config)
    if full:
        case["full"] = full_case(bag, images, config)
    case["peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return case


def run_bench(
    presets: list[str],
    seeds: list[int],
    scenarios: list[str],
    out_dir: Path,
    log=print,
    full: bool = True,
    sweep_preset: str | None = None,
    resume: bool = False,
    on_case=None,
    config: YowoConfig = YowoConfig(),
) -> dict:
    """Every preset x scenario x seed; with `sweep_preset`, scenarios other than
    "normal" run on that preset only (the larger presets take the normal scenario).
    Each finished case is saved at once to cases.jsonl; `resume` reuses those; `on_case`
    gets the results so far after each case. A case that fails is logged with its
    error and left out of the tables."""
    out_dir.mkdir(parents=True, exist_ok=True)
    saved = out_dir / "cases.jsonl"
    done = {}
    if resume and saved.exists():
        stored = [json.loads(line) for line in saved.read_text().splitlines()]
        for c in stored:
            if c["bound"].get("version") != BOUND_VERSION:
                log(f"{c['preset']} {c['scenario']} seed {c['seed']}: recomputing the stored bound")
                c["bound"] = bound_case(c, out_dir / "bags" / c["bag"], scenario_preset(c["preset"], c["scenario"]))
            done[(c["preset"], c["scenario"], c["seed"], "full" in c)] = c
        saved.write_text("".join(json.dumps(c) + "\n" for c in stored))
    elif saved.exists():
        saved.unlink()
    plan = [
        (preset, scenario, seed)
        for preset in presets
        for scenario in scenarios
        if not (
            sweep_preset
            and scenario != "normal"
            and preset != sweep_preset
            and not SCENARIOS[scenario].get("every_preset")
        )
        and not (preset in SCALE_ONLY_PRESETS and scenario != "normal")
        for seed in (seeds[:1] if preset in SCALE_ONLY_PRESETS else seeds)
    ]
    # Reused cases first, so the tables written after each new case hold every finished one.
    cases = [done[(p, s, seed, full)] for p, s, seed in plan if (p, s, seed, full) in done]
    for p, s, seed in plan:
        if (p, s, seed, full) in done:
            log(f"{p} {s} seed {seed}: reused from {saved}")
    failures = []
    spawn = multiprocessing.get_context("spawn")
    for preset, scenario, seed in plan:
        if (preset, scenario, seed, full) in done:
            continue
        bag = bag_for(preset, scenario, seed, out_dir / "bags", log)
        try:
            with ProcessPoolExecutor(1, mp_context=spawn) as pool:
                case = pool.submit(run_case, preset, scenario, seed, bag, full, config).result()
        except Exception as exc:  # one broken case must not lose the others
            # The worker's traceback arrives as the exception's cause; keep it to find the failing call.
            trace = "".join(traceback.format_exception(exc))
            failures.append(
                {"preset": preset, "scenario": scenario, "seed": seed, "error": str(exc), "traceback": trace}
            )
            log(f"{preset} {scenario} seed {seed}: FAILED: {exc}\n{trace}")
            continue
        with saved.open("a") as f:
            f.write(json.dumps(case) + "\n")
        cases.append(case)
        if on_case:
            on_case(
                {
                    "presets": presets,
                    "seeds": seeds,
                    "scenarios": scenarios,
                    "cases": cases,
                    "failures": failures,
                    "partial": True,
                }
            )
        log(
            f"{preset} {scenario} seed {seed}: "
            + ", ".join(
                f"{m} {r['summary']['pos_avg']:.4f} m / {r['summary']['rot_avg']:.3f} deg"
                for m, r in case["relative"].items()
            )
        )
        if full:
            f = case["full"]
            log(
                f"  full: registration {f['registration']['YOWO']['pos_avg']:.3f} m / "
                f"{f['registration']['YOWO']['rot_avg']:.3f} deg, ATE {f['ate'].get('joint', float('nan')):.3f} m, "
                f"IoU {f['layout_iou']:.3f}, real-time factor {f['realtime_factor']:.2f}, "
                f"peak memory {case['peak_memory_mb']:.0f} MB"
            )
    return {"presets": presets, "seeds": seeds, "scenarios": scenarios, "cases": cases, "failures": failures}
