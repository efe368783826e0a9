"""`yowo bench-guidance` (issue #48): generated walks deficient on purpose (a camera that sees the
walker only in one corner of its image; two rooms joined by one pass through a doorway) and
sufficient ones (the seed's usual walk), each through a plain `yowo run --rate 0`; the walk
guidance scored against what was made deficient (/gt/deficient, evaluation only):

- per camera, deficient by construction against the final /yowo/guidance verdict ("needs more"):
  precision and recall over every camera of every recording;
- per doorway walk, whether weak_places.yaml names a place near the doorway (its true middle,
  in YOWO's map frame): the hit rate."""

from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from .bench_markdown import produced_by
from .bench_report import markers
from .graph_bench import graph_case, write_cases

SECTION = "guidance"
BEGIN, END = markers(SECTION)
KINDS = ("sufficient", "corner", "doorway", "covering")
DOORWAY_RADIUS_M = 1.5  # a weak place this near the doorway's true middle names it
NEEDS_MORE = "needs more"


def check_kinds(kinds: list[str]) -> None:
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        raise ValueError(f"unknown walk(s) {', '.join(unknown)} (choose from {', '.join(KINDS)})")


# ------------------------------------------------------------------------ scoring (pure)


def deficient_cameras(truth: list[dict]) -> set[str]:
    """The cameras deficient by construction: the corner walks' camera (a doorway walk makes no
    camera deficient by itself: its measure is the weak place)."""
    return {t["camera"] for t in truth if t.get("kind") == "corner"}


def precision_recall(pairs: list[tuple[bool, bool]]) -> dict:
    """(deficient by construction, guidance says "needs more") per camera -> counts, precision
    and recall of "needs more" (None where undefined: nothing said, or nothing deficient)."""
    tp = sum(d and s for d, s in pairs)
    fp = sum(s and not d for d, s in pairs)
    fn = sum(d and not s for d, s in pairs)
    tn = sum(not d and not s for d, s in pairs)
    return {
        "cameras": len(pairs),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
        "precision": tp / (tp + fp) if tp + fp else None,
        "recall": tp / (tp + fn) if tp + fn else None,
    }


def doorway_hit(places: list[dict], door_xy, radius_m: float = DOORWAY_RADIUS_M) -> dict:
    """Whether a weak place (x_m, y_m in the map frame) lies within radius_m of the doorway."""
    if not places:
        return {"hit": False, "nearest_m": None, "kind": None}
    d = [float(np.hypot(p["x_m"] - door_xy[0], p["y_m"] - door_xy[1])) for p in places]
    k = int(np.argmin(d))
    return {"hit": d[k] <= radius_m, "nearest_m": round(d[k], 3), "kind": places[k]["kind"]}


def corner_named(reasons: list[str], corner: str) -> bool:
    """Whether a camera's reasons name its corner ("... top-left corner")."""
    return any(f"{corner} corner" in r for r in reasons)


def hit_rate(cases: list[dict]) -> dict:
    hits = [c["doorway"]["hit"] for c in cases if c.get("doorway")]
    return {"walks": len(hits), "hits": sum(hits), "rate": sum(hits) / len(hits) if hits else None}


# ------------------------------------------------------------------------ reading a run


def read_truth(bag: Path) -> tuple[list[dict], np.ndarray]:
    """/gt/deficient (empty: a sufficient walk) and the simulator's frame -> YOWO's map frame."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.topics import GT_DEFICIENT

    from .ground_truth import read_ground_truth

    truth = []
    for _, _, msg in read_messages(bag, [GT_DEFICIENT]):
        truth = yaml.safe_load(msg.data)["deficient"]
    return truth, read_ground_truth(bag).T_map_sim


def final_guidance(run: Path) -> dict[str, dict]:
    """Per camera, the verdict and reasons of the run's last /yowo/guidance (result.mcap), else of
    cameras.yaml's `coverage:`."""
    from yowo_common.ros.bag import read_messages

    last = None
    if (run / "result.mcap").exists():
        for _, _, msg in read_messages(run / "result.mcap", ["/yowo/guidance"]):
            last = msg
    if last is not None:
        return {
            c.name: {"verdict": c.verdict, "reasons": list(c.reasons), "source": "final /yowo/guidance"}
            for c in last.cameras
        }
    out = {}
    if (run / "cameras.yaml").exists():
        for c in yaml.safe_load((run / "cameras.yaml").read_text()).get("cameras", []):
            cov = c.get("coverage") or {}
            out[c["name"]] = {
                "verdict": cov.get("verdict"),
                "reasons": cov.get("reasons", []),
                "source": "cameras.yaml coverage",
            }
    return out


def read_weak_places(run: Path) -> list[dict]:
    f = run / "weak_places.yaml"
    return (yaml.safe_load(f.read_text()) or {}).get("weak_places") or [] if f.exists() else []


def score_case(case: dict, bag: Path, run: Path) -> dict:
    """The case's scores from its recording's ground truth and its run's results."""
    truth, T_map_sim = read_truth(bag)
    deficient = deficient_cameras(truth)
    guidance = final_guidance(run)
    case["truth"] = truth
    case["cameras"] = {
        name: {**g, "deficient": name in deficient, "needs_more": g["verdict"] == NEEDS_MORE}
        for name, g in guidance.items()
    }
    for name, cov in true_coverage(case["preset"], case["kind"], case["seed"]).items():
        if name in case["cameras"]:
            case["cameras"][name]["true_region_reason"] = cov["region_reason"]
            case["cameras"][name]["true_ninths"] = cov["ninths"]
    for t in truth:
        if t["kind"] == "corner" and t["camera"] in guidance and t.get("region") == "ninth":
            case["corner_named"] = corner_named(guidance[t["camera"]]["reasons"], t["corner"])
        if t["kind"] == "doorway":
            door = (T_map_sim @ [t["door_x_m"], t["door_y_m"], 0.0, 1.0])[:2]
            case["doorway"] = {**doorway_hit(read_weak_places(run), door), "door_map_xy": door.round(3).tolist()}
    return case


def true_coverage(preset: str, kind: str, seed: int, step_s: float = 0.1) -> dict[str, dict]:
    """Per camera, where in its image the walker truly was (the simulator's walk again, its
    keypoints as the simulated detector sees them: in the image, not hidden by the scene): the
    count per ninth and the coverage model's region reason on them ('' every third reached).
    Walks deficient on purpose change what other cameras see too; this tells those apart."""
    from yowo_cmc.coverage import region_reason
    from yowo_cmc.params import CoverageParams
    from yowo_sim.body import agent_keypoints_3d
    from yowo_sim.capture import build_capture
    from yowo_sim.detector import visible_points
    from yowo_sim.render import Renderer

    setup = build_capture(_preset(preset, kind), seed)
    renderer = Renderer(setup.scene)
    times = np.arange(0.0, setup.walk.duration_s, step_s)
    kps = []
    for t in times:
        xy, heading, phase = setup.walk.state_at(t)
        kps += list(agent_keypoints_3d(xy, heading, setup.walk.height_m, phase).values())
    kps = np.array(kps)
    out = {}
    for cmc in setup.cmcs:
        depth = renderer.render(cmc.camera, cmc.T_world_cam).depth
        uv, ok = visible_points(cmc.camera, cmc.T_world_cam, kps, depth, 0.05)
        uv = uv[ok]
        counts = np.zeros((3, 3), int)
        rows = np.clip((uv[:, 1] * 3 // cmc.camera.height).astype(int), 0, 2)
        cols = np.clip((uv[:, 0] * 3 // cmc.camera.width).astype(int), 0, 2)
        np.add.at(counts, (rows, cols), 1)
        reason = region_reason(counts, CoverageParams()) if len(uv) else "agent never seen in the image"
        out[cmc.name] = {"ninths": counts.tolist(), "region_reason": reason}
    return out


# ------------------------------------------------------------------------ the bench


def _preset(preset: str, kind: str):
    from yowo_sim.deficient import parse_deficient
    from yowo_sim.presets import get_preset

    deficient = parse_deficient([kind] if kind != "sufficient" else [])
    return get_preset(preset, cmc_images=False, deficient=deficient)


def guidance_bag(preset: str, kind: str, seed: int, bags_dir: Path, log=print) -> Path:
    """The case's recording (keypoints only, no CMC images: the runs use the recorded keypoints),
    generated once and reused. A corner walk no camera can have raises ValueError."""
    import shutil

    from yowo_sim.capture import generate

    path = bags_dir / f"{preset}_guidance_{kind}_s{seed}"
    if (path / "metadata.yaml").exists():
        return path
    shutil.rmtree(path, ignore_errors=True)  # an interrupted generation
    bags_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    summary = generate(_preset(preset, kind), seed, path)
    log(f"generated {path.name}: {summary.duration_s:.0f} s walk in {time.perf_counter() - t0:.0f} s")
    return path


def guidance_cases(
    preset: str,
    seeds: list[int],
    kinds: list[str],
    out_dir: Path,
    extra: list[str],
    log=print,
    stop_at=None,
    on_case=None,
    previous: dict | None = None,
) -> list[dict]:
    """Every (seed, kind) case, in seed order; `stop_at`: a time.time() after which no case starts;
    `on_case`: called with the cases so far after each; `previous`: cases of an earlier bench by
    (seed, kind), reused where their recording and run are still there."""
    cases = []
    for seed in seeds:
        for kind in kinds:
            if stop_at is not None and time.time() > stop_at:
                log(f"stopping before seed {seed} {kind}: time is up")
                return cases
            case = {"preset": preset, "seed": seed, "kind": kind}
            done = (previous or {}).get((seed, kind))
            if done and done.get("exit") == 0 and (out_dir / "bags" / done["bag"] / "metadata.yaml").exists():
                run = out_dir / "runs" / done["bag"]
                if (run / "cameras.yaml").exists():
                    cases.append(score_case(done, out_dir / "bags" / done["bag"], run))
                    log(f"{done['bag']}: the earlier run, scored again")
                    if on_case:
                        on_case(cases)
                    continue
            try:
                bag = guidance_bag(preset, kind, seed, out_dir / "bags", log)
            except ValueError as e:
                log(f"seed {seed} {kind}: no such walk ({e})")
                cases.append({**case, "skipped": str(e)})
                continue
            run = out_dir / "runs" / bag.name
            case.update(graph_case(bag, run, "keypoints", extra))
            case["preset"], case["seed"], case["kind"] = preset, seed, kind
            if case["exit"] == 0:
                try:
                    score_case(case, bag, run)
                except (OSError, KeyError, ValueError) as e:  # a run without what scoring reads
                    case["score_error"] = f"{type(e).__name__}: {e}"
            log(
                f"{bag.name}: exit {case['exit']}, needs more: "
                f"{[n for n, c in case.get('cameras', {}).items() if c['needs_more']]}, "
                f"deficient: {[n for n, c in case.get('cameras', {}).items() if c['deficient']]}"
                + (f", doorway {case['doorway']}" if case.get("doorway") else "")
            )
            cases.append(case)
            if on_case:
                on_case(cases)
    return cases


def summary(cases: list[dict]) -> dict:
    scored = [c for c in cases if c.get("cameras")]
    pairs = [(x["deficient"], x["needs_more"]) for c in scored for x in c["cameras"].values()]
    named = [c["corner_named"] for c in scored if "corner_named" in c]
    return {
        "recordings": len(scored),
        "all": precision_recall(pairs),
        "by_kind": {
            k: precision_recall(
                [(x["deficient"], x["needs_more"]) for c in scored if c["kind"] == k for x in c["cameras"].values()]
            )
            for k in KINDS
            if any(c["kind"] == k for c in scored)
        },
        # Against where each camera truly saw the walker: thin when its image's thirds are not all reached.
        "against_true_regions": precision_recall(
            [
                (bool(x["true_region_reason"]), x["needs_more"])
                for c in scored
                for x in c["cameras"].values()
                if "true_region_reason" in x
            ]
        ),
        "corner_named": {"walks": len(named), "named": sum(named)},
        "doorway": hit_rate(scored),
    }


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def guidance_markdown(cases: list[dict], command: str) -> str:
    s = summary(cases)
    a, door, named, t = s["all"], s["doorway"], s["corner_named"], s["against_true_regions"]
    lines = [
        BEGIN,
        "## Walk guidance on deficient walks (`yowo bench-guidance`)",
        "",
        *produced_by(command),
        "Generated walks made deficient on purpose (`yowo simulate --deficient`): *corner*, one ceiling camera "
        "sees the walker only in one corner of its image (a ninth, else a quadrant; the walk keeps off the rest "
        "of its view); *doorway*, the walk crosses once between two rooms joined by a doorway; *sufficient*, "
        "the seed's usual walk; and *covering*, the reference: the walk passes every ninth of every camera's image "
        "it can reach. Each through `yowo run --rate 0` with the recorded keypoints. A camera is "
        "deficient by construction when it is a corner walk's camera (/gt/deficient); the guidance names it "
        "when the final /yowo/guidance says `needs more`. Doorway: a place in weak_places.yaml within "
        f"{DOORWAY_RADIUS_M} m of the doorway's true middle.",
        "",
        f"Over {s['recordings']} recordings, {a['cameras']} cameras: precision of `needs more` "
        f"{_pct(a['precision'])} ({a['tp']} of {a['tp'] + a['fp']}), recall {_pct(a['recall'])} "
        f"({a['tp']} of {a['tp'] + a['fn']}); the corner named in the reasons in {named['named']} of "
        f"{named['walks']} corner walks; doorway named by a weak place in {door['hits']} of {door['walks']} "
        f"doorway walks ({_pct(door['rate'])}).",
        "",
        "The deficient walks change what the other cameras see too (a corner walk keeps off much of a room). "
        "Against where each camera truly saw the walker (the simulator's walk again: its keypoints in the image "
        "and not hidden, by ninths; *thin* when the coverage model's region test on them fails): "
        f"precision {_pct(t['precision'])} ({t['tp']} of {t['tp'] + t['fp']}), recall {_pct(t['recall'])} "
        f"({t['tp']} of {t['tp'] + t['fn']}).",
        "",
        "| recording | walk | exit | deficient (truth) | `needs more` (final guidance) | thin in truth | corner named | "
        "doorway: nearest weak place [m] | processing / recording |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        if c.get("skipped"):
            lines.append(
                f"| {c['preset']} seed {c['seed']} | {c['kind']} | - | no such walk: {c['skipped']} | | | | | |"
            )
            continue
        cams = c.get("cameras", {})
        truth = ", ".join(
            f"{t['camera']} ({t['corner']} {t['region']})" for t in c.get("truth", []) if t["kind"] == "corner"
        )
        said = ", ".join(n for n, x in cams.items() if x["needs_more"]) or "none"
        thin = ", ".join(n for n, x in cams.items() if x.get("true_region_reason")) or "none"
        corner = {True: "yes", False: "no"}.get(c.get("corner_named"), "")
        d = c.get("doorway")
        door_cell = "" if not d else f"{d['nearest_m']} ({d['kind']}){' hit' if d['hit'] else ''}"
        lines.append(
            f"| {c['bag']} | {c['kind']} | {c['exit']} | {truth or '-'} | {said} | {thin} | {corner} | {door_cell} "
            f"| {c['ratio']:.2f} |"
        )
    return "\n".join(lines + [END, ""])


def rescore(out_dir: Path, log=print) -> list[dict]:
    """The cases of an earlier bench in out_dir scored again from their recordings and runs."""
    cases = json.loads((out_dir / "guidance_cases.json").read_text())
    for case in cases:
        if case.get("exit") == 0 and not case.get("skipped"):
            bag = out_dir / "bags" / case["bag"]
            score_case(case, bag, out_dir / "runs" / bag.name)
            log(f"scored {case['bag']} again")
    return cases


def run_guidance_bench(
    preset: str,
    seeds: list[int],
    kinds: list[str],
    out_dir: Path,
    markdown_path: Path | None,
    extra: list[str],
    stop_at=None,
    rescore_only: bool = False,
    resume: bool = False,
    log=print,
) -> list[dict]:
    """The bench (or with `rescore_only` the earlier cases in out_dir scored again: no runs)."""
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    out_dir.mkdir(parents=True, exist_ok=True)

    def write(cases: list[dict]) -> None:
        section = guidance_markdown(cases, command)
        write_cases(out_dir, ("guidance_cases.json", "GUIDANCE.md"), cases, section, markdown_path, SECTION)
        results = {"command": command, "summary": summary(cases), "cases": cases}
        (out_dir / "results.json").write_text(json.dumps(results, indent=1))

    if rescore_only:
        cases = rescore(out_dir, log)
        command = json.loads((out_dir / "results.json").read_text())["command"]
    else:
        previous = None
        if resume and (out_dir / "guidance_cases.json").exists():
            earlier = json.loads((out_dir / "guidance_cases.json").read_text())
            previous = {(c["seed"], c["kind"]): c for c in earlier if c.get("preset") == preset}
        cases = guidance_cases(preset, seeds, kinds, out_dir, extra, log, stop_at, write, previous)
    write(cases)
    return cases
