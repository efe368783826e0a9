"""`yowo bench-second-walk` (issue #48): does following the suggested second walk help?

Per generated walk (bench-guidance's recordings: deficient on purpose or the seed's usual
walk): the first walk through `yowo run --rate 0`; a second walk that follows its
second_walk.yaml simulated in the same building, cameras and clocks (`yowo simulate --follow`);
both through one `yowo run FIRST SECOND`. Scored per camera the first run said `needs more`
for (the final /yowo/guidance): its verdict and registration error against the ground truth
before and after, and whether it reached `ok` within SUCCESS_M."""

from __future__ import annotations

import json
import shlex
import shutil
import sys
import time
from pathlib import Path

import yaml

from .bench_markdown import produced_by
from .bench_report import markers
from .graph_bench import graph_case, recording_seconds, write_cases
from .guidance_bench import NEEDS_MORE, _preset, final_guidance, guidance_bag

SECTION = "second-walk"
BEGIN, END = markers(SECTION)
SUCCESS_M = 0.02  # a named camera is brought to ok within this registration error [m]
GAP_S = 60.0  # the silence between the two walks [s]


def registration(run: Path) -> dict[str, dict]:
    """Per camera: its registration error (metrics.json, None when not registered) and status."""
    metrics = json.loads((run / "metrics.json").read_text()) if (run / "metrics.json").exists() else {}
    errors = {c["name"]: c for c in metrics.get("registration", {}).get("cameras", [])}
    cams = yaml.safe_load((run / "cameras.yaml").read_text())["cameras"] if (run / "cameras.yaml").exists() else []
    return {
        c["name"]: {
            "status": c.get("status"),
            "eps_pos_m": errors.get(c["name"], {}).get("eps_pos_m"),
            "eps_rot_deg": errors.get(c["name"], {}).get("eps_rot_deg"),
        }
        for c in cams
    }


def score(first_run: Path, joined_run: Path) -> dict[str, dict]:
    """Per camera the first run named (`needs more`): verdicts, registration before and after."""
    before, after = final_guidance(first_run), final_guidance(joined_run)
    reg0, reg1 = registration(first_run), registration(joined_run)
    out = {}
    for name, g in before.items():
        if g["verdict"] != NEEDS_MORE:
            continue
        a = after.get(name, {})
        err = reg1.get(name, {}).get("eps_pos_m")
        out[name] = {
            "reasons_before": g["reasons"],
            "verdict_after": a.get("verdict"),
            "reasons_after": a.get("reasons", []),
            "status_before": reg0.get(name, {}).get("status"),
            "status_after": reg1.get(name, {}).get("status"),
            "eps_pos_before_m": reg0.get(name, {}).get("eps_pos_m"),
            "eps_pos_after_m": err,
            "ok_after": a.get("verdict") == "ok",
            "within_m": err is not None and err <= SUCCESS_M,
        }
    return out


def second_walk_case(preset: str, kind: str, seed: int, out_dir: Path, extra: list[str], log=print) -> dict:
    from yowo_sim.capture import generate
    from yowo_sim.follow import follow_walk

    case = {"preset": preset, "seed": seed, "kind": kind}
    try:
        first = guidance_bag(preset, kind, seed, out_dir / "bags", log)
    except ValueError as e:
        return {**case, "skipped": f"no such walk ({e})"}
    run1 = out_dir / "runs" / first.name
    if not (run1 / "cameras.yaml").exists():
        case["first"] = graph_case(first, run1, "keypoints", extra)
        if case["first"]["exit"] != 0:
            return {**case, "skipped": f"first run failed: {case['first']['error']}"}
    plan = yaml.safe_load((run1 / "second_walk.yaml").read_text())
    case["waypoints"] = len(plan.get("waypoints") or [])
    case["not_placed"] = plan.get("not_placed") or {}
    if not case["waypoints"]:
        return {**case, "skipped": "the first run suggests no second walk"}
    second = out_dir / "second_walks" / f"{first.name}_second"  # made from this bench's first run
    if not (second / "metadata.yaml").exists():
        shutil.rmtree(second, ignore_errors=True)
        second.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        walk = generate(_preset(preset, kind), seed, second, follow=follow_walk(run1, first, GAP_S))
        log(f"generated {second.name}: {walk.duration_s:.0f} s walk in {time.perf_counter() - t0:.0f} s")
    case["second_walk_s"] = round(recording_seconds(second), 1)
    joined = out_dir / "runs" / f"{first.name}_joined"
    run = graph_case([first, second], joined, "keypoints", extra)
    case.update(exit=run["exit"], error=run["error"], ego_ate_m=run["ego_ate_m"])
    if run["exit"] == 0:
        case["cameras"] = score(run1, joined)
    return case


def summary(cases: list[dict]) -> dict:
    named = [c for case in cases for c in case.get("cameras", {}).values()]
    return {
        "recordings": sum(1 for c in cases if "cameras" in c),
        "named": len(named),
        "ok_after": sum(c["ok_after"] for c in named),
        "within": sum(c["within_m"] for c in named),
        "both": sum(c["ok_after"] and c["within_m"] for c in named),
    }


def _cm(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}"


def second_walk_markdown(cases: list[dict], command: str) -> str:
    s = summary(cases)
    lines = [
        BEGIN,
        "## Following the suggested second walk (`yowo bench-second-walk`)",
        "",
        *produced_by(command),
        "Each first walk (bench-guidance's recordings) through `yowo run --rate 0`; a second walk that follows "
        f"its second_walk.yaml simulated {GAP_S:.0f} s after it (`yowo simulate --follow RUN --after FIRST`); "
        "both through `yowo run FIRST SECOND`. Per camera the first run's final guidance said `needs more` for: "
        f"its verdict after, and its registration error before / after [cm]. Brought to `ok` within "
        f"{100 * SUCCESS_M:.0f} cm: {s['both']} of {s['named']} named cameras over {s['recordings']} recordings "
        f"(`ok` after: {s['ok_after']}; within {100 * SUCCESS_M:.0f} cm after: {s['within']}).",
        "",
        "| recording | waypoints | camera | verdict after | reasons after | status before / after | "
        "error before / after [cm] |",
        "|---|---|---|---|---|---|---|",
    ]
    for case in cases:
        name = f"{case['preset']} {case['kind']} s{case['seed']}"
        if case.get("skipped"):
            lines.append(f"| {name} | {case.get('waypoints', '-')} | {case['skipped']} | | | | |")
            continue
        if case.get("exit"):
            lines.append(f"| {name} | {case['waypoints']} | run failed (exit {case['exit']}) | | | | |")
            continue
        for cam, c in case.get("cameras", {}).items():
            lines.append(
                f"| {name} | {case['waypoints']} | {cam} | {c['verdict_after']} | {'; '.join(c['reasons_after'])} | "
                f"{c['status_before']} / {c['status_after']} | {_cm(c['eps_pos_before_m'])} / "
                f"{_cm(c['eps_pos_after_m'])} |"
            )
    return "\n".join(lines + [END, ""])


def run_second_walk_bench(
    preset: str, seeds: list[int], kinds: list[str], out_dir: Path, markdown_path: Path | None, extra: list[str]
) -> list[dict]:
    command = "yowo " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    out_dir.mkdir(parents=True, exist_ok=True)
    cases = []
    for seed in seeds:
        for kind in kinds:
            cases.append(second_walk_case(preset, kind, seed, out_dir, extra))
            print(f"{preset} {kind} s{seed}: {json.dumps(cases[-1].get('cameras', cases[-1].get('skipped')))[:400]}")
            section = second_walk_markdown(cases, command)
            write_cases(out_dir, ("second_walk_cases.json", "SECOND_WALK.md"), cases, section, markdown_path, SECTION)
    return cases
