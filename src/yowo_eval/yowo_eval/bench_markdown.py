"""BENCHMARKS.md's text from `yowo bench`'s cases: the paper's tables (relative_pose_eval,
register_pose_eval_1/2, scene_map, ablation) plus the clock offsets, the image detector, the
verdicts, speed/scale and the Cramer-Rao bound, with the command, versions and machine.
One function per section, in the document's order; kept in one module, above the usual size,
so the generated document reads top to bottom here."""

from __future__ import annotations

import numpy as np

from yowo_fusion.records import FAILED, OK, WEAK

# The synchronised case of a recording with CMC clock offsets (yowo_eval.bench.truth_clocked).
TRUE_CLOCKS = "YOWO, clocks from the truth"


def _finite(values) -> list[float]:
    return [v for v in values if v is not None and np.isfinite(v)]


def _errors_and_bounds(cases: list[dict], k: int, what: str) -> list[tuple[float, float]]:
    """(YOWO's error, bound record `what`) of every camera with a bound; k: 0 position, 1 rotation."""
    return [(c["relative"]["YOWO"]["errors"][n][k], b) for c in cases for n, b in c["bound"][what].items()]


def _mean(values) -> float:
    values = _finite(values)
    return float(np.mean(values)) if values else float("nan")


def _ablation_rows(preset: str, scenario: str, fs: list[dict]) -> list[list[str]]:
    def cols(method: str | None, ate: str, iou: str) -> list[float]:
        reg = [f["registration"][method] for f in fs] if method else []
        return [
            _mean(r["pos_avg"] for r in reg),
            _mean(r["rot_avg"] for r in reg),
            _mean(f["ate"].get(ate) for f in fs),
            _mean(f.get(iou) for f in fs),
        ]

    ego = cols(None, "bundle", "layout_iou")
    no_jo = cols("YOWO without joint optimisation", "bundle", "layout_iou")
    jo = cols("YOWO", "joint", "layout_iou_joint")
    fmt = (".4f", ".3f", ".4f", ".3f")

    def text(values, base=None) -> list[str]:
        out = []
        for v, f, b in zip(values, fmt, base or [None] * 4):
            cell = "-" if not np.isfinite(v) else f"{v:{f}}"
            if b is not None and np.isfinite(v) and np.isfinite(b):
                cell += f" ({v - b:+{f}})"
            out.append(cell)
        return out

    return [
        [preset, scenario, "(i)"] + text(ego),
        [preset, scenario, "(i)(ii)(iii) w/o JO"] + text(no_jo),
        [preset, scenario, "(i)(ii)(iii) w/ JO"] + text(jo, no_jo),
    ]


def _count(values) -> list[tuple[str, int]]:
    counts: dict[str, int] = {}
    for v in values:
        counts[v] = counts.get(v, 0) + 1
    return sorted(counts.items())


def _median(values) -> float:
    values = _finite(values)
    return float(np.median(values)) if values else float("nan")


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + ["| " + " | ".join(r) + " |" for r in rows]


def _abs_errors(values) -> list[str]:
    """Count, median and max |error|, the share within 2 ms (issue #17's bound)."""
    err = np.abs(list(values))
    return (
        [str(len(err)), f"{np.median(err):.1f}", f"{err.max():.1f}", f"{np.mean(err <= 2.0):.2f}"]
        if len(err)
        else ["0", "n/a", "n/a", "n/a"]
    )


def _paired_ratio(pairs) -> str:
    """mean(a) / mean(b) over the (a, b) pairs where both exist (seeds with both cases)."""
    pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
    return f"{_mean(a for a, _ in pairs) / _mean(b for _, b in pairs):.2f}" if pairs else "n/a"


def _by_setting(cases: list[dict]) -> dict[tuple[str, str], list[dict]]:
    out: dict[tuple[str, str], list[dict]] = {}
    for c in cases:
        out.setdefault((c["preset"], c["scenario"]), []).append(c)
    return out


ERROR_COLUMNS = [
    "avg eps_pos [m]",
    "min eps_pos [m]",
    "max eps_pos [m]",
    "avg eps_rot [deg]",
    "min eps_rot [deg]",
    "max eps_rot [deg]",
]


def _error_row(summaries: list[dict], count_key: str) -> list[str]:
    """avg/min/max eps_pos and eps_rot (mean over seeds) and the count summed over seeds."""
    return (
        [f"{_mean(s[f'pos_{k}'] for s in summaries):.4f}" for k in ("avg", "min", "max")]
        + [f"{_mean(s[f'rot_{k}'] for s in summaries):.3f}" for k in ("avg", "min", "max")]
        + [f"{sum(s[count_key] for s in summaries)} / {sum(s['cameras'] for s in summaries)}"]
    )


# An `ok` camera further off than this misled its user (issue #18's registration bar).
OK_BAR_M = 0.10


def _verdict_row(preset: str, scenario: str, fulls: list[dict]) -> list[str]:
    """ok / weak / failed counts and the errors of each verdict's cameras; [] for cases
    recorded before the statuses were."""
    yowo = [f["registration"]["YOWO"] for f in fulls if "statuses" in f["registration"].get("YOWO", {})]
    if not yowo:
        return []
    statuses = [(status, y["errors"].get(name, [np.nan])[0]) for y in yowo for name, status in y["statuses"].items()]
    ok = [e for st, e in statuses if st == OK and np.isfinite(e)]
    weak = [e for st, e in statuses if st == WEAK and np.isfinite(e)]
    counts = " / ".join(str(sum(st == k for st, _ in statuses)) for k in (OK, WEAK, FAILED))
    return [
        preset,
        scenario,
        counts,
        f"{_mean(ok):.4f}" if ok else "-",
        f"{max(ok):.4f}" if ok else "-",
        str(sum(e > OK_BAR_M for e in ok)),
        f"{_mean(weak):.4f}" if weak else "-",
    ]


def _methods(cases: list[dict], key) -> list[str]:
    seen: list[str] = []
    for c in cases:
        seen += [m for m in key(c) if m not in seen]
    return seen


def produced_by(command: str) -> list[str]:
    """The lines of a generated section that name the command that produced it."""
    return ["Produced by:", "", "```", command, "```", ""]


def markdown(results: dict, command: str, env: dict) -> str:
    """The document: one section after the other, each [] where the cases have nothing for it."""
    settings = _by_setting(results["cases"])
    full = {k: [c["full"] for c in cs if "full" in c] for k, cs in settings.items()}
    full = {k: v for k, v in full.items() if v}
    lines = [
        *_header(results, command, env),
        *_relative_pose_section(settings),
        *_clock_section(settings),
        *_detector_section(settings),
        *_registration_section(full),
        *_verdict_section(full),
        *_scene_map_section(full),
        *_ablation_section(full),
        *_speed_section(settings, full),
        *_bound_section(settings),
        *_efficient_estimator_section(settings),
        *_failures_section(results),
    ]
    return "\n".join(lines) + "\n"


def _header(results: dict, command: str, env: dict) -> list[str]:
    """Title, the command, versions and machine, what the averages are over, the code's commits."""
    cases = results["cases"]
    return [
        "# BENCHMARKS",
        "",
        *produced_by(command),
        f"Machine: {env['cpu']} ({env['cores']} cores); Python {env['python']}, numpy {env['numpy']}, "
        f"OpenCV {env.get('opencv-python-headless', env.get('opencv'))}, "
        f"Open3D {env.get('open3d-cpu', env.get('open3d'))}, GTSAM {env['gtsam']}; {env['date']}.",
        "",
        f"Presets {', '.join(results['presets'])}; seeds {results['seeds']}. Errors are averaged over seeds "
        "(each seed's value is the avg or max over cameras); counts are summed over seeds. Baselines marked "
        "-style are labelled reimplementations of the ideas, not the authors' code.",
        "",
        "Code (git commit of the tree each case ran on, with `+changes` for uncommitted edits): "
        + ", ".join(f"{v} ({n} cases)" for v, n in _count(c.get("code", "unknown") for c in cases))
        + ".",
        "",
        *(
            ["**Partial: the run was still going (or stopped) after the cases below.**", ""]
            if results.get("partial")
            else []
        ),
    ]


def _relative_pose_section(settings: dict[tuple[str, str], list[dict]]) -> list[str]:
    """Paper Table relative_pose_eval: every method's KU-aligned errors per setting."""
    rows = []
    for (preset, scenario), cs in settings.items():
        for m in _methods(cs, lambda c: c["relative"]):
            rs = [c["relative"][m] for c in cs if m in c["relative"]]
            rows.append(
                [preset, scenario, m]
                + _error_row(
                    [r["summary"] | {"calibrated": r["calibrated"], "cameras": r["cameras"]} for r in rs], "calibrated"
                )
                + [f"{_mean(r['seconds'] for r in rs):.1f}"]
            )
    return [
        "## CMC relative pose (KU-aligned per group), paper Table relative_pose_eval",
        "",
    ] + _table(["preset", "scenario", "method", *ERROR_COLUMNS, "calibrated / cameras", "time [s]"], rows)


def _clock_section(settings: dict[tuple[str, str], list[dict]]) -> list[str]:
    """The CMC clock offsets' errors and the ratios to the synchronised case (settings with clock offsets)."""
    clocks = {
        k: cs for k, cs in settings.items() if any("clock_errors_ms" in c["relative"].get("YOWO", {}) for c in cs)
    }
    if not clocks:
        return []
    lines = [
        "",
        "## CMC clock offsets (YOWO, estimated from the agent's motion and applied)",
        "",
        "Each calibrated camera's offset to its group's reference camera, and each registered camera's "
        "offset to the ego clock, against the simulator's truth. The synchronised case is the same "
        f"recording with every CMC stamp moved onto the ego clock by the truth and clock estimation off "
        f"(`{TRUE_CLOCKS}`: same frames, same noise); the ratios are YOWO's avg eps_pos over it.",
        "",
    ]
    rows = []
    for (p, s), cs in clocks.items():
        yowo = [c["relative"].get("YOWO", {}) for c in cs]
        synced = [c["relative"].get(TRUE_CLOCKS, {}) for c in cs]
        full = [c["full"] for c in cs if "full" in c]
        rows.append(
            [
                p,
                s,
                *_abs_errors(e for y in yowo for e in y.get("clock_errors_ms", {}).values()),
                *_abs_errors(e for f in full for e in f.get("clock_errors_to_ego_ms", {}).values()),
                _paired_ratio(
                    (y.get("summary", {}).get("pos_avg"), t.get("summary", {}).get("pos_avg"))
                    for y, t in zip(yowo, synced)
                ),
                _paired_ratio(
                    (
                        f["registration"].get("YOWO", {}).get("pos_avg"),
                        f["registration"].get(TRUE_CLOCKS, {}).get("pos_avg"),
                    )
                    for f in full
                ),
            ]
        )
    return lines + _table(
        [
            "preset",
            "scenario",
            "members",
            "median \\|error\\| to reference [ms]",
            "max [ms]",
            "within 2 ms",
            "registered",
            "median \\|error\\| to ego [ms]",
            "max [ms]",
            "within 2 ms",
            "relative eps_pos / synchronised",
            "registration eps_pos / synchronised",
        ],
        rows,
    )


def _detector_section(settings: dict[tuple[str, str], list[dict]]) -> list[str]:
    """The image detector against the simulator's keypoints (cases that ran it)."""
    detected = [(k, [c["detector"] for c in cs if "detector" in c]) for k, cs in settings.items()]
    if not any(ds for _, ds in detected):
        return []
    lines = [
        "",
        "## Image detector (model-free, on the rendered CMC images) vs simulator ground truth",
        "",
        "Full view: every body keypoint in the image and not hidden by the static scene. Detected: head "
        "top and ground point both reported.",
        "",
    ]
    rows = [
        [
            p,
            s,
            str(sum(d["frames_full_view"] for d in ds)),
            f"{sum(d['detected'] for d in ds) / max(sum(d['frames_full_view'] for d in ds), 1):.3f}",
            f"{_mean(d['median_px'] for d in ds):.2f}",
        ]
        + [
            f"{_mean(d[q][k] for d in ds):.2f}"
            for k in ("head_top", "ground")
            for q in ("median_px_by_id", "p90_px_by_id")
        ]
        + [f"{sum(d['frames'] for d in ds) / sum(d['seconds'] for d in ds):.0f}"]
        for (p, s), ds in detected
        if ds
    ]
    return lines + _table(
        [
            "preset",
            "scenario",
            "frames in full view",
            "detection rate",
            "median error [px]",
            "head top median [px]",
            "head top p90 [px]",
            "ground median [px]",
            "ground p90 [px]",
            "frames / s",
        ],
        rows,
    )


def _registration_section(full: dict[tuple[str, str], list[dict]]) -> list[str]:
    """Paper Tables register_pose_eval_1/2: every method's errors in the map frame (full cases)."""
    if not full:
        return []
    lines = [
        "",
        "## CMC registration in the map frame (no alignment), paper Tables register_pose_eval_1/2 and ablation",
        "",
        "The map frame is YOWO's (defined by the first ego pose); ground truth is "
        "expressed in it. Hloc-style: VLAD-over-RootSIFT retrieval of ego keyframes, SIFT matches lifted "
        "with depth, PnP + RANSAC, on each CMC's background image; with prior: keyframes that see the "
        "prior camera's view, matches gated near the prior's projection.",
        "",
    ]
    rows = []
    for (preset, scenario), fs in full.items():
        for m in _methods(fs, lambda f: f["registration"]):
            rs = [f["registration"][m] for f in fs if m in f["registration"]]
            rows.append([preset, scenario, m] + _error_row(rs, "registered"))
    return lines + _table(["preset", "scenario", "method", *ERROR_COLUMNS, "registered / cameras"], rows)


def _verdict_section(full: dict[tuple[str, str], list[dict]]) -> list[str]:
    """YOWO's status of each registered camera beside its error (cases recorded with the statuses)."""
    verdicts = [_verdict_row(p, s, fs) for (p, s), fs in full.items()]
    if not any(verdicts):
        return []
    return [
        "",
        "## Verdicts: each camera's own status against its error",
        "",
        "What YOWO says of each camera it registered (`ok`, `weak`: the registration rests on "
        "something it could not check; `failed`), beside the camera's error in the map frame. An "
        f"`ok` camera more than {OK_BAR_M} m off is a verdict that misled; counts summed over seeds.",
        "",
    ] + _table(
        [
            "preset",
            "scenario",
            "ok / weak / failed",
            "ok: avg eps_pos [m]",
            "ok: max eps_pos [m]",
            f"ok beyond {OK_BAR_M} m",
            "weak: avg eps_pos [m]",
        ],
        [v for v in verdicts if v],
    )


def _scene_map_section(full: dict[tuple[str, str], list[dict]]) -> list[str]:
    """Paper Table scene_map: the ego ATE after each stage and the layout IoU (full cases)."""
    if not full:
        return []
    stages = _methods([f for fs in full.values() for f in fs], lambda f: f["ate"])
    return [
        "",
        "## Scene mapping, paper Table scene_map",
        "",
        "ATE after each stage: ego-only odometry, + multiway registration, + bundle adjustment (the "
        "ego-only baselines of the table), and after YOWO's joint optimisation.",
        "",
    ] + _table(
        ["preset", "scenario"] + [f"ego ATE RMSE: {s} [m]" for s in stages] + ["layout IoU"],
        [
            [p, s]
            + [f"{_mean(f['ate'].get(st) for f in fs):.4f}" for st in stages]
            + [f"{_mean(f['layout_iou'] for f in fs):.3f}"]
            for (p, s), fs in full.items()
        ],
    )


def _ablation_section(full: dict[tuple[str, str], list[dict]]) -> list[str]:
    """Paper Table ablation: the ego stage alone, then with the CMCs without and with the joint optimisation."""
    if not full:
        return []
    return [
        "",
        "## Ablation, paper Table ablation",
        "",
        "(i) ego-camera processing, (ii) CMC processing, (iii) collaborative processing; JO: the joint "
        "optimisation (eq. factor_graph_all). Without JO the ego map is the ego stage's (after its bundle "
        "adjustment); with JO the trajectory and the layout come from the refined map. In brackets: the "
        "change that JO makes.",
        "",
    ] + _table(
        ["preset", "scenario", "setting", "avg eps_pos [m]", "avg eps_rot [deg]", "ego ATE RMSE [m]", "layout IoU"],
        [row for (p, s), fs in full.items() for row in _ablation_rows(p, s, fs)],
    )


def _speed_section(settings: dict[tuple[str, str], list[dict]], full: dict[tuple[str, str], list[dict]]) -> list[str]:
    """Each stage's time, the processing / recording time and the peak memory (full cases)."""
    if not full:
        return []
    rows = []
    for (preset, scenario), cs in settings.items():
        fs = [c["full"] for c in cs if "full" in c]
        if fs:
            rows.append(
                [preset, scenario, str(fs[0]["cmcs"]), f"{_mean(f['recording_s'] for f in fs):.0f}"]
                + [f"{_mean(f['seconds'][k] for f in fs):.1f}" for k in ("ego", "cmc", "fusion")]
                + [f"{_mean(f['realtime_factor'] for f in fs):.2f}", f"{max(c['peak_memory_mb'] for c in cs):.0f}"]
            )
    return ["", "## Speed and scale (2 cores, offline API, one process per case)", ""] + _table(
        [
            "preset",
            "scenario",
            "CMCs",
            "recording [s]",
            "ego [s]",
            "CMC [s]",
            "fusion [s]",
            "processing / recording time",
            "peak memory [MB]",
        ],
        rows,
    )


def _bound_section(settings: dict[tuple[str, str], list[dict]]) -> list[str]:
    """The Cramer-Rao bound of each CMC's pose in its group and YOWO's error over it (medians)."""
    lines = [
        "",
        "## Achieved error / Cramer-Rao bound (CMC pose in its group)",
        "",
        "Bound: the group bundle adjustment's information at ground truth with the simulated detector noise "
        "(scene points eliminated by Schur complement; gauge: first camera fixed, first baseline's length), "
        "pushed through the evaluation's KU alignment by Monte Carlo. Ratio: YOWO's KU-aligned error / bound "
        "per camera. Medians over the cameras of all seeds: a group with little parallax has a bound of "
        "metres and degrees, which would swamp a mean. Caveat: the bound treats every grid sample as an "
        "independent measurement, while the estimator also exploits the walk's temporal smoothness "
        "(Savitzky-Golay smoothing of each track), so ratios below 1 are possible.",
        "",
    ]
    rows = []
    for (p, s), cs in settings.items():
        row = [
            p,
            s,
            f"{sum(c['bound']['cameras'] for c in cs)} / {sum(c['relative']['YOWO']['calibrated'] for c in cs)}",
        ]
        for k, what, unit in ((0, "position_m", ".4f"), (1, "rotation_deg", ".3f")):
            bounds = _errors_and_bounds(cs, k, what)
            row += [f"{_median(b for _, b in bounds):{unit}}", f"{_median(e / b for e, b in bounds if b > 0):.2f}"]
        rows.append(row)
    return lines + _table(
        [
            "preset",
            "scenario",
            "cameras with a bound / calibrated",
            "median bound eps_pos [m]",
            "median ratio eps_pos",
            "median bound eps_rot [deg]",
            "median ratio eps_rot",
        ],
        rows,
    )


def _efficient_estimator_section(settings: dict[tuple[str, str], list[dict]]) -> list[str]:
    """The bound section's second table: an efficient estimator's mean error beside YOWO's."""
    lines = [
        "",
        "Averages as in Table relative_pose_eval, over the cameras with a bound (all seeds): the mean "
        "error an efficient estimator would reach (the same Monte Carlo) beside YOWO's.",
        "",
    ]
    rows = []
    for (p, s), cs in settings.items():
        row = [p, s]
        for k, what, unit in ((0, "mean_position_m", ".4f"), (1, "mean_rotation_deg", ".3f")):
            pairs = _errors_and_bounds(cs, k, what)
            row += [f"{_mean(b for _, b in pairs):{unit}}", f"{_mean(e for e, _ in pairs):{unit}}"]
        rows.append(row)
    return lines + _table(
        [
            "preset",
            "scenario",
            "efficient avg eps_pos [m]",
            "YOWO avg eps_pos [m]",
            "efficient avg eps_rot [deg]",
            "YOWO avg eps_rot [deg]",
        ],
        rows,
    )


def _failures_section(results: dict) -> list[str]:
    """The cases that raised, with their errors."""
    if not results.get("failures"):
        return []
    return ["", "## Cases that failed", ""] + [
        f"- {f['preset']} {f['scenario']} seed {f['seed']}: {f['error']}" for f in results["failures"]
    ]
