"""`yowo bench`: YOWO and the baselines on the same generated recordings, written
to BENCHMARKS.md (tables + the exact command + versions + machine) and JSON."""
from __future__ import annotations

import json
import os
import platform
import shlex
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from yowo_cmc.group_sfm import SfmParams, calibrate_groups
from yowo_sim.capture import generate
from yowo_sim.detector import DetectorSpec
from yowo_sim.presets import get_preset

from .evaluation import ErrorSummary, relative_pose_errors
from .offline import read_cmc_tracks
from .results import read_ground_truth

# Only scenarios that need CMC images render them (scene keypoints in CMC views, the
# image detector, texture and light): the rest record keypoints only, 3-5x faster.
SCENARIOS = {
    "normal": {"cmc_images": True},
    "texture_poor": {"texture": "poor"},
    "symmetric": {"texture": "symmetric"},
    "dim_light": {"light_intensity": 0.4},
    "stationary": {"long_pause_s": 60.0},
    **{f"kp_noise_{s}px": {"kp_sigma_px": s} for s in (0.5, 1.0, 2.0, 5.0)},
}

# Relative calibration methods compared in Table "relative_pose_eval".
RELATIVE_METHODS = {
    "YOWO": SfmParams(),
    # Labelled reimplementation of the idea, not the authors' code: E-matrix pair with the
    # most inliers, PnP in order of matches, one BA with one sigma, no overlap scores.
    "ECCMP-style": SfmParams(overlap_ordering=False, per_id_sigma=False, min_edge_overlap=0.0),
}


def scenario_preset(preset: str, scenario: str):
    spec = SCENARIOS[scenario]
    images = bool({"cmc_images", "texture", "light_intensity"} & spec.keys())
    p = get_preset(preset, cmc_images=images)
    if "texture" in spec or "light_intensity" in spec:
        p = replace(p, scene=replace(p.scene, **{k: v for k, v in spec.items() if k in ("texture", "light_intensity")}))
    if "long_pause_s" in spec:
        p = replace(p, walk=replace(p.walk, long_pause_s=spec["long_pause_s"]))
    if "kp_sigma_px" in spec:
        s = spec["kp_sigma_px"]
        p = replace(p, detector=DetectorSpec(sigma_px={0: s, 1: 1.5 * s}, sigma_body_px=4.0 * s))
    return p


def bag_for(preset: str, scenario: str, seed: int, bags_dir: Path, log=print) -> Path:
    """The recording of a case, generated once and reused (same seed, same bag)."""
    path = bags_dir / f"{preset}_{scenario}_s{seed}"
    if not (path / "metadata.yaml").exists():
        if path.exists():
            import shutil
            shutil.rmtree(path)  # an interrupted generation
        t0 = time.perf_counter()
        summary = generate(scenario_preset(preset, scenario), seed, path)
        log(f"generated {path.name}: {summary.duration_s:.0f} s walk, {len(summary.cmcs)} CMCs "
            f"in {time.perf_counter() - t0:.0f} s")
    return path


def relative_pose_case(bag: Path) -> dict:
    gt = read_ground_truth(bag).cameras
    tracks = read_cmc_tracks(bag)
    out = {}
    for method, params in RELATIVE_METHODS.items():
        t0 = time.perf_counter()
        result = calibrate_groups(tracks, params)
        seconds = time.perf_counter() - t0
        est = {n: T for g in result.groups for n, T in g.T_local_cam.items()}
        groups = {g.group_id: g.names for g in result.groups}
        errs, _ = relative_pose_errors(est, gt, groups)
        out[method] = {"summary": asdict(ErrorSummary.of(errs)), "calibrated": len(est), "cameras": len(tracks),
                       "seconds": seconds, "errors": {e.name: e.eps_pos_m for e in errs}, "groups": groups}
    return out


def detector_case(bag: Path, preset, seed: int) -> dict:
    """The built-in image detector against the simulator's agent keypoints (issue: median
    error <= 3 px, >= 90 % of the frames with the whole agent in view detected). The agent
    is in full view when every body keypoint is in the image and not hidden by the static
    scene (the simulated detector's depth test, on the capture rebuilt from its seed); a
    frame counts as detected when it has both the head top and the ground point."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import points_to_array, stamp_to_ns
    from yowo_sim.capture import GT_AGENT_KEYPOINTS, build_capture
    from yowo_sim.detector import visible_points
    from yowo_sim.render import Renderer

    t0 = time.perf_counter()
    tracks = {t.name: t for t in read_cmc_tracks(bag, source="images")}
    seconds = time.perf_counter() - t0
    setup = build_capture(preset, seed)
    renderer = Renderer(setup.scene)
    cmcs = {c.name: (c, renderer.render(c.camera, c.T_world_cam)[1]) for c in setup.cmcs}
    agent, frames = {}, {}
    for topic, _, msg in read_messages(bag):
        if topic == GT_AGENT_KEYPOINTS:
            agent[stamp_to_ns(msg.header.stamp)] = points_to_array([p.position for p in msg.poses])
        elif topic.startswith("/cmc/") and topic.endswith("/camera_info"):
            frames.setdefault(topic.split("/")[2], []).append(stamp_to_ns(msg.header.stamp))
    errors = {0: [], 1: []}
    full = detected = 0
    for name, stamps in frames.items():
        cmc, depth = cmcs[name]
        found = {k: dict(zip(tr.stamps_ns.tolist(), tr.uv)) for k, tr in tracks[name].tracks.items()} \
            if name in tracks else {}
        for s in stamps:
            uv, visible = visible_points(cmc.camera, cmc.T_world_cam, agent[s], depth, preset.detector.occlusion_margin_m)
            if not visible.all():
                continue
            full += 1
            detected += all(s in found.get(k, {}) for k in (0, 1))
            for k in (0, 1):
                if s in found.get(k, {}):
                    errors[k].append(float(np.linalg.norm(found[k][s] - uv[k])))
    both = errors[0] + errors[1]
    return {"frames_full_view": full, "detected": detected, "detection_rate": detected / max(full, 1),
            "median_px": float(np.median(both)) if both else float("nan"),
            "median_px_by_id": {k: float(np.median(v)) if v else float("nan") for k, v in errors.items()},
            "p90_px_by_id": {k: float(np.percentile(v, 90)) if v else float("nan") for k, v in errors.items()},
            "seconds": seconds, "frames": sum(len(v) for v in frames.values())}


def relative_pose_bound(bag: Path, groups: dict[str, list[str]], preset) -> dict[str, float]:
    """Cramer-Rao bound of each CMC's position in its group: the marginal covariance of
    the group bundle adjustment evaluated at the ground truth (GTSAM Marginals) with the
    simulated detector's noise, gauge fixed by the first camera and the scale of the
    first baseline. Observations are the recorded detections, snapped to the 10 Hz grid
    the estimator uses. Returns camera -> RMS KU-aligned position error (m) that an
    efficient estimator would reach (the bound pushed through the evaluation's alignment)."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from yowo_common.bundle import cal3, pose3
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import camera_info_to_model, points_to_array, stamp_to_ns
    from yowo_sim.capture import GT_AGENT_KEYPOINTS

    gt = read_ground_truth(bag).cameras
    spec = preset.detector
    period = int(1e9 / preset.cmc_hz)
    agent: dict[int, np.ndarray] = {}
    dets: dict[str, list[tuple[int, int]]] = {}
    cams = {}
    for topic, _, msg in read_messages(bag):
        if topic == GT_AGENT_KEYPOINTS:
            agent[stamp_to_ns(msg.header.stamp)] = points_to_array([p.position for p in msg.poses])
        elif topic.endswith("/agent_keypoints"):
            dets.setdefault(msg.camera_name, []).extend((stamp_to_ns(msg.header.stamp), k.id) for k in msg.keypoints)
        elif topic.startswith("/cmc/") and topic.endswith("/camera_info") and topic.split("/")[2] not in cams:
            cams[topic.split("/")[2]] = camera_info_to_model(msg)
    bounds = {}
    for names in groups.values():
        obs: dict[tuple[int, int], list] = {}
        for i, n in enumerate(names):
            for stamp, kp in dets.get(n, []):
                if stamp in agent and kp < len(agent[stamp]):
                    obs.setdefault((round(stamp / period), kp), []).append((i, n, agent[stamp][kp], kp))
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for i, n in enumerate(names):
            values.insert(X(i), pose3(gt[n]))
        for key, views in enumerate(v for v in obs.values() if len({i for i, *_ in v}) >= 2):
            values.insert(L(key), gtsam.Point3(*views[0][2]))  # shared point: the grid slot's first sample
            for i, n, P, kp in views:
                sigma = spec.sigma_px.get(kp, spec.sigma_body_px)
                graph.add(gtsam.GenericProjectionFactorCal3_S2(
                    gtsam.Point2(*cams[n].project_world(gt[n], views[0][2][None])[0][0]),
                    gtsam.noiseModel.Isotropic.Sigma(2, max(sigma, 0.1)), X(i), L(key), cal3(cams[n])))
        # Gauge priors tight against the cm-level bounds yet loose enough for a stable Cholesky.
        graph.add(gtsam.PriorFactorPose3(X(0), pose3(gt[names[0]]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-5)))
        base = float(np.linalg.norm(gt[names[1]][:3, 3] - gt[names[0]][:3, 3]))
        graph.add(gtsam.RangeFactorPose3(X(0), X(1), base, gtsam.noiseModel.Isotropic.Sigma(1, 1e-5)))
        try:
            marginals = gtsam.Marginals(graph, values)
        except RuntimeError:
            continue  # a point seen once is unconstrained: no bound for this group
        # The metric is KU-aligned, so push the bound through the same alignment: sample
        # the joint marginal, perturb the ground truth, align, measure (Monte Carlo).
        keys = gtsam.KeyVector([X(i) for i in range(1, len(names))])
        cov = marginals.jointMarginalCovariance(keys).fullMatrix()
        rng = np.random.default_rng(0)
        errors = {n: [] for n in names}
        for delta in rng.multivariate_normal(np.zeros(len(cov)), cov, size=200):
            est = {names[0]: gt[names[0]]}
            for i, n in enumerate(names[1:]):
                est[n] = pose3(gt[n]).retract(delta[6 * i: 6 * i + 6]).matrix()
            for e in relative_pose_errors(est, gt, {"g": names})[0]:
                errors[e.name].append(e.eps_pos_m)
        bounds.update({n: float(np.sqrt(np.mean(np.square(v)))) for n, v in errors.items()})
    return bounds


def full_case(bag: Path) -> dict:
    """The whole method (offline API) with and without joint optimisation; ego ATE per
    stage of the ego pipeline; layout IoU; time per stage and the real-time factor."""
    from yowo_fusion.pipeline import CmcInput, FusionParams, fuse

    from .evaluation import Trajectory, ate, layout_iou, registration_errors
    from .offline import ego_map_data, process, read_backgrounds, read_cmc_tracks

    gt = read_ground_truth(bag)
    r = process(bag)
    tracks = read_cmc_tracks(bag)
    backgrounds = read_backgrounds(bag, [t.name for t in tracks])
    no_jo = fuse(ego_map_data(r.ego), r.grouping.groups, r.grouping.ungrouped,
                 {t.name: CmcInput(t, backgrounds.get(t.name)) for t in tracks}, FusionParams(joint_optimisation=False))

    def registration(result):
        est = {c.name: c.T_world_cam for c in result.cameras if c.T_world_cam is not None}
        return asdict(ErrorSummary.of(registration_errors(est, gt.cameras))) | {"registered": len(est),
                                                                                 "cameras": len(gt.cameras)}
    ate_by_stage = {stage: ate(Trajectory(r.ego.stamps_ns, T), gt.ego).rmse_m
                    for stage, T in r.ego.trajectories.items()}
    ate_by_stage["joint"] = ate(Trajectory(r.ego.stamps_ns, r.fusion.T_world_ego), gt.ego).rmse_m
    duration = (gt.ego.stamps_ns.max() - gt.ego.stamps_ns.min()) / 1e9
    return {"registration": registration(r.fusion), "registration_no_jo": registration(no_jo),
            "ate": ate_by_stage, "layout_iou": layout_iou(r.ego.layout.floor_polygons, gt.floor),
            "seconds": r.seconds, "recording_s": duration, "realtime_factor": sum(r.seconds.values()) / duration}


def _mean(values):
    values = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def run_bench(preset: str, seeds: list[int], scenarios: list[str], out_dir: Path, log=print, full: bool = True) -> dict:
    out_dir.mkdir(parents=True, exist_ok=True)
    cases = []
    for scenario in scenarios:
        for seed in seeds:
            bag = bag_for(preset, scenario, seed, out_dir / "bags", log)
            case = {"scenario": scenario, "seed": seed, "bag": bag.name, "relative": relative_pose_case(bag)}
            yowo = case["relative"]["YOWO"]
            bound = relative_pose_bound(bag, yowo["groups"], scenario_preset(preset, scenario))
            ratios = [yowo["errors"][n] / b for n, b in bound.items() if n in yowo["errors"] and b > 0]
            case["bound"] = {"position_m": bound, "mean_bound_m": _mean(bound.values()),
                             "mean_ratio": _mean(ratios)}
            if full:
                case["full"] = full_case(bag)
                f = case["full"]
                log(f"  full: registration {f['registration']['pos_avg']:.3f} m / {f['registration']['rot_avg']:.3f} deg, "
                    f"ATE {f['ate'].get('joint', float('nan')):.3f} m, IoU {f['layout_iou']:.3f}, "
                    f"real-time factor {f['realtime_factor']:.2f}")
            cases.append(case)
            log(f"{scenario} seed {seed}: " + ", ".join(
                f"{m} {r['summary']['pos_avg']:.4f} m / {r['summary']['rot_avg']:.3f} deg"
                for m, r in case["relative"].items()))
    return {"preset": preset, "seeds": seeds, "scenarios": scenarios, "cases": cases}


def environment() -> dict:
    import cv2
    import gtsam  # noqa: F401
    import open3d

    cpu = ""
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    from importlib.metadata import version
    return {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "open3d": open3d.__version__, "gtsam": version("gtsam"), "cpu": cpu, "cores": os.cpu_count(),
            "date": time.strftime("%Y-%m-%d")}


def markdown(results: dict, command: str, env: dict) -> str:
    lines = ["# BENCHMARKS", "", "Produced by:", "", "```", command, "```", "",
             f"Machine: {env['cpu']} ({env['cores']} cores); Python {env['python']}, numpy {env['numpy']}, "
             f"OpenCV {env['opencv']}, Open3D {env['open3d']}, GTSAM {env['gtsam']}; {env['date']}.", "",
             f"Preset `{results['preset']}`, seeds {results['seeds']}. Errors are averaged over seeds; "
             "each seed's value is the avg (or max) over cameras.", "",
             "## CMC relative pose (KU-aligned per group), paper Table relative_pose_eval", "",
             "| scenario | method | avg eps_pos [m] | max eps_pos [m] | avg eps_rot [deg] | max eps_rot [deg] "
             "| calibrated / cameras | time [s] |", "|---|---|---|---|---|---|---|---|"]
    by_scenario: dict[str, list] = {}
    for case in results["cases"]:
        by_scenario.setdefault(case["scenario"], []).append(case)
    for scenario, cases in by_scenario.items():
        for method in RELATIVE_METHODS:
            rs = [c["relative"][method] for c in cases]
            lines.append(
                f"| {scenario} | {method} | {_mean(r['summary']['pos_avg'] for r in rs):.4f} | "
                f"{_mean(r['summary']['pos_max'] for r in rs):.4f} | {_mean(r['summary']['rot_avg'] for r in rs):.3f} | "
                f"{_mean(r['summary']['rot_max'] for r in rs):.3f} | "
                f"{sum(r['calibrated'] for r in rs)} / {sum(r['cameras'] for r in rs)} | "
                f"{_mean(r['seconds'] for r in rs):.1f} |")
    full = [c for c in results["cases"] if "full" in c]
    if full:
        lines += ["", "## CMC registration in the map frame (no alignment), paper Tables register_pose_eval / ablation",
                  "", "The map frame is YOWO's (defined by the first ego pose); ground truth is expressed in it.", "",
                  "| scenario | method | avg eps_pos [m] | max eps_pos [m] | avg eps_rot [deg] | max eps_rot [deg] "
                  "| registered / cameras |", "|---|---|---|---|---|---|---|"]
        for scenario in by_scenario:
            cs = [c["full"] for c in full if c["scenario"] == scenario]
            for key, label in (("registration_no_jo", "YOWO without joint optimisation"), ("registration", "YOWO")):
                rs = [c[key] for c in cs]
                lines.append(f"| {scenario} | {label} | {_mean(r['pos_avg'] for r in rs):.4f} | "
                             f"{_mean(r['pos_max'] for r in rs):.4f} | {_mean(r['rot_avg'] for r in rs):.3f} | "
                             f"{_mean(r['rot_max'] for r in rs):.3f} | {sum(r['registered'] for r in rs)} / "
                             f"{sum(r['cameras'] for r in rs)} |")
        stages = list(full[0]["full"]["ate"])
        lines += ["", "## Scene mapping, paper Table scene_map", "",
                  "| scenario | " + " | ".join(f"ego ATE RMSE: {s} [m]" for s in stages) + " | layout IoU |",
                  "|---|" + "---|" * (len(stages) + 1)]
        for scenario in by_scenario:
            cs = [c["full"] for c in full if c["scenario"] == scenario]
            lines.append(f"| {scenario} | " + " | ".join(f"{_mean(c['ate'][s] for c in cs):.4f}" for s in stages)
                         + f" | {_mean(c['layout_iou'] for c in cs):.3f} |")
        lines += ["", "## Speed (2 cores)", "", "| scenario | ego [s] | CMC [s] | fusion [s] | recording [s] "
                  "| processing / recording time |", "|---|---|---|---|---|---|"]
        for scenario in by_scenario:
            cs = [c["full"] for c in full if c["scenario"] == scenario]
            lines.append(f"| {scenario} | {_mean(c['seconds']['ego'] for c in cs):.1f} | "
                         f"{_mean(c['seconds']['cmc'] for c in cs):.1f} | {_mean(c['seconds']['fusion'] for c in cs):.1f} | "
                         f"{_mean(c['recording_s'] for c in cs):.1f} | {_mean(c['realtime_factor'] for c in cs):.2f} |")
    lines += ["", "## Achieved error / Cramer-Rao bound (CMC position in its group)", "",
              "Bound: GTSAM marginals of the group BA at ground truth with the simulated detector noise "
              "(gauge: first camera fixed, first baseline's length). Ratio: YOWO's KU-aligned eps_pos / bound, "
              "averaged over cameras (target <= 1.5). Caveat: the bound treats every grid sample as an independent "
              "measurement, while the estimator also exploits the walk's temporal smoothness (Savitzky-Golay "
              "smoothing of each track), so ratios below 1 are possible; a bound with the motion prior is to do.", "",
              "| scenario | mean bound [m] | mean ratio |", "|---|---|---|"]
    for scenario, cases in by_scenario.items():
        lines.append(f"| {scenario} | {_mean(c['bound']['mean_bound_m'] for c in cases):.4f} | "
                     f"{_mean(c['bound']['mean_ratio'] for c in cases):.2f} |")
    return "\n".join(lines) + "\n"


def write_outputs(results: dict, out_dir: Path, markdown_path: Path | None) -> None:
    env = environment()
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[0].endswith("yowo") \
        else " ".join(shlex.quote(a) for a in sys.argv)
    results = {**results, "environment": env, "command": command}
    (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    text = markdown(results, command, env)
    (out_dir / "BENCHMARKS.md").write_text(text)
    if markdown_path is not None:
        markdown_path.write_text(text)
