"""What yowo_eval adds to the `yowo` command line and to a run (entry points in its
setup.py; yowo_bringup.plugins finds them): the `eval` and `bench` verbs, and the
metrics of a run whose recording has ground truth."""

from __future__ import annotations

import json
from pathlib import Path


def __getattr__(name: str):
    """print_tables and write_metrics from .eval, imported when first used: every `yowo`
    command loads this module to add its verbs, and .eval pulls in the whole pipeline
    (Open3D: 1 s of the 1.5 s `yowo --version` took)."""
    if name in ("print_tables", "write_metrics"):
        from . import results_eval as evaluation

        return getattr(evaluation, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def evaluate_run(out_dir, bag) -> tuple[dict, dict] | None:
    """(metrics, ground-truth camera poses) of a results directory, or None when the
    recording has no ground truth for it."""
    from .ground_truth import read_ground_truth
    from .results_eval import evaluate

    try:
        gt = read_ground_truth(bag)  # read once: a second reading of a recording costs ~1 s
        return evaluate(out_dir, bag, gt), gt.cameras
    except ValueError:
        return None


def cmd_eval(args) -> int:
    """Metrics of a results directory against the recording's ground truth."""
    from rich.console import Console

    from .results_eval import evaluate, print_tables, write_metrics

    metrics = evaluate(args.results, args.bag)
    print_tables(metrics, Console())
    if args.metrics:
        write_metrics(metrics, Path(args.metrics))
        print(f"metrics: {args.metrics}")
    if args.gt_tum:
        from yowo_common.trajectory import write_tum

        from .ground_truth import read_ground_truth

        gt = read_ground_truth(args.bag)  # in the map frame already (evaluation compares there)
        if gt.ego is None:
            raise ValueError(f"{args.bag}: no ground-truth ego trajectory (/gt/ego/pose) to write")
        write_tum(Path(args.gt_tum), gt.ego)
        print(f"ground-truth ego trajectory in the map frame (for evo): {args.gt_tum}")
    return 0


def cmd_bench(args) -> int:
    """YOWO and the baselines on generated recordings -> BENCHMARKS.md + results.json."""
    from yowo_bringup.cli import config_from_args

    from .bench import SCENARIOS, run_bench
    from .bench_report import write_outputs

    unknown = [s for s in args.scenarios if s not in SCENARIOS]
    if unknown:
        raise ValueError(f"unknown scenario(s) {', '.join(unknown)} (choose from {', '.join(SCENARIOS)})")
    out = Path(args.output)
    markdown = Path(args.markdown) if args.markdown else None
    if args.from_results:
        write_outputs(json.loads((out / "results.json").read_text()), out, markdown)
        print(f"re-rendered {out / 'BENCHMARKS.md'} from {out / 'results.json'}")
        return 0
    results = run_bench(
        args.preset,
        args.seeds,
        args.scenarios,
        out,
        full=not args.cmc_only,
        sweep_preset=args.sweep_preset,
        resume=args.resume,
        on_case=lambda partial: write_outputs(partial, out, markdown),  # tables so far
        config=config_from_args(args),
    )
    write_outputs(results, out, markdown)
    print(f"wrote {out / 'BENCHMARKS.md'} and {out / 'results.json'}" + (f" and {markdown}" if markdown else ""))
    return 0


def _config_arguments(args) -> list[str]:
    """The configuration options given to a bench verb, as `yowo run` arguments."""
    return [a for s in (args.set or []) for a in ("--set", s)] + (["--config", args.config] if args.config else [])


def cmd_bench_graph(args) -> int:
    """`yowo run --rate 0` on generated recordings: the real graph's speed per stage."""
    from .graph_bench import run_graph_bench

    extra = _config_arguments(args)
    cases = run_graph_bench(
        args.preset, args.seeds, args.sources, Path(args.output), Path(args.markdown) if args.markdown else None, extra
    )
    return 0 if all(c["exit"] == 0 for c in cases) else 1


def cmd_bench_layouts(args) -> int:
    """One generated recording in every input layout through a plain `yowo run`."""
    from .layout_bench import run_layout_bench

    cases = run_layout_bench(
        args.preset,
        args.seed,
        args.cmc_source,
        Path(args.output),
        Path(args.markdown) if args.markdown else None,
        _config_arguments(args),
        args.no_camera_info,
    )
    return 0 if all(c["exit"] == 0 for c in cases) else 1


def cmd_bench_bystanders(args) -> int:
    """One generated walk with 0 / 1 / 3 bystanders through `yowo run --cmc-source pose`."""
    from .bystander_bench import run_bystander_bench

    cases = run_bystander_bench(
        args.preset,
        args.seeds,
        args.bystanders,
        Path(args.output),
        Path(args.markdown) if args.markdown else None,
        _config_arguments(args),
    )
    return 0 if all(c["exit"] == 0 for c in cases) else 1


def cmd_bench_guidance(args) -> int:
    """Walks deficient on purpose and sufficient ones through `yowo run`: the guidance scored."""
    import datetime

    from .guidance_bench import check_kinds, run_guidance_bench

    check_kinds(args.kinds)
    stop_at = None
    if args.until:
        hour, minute = (int(v) for v in args.until.split(":"))
        now = datetime.datetime.now()
        stop_at = now.replace(hour=hour, minute=minute, second=0, microsecond=0).timestamp()
    cases = run_guidance_bench(
        args.preset,
        args.seeds,
        args.kinds,
        Path(args.output),
        Path(args.markdown) if args.markdown else None,
        _config_arguments(args),
        stop_at,
        args.rescore,
        args.resume,
    )
    print(f"wrote {Path(args.output) / 'results.json'} and {Path(args.output) / 'GUIDANCE.md'}")
    return 0 if all(c.get("exit", 0) == 0 for c in cases) else 1


def cmd_bench_second_walk(args) -> int:
    """The suggested second walk followed and run with the first: the named cameras scored."""
    from .guidance_bench import check_kinds
    from .second_walk_bench import run_second_walk_bench

    check_kinds(args.kinds)
    markdown = Path(args.markdown) if args.markdown else None
    cases = run_second_walk_bench(
        args.preset, args.seeds, args.kinds, Path(args.output), markdown, _config_arguments(args)
    )
    print(f"wrote {Path(args.output) / 'SECOND_WALK.md'}")
    return 0 if all(c.get("exit", 0) == 0 for c in cases) else 1


def cmd_bench_tum(args) -> int:
    """TUM RGB-D sequences through the real graph with no CMCs: ATE beside published numbers."""
    from .tum_bench import run_tum_bench

    missing = [f for f in args.sequences if not Path(f).is_dir()]
    if missing:
        raise ValueError(f"no such sequence folder: {', '.join(missing)}")
    extra = _config_arguments(args)
    cases = run_tum_bench(
        [Path(f) for f in args.sequences], Path(args.output), Path(args.markdown) if args.markdown else None, extra
    )
    return 0 if all(c["exit"] == 0 for c in cases) else 1


def _walk_bench_arguments(p, kinds: list[str], kinds_help: str, output_help: str) -> None:
    """The options bench-guidance and bench-second-walk share: which generated walks, where."""
    p.add_argument("--preset", default="small")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--kinds", nargs="+", default=kinds, help=kinds_help)
    p.add_argument("-o", "--output", default="bench/guidance", help=output_help)
    p.add_argument("--markdown", help="put the section into this file (e.g. BENCHMARKS.md), replacing an earlier one")


def add_verbs(verbs) -> None:
    from yowo_bringup.cli import add_config_options

    from .multiview_bench import add_verb as add_multiview_bench_verb
    from .multiview_import import add_verbs as add_multiview_verbs
    from .tum_import import add_verbs as add_import_verbs

    p = verbs.add_parser("bench", help="YOWO and baselines on generated recordings -> BENCHMARKS.md")
    p.add_argument(
        "--preset",
        nargs="+",
        default=["small"],
        help="one or more of tiny, small, standard, large, floor50 (several: the scale table; "
        "large and floor50 run the first seed only, keypoints only)",
    )
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument(
        "--scenarios",
        nargs="+",
        default=["normal"],
        help="normal, texture_poor, symmetric, "
        "dim_light, stationary, kp_noise_{0.5,1.0,2.0,5.0}px, kp_outliers_5pct, clock_offsets",
    )
    p.add_argument("-o", "--output", default="bench", help="directory for bags, results.json, BENCHMARKS.md")
    p.add_argument("--markdown", help="also write the tables here (e.g. BENCHMARKS.md at the repo root)")
    p.add_argument("--cmc-only", action="store_true", help="only the CMC relative calibration tables (fast)")
    p.add_argument(
        "--sweep-preset", help="run the scenarios other than 'normal' (and kp_outliers_5pct) on this preset only"
    )
    p.add_argument("--resume", action="store_true", help="reuse the cases already finished in OUTPUT/cases.jsonl")
    add_config_options(p)
    p.add_argument(
        "--from-results",
        action="store_true",
        help="run nothing: render the tables again from OUTPUT/results.json (e.g. after a report change)",
    )
    p.set_defaults(func=cmd_bench)

    p = verbs.add_parser(
        "bench-layouts",
        help="one generated recording in YOWO's, the RGB-D drivers' and a video "
        "layout through a plain yowo run -> BENCHMARKS.md",
    )
    p.add_argument("--preset", default="small")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--cmc-source",
        default="pose",
        choices=("pose", "images"),
        help="CMC keypoints for every layout (video files carry none): the pose model or the detector",
    )
    p.add_argument("-o", "--output", default="bench/layouts", help="directory for the recordings and runs")
    p.add_argument(
        "--no-camera-info",
        nargs="+",
        default=[],
        metavar="CAM",
        help="also the realsense layout with this camera's CameraInfo left out, one run per camera: its "
        "estimated intrinsics against the truth",
    )
    p.add_argument("--markdown", help="put the table into this file (e.g. BENCHMARKS.md), replacing an earlier one")
    add_config_options(p)
    p.set_defaults(func=cmd_bench_layouts)

    p = verbs.add_parser(
        "bench-bystanders",
        help="one generated walk with other people in view (0, 1, 3) through yowo run --cmc-source pose: "
        "registration and walker identification per camera -> BENCHMARKS.md",
    )
    p.add_argument("--preset", default="standard")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--bystanders", type=int, nargs="+", default=[0, 1, 3], choices=(0, 1, 3))
    p.add_argument("-o", "--output", default="bench/bystanders", help="directory for the recordings and runs")
    p.add_argument("--markdown", help="put the table into this file (e.g. BENCHMARKS.md), replacing an earlier one")
    add_config_options(p)
    p.set_defaults(func=cmd_bench_bystanders)

    p = verbs.add_parser(
        "bench-guidance",
        help="generated walks deficient on purpose (a camera seeing the walker in one corner, one pass through a "
        "doorway) and sufficient ones through yowo run: the walk guidance's precision and recall -> markdown",
    )
    _walk_bench_arguments(
        p,
        ["sufficient", "corner", "doorway"],
        "walks per seed: sufficient (the seed's usual walk), corner (a camera drawn from the seed sees the "
        "walker only in one corner of its image), doorway (one pass between two rooms), covering (the reference: "
        "every camera's image ninths the walk can reach are passed)",
        "directory for the recordings and runs",
    )
    p.add_argument("--until", metavar="HH:MM", help="start no new case after this local time")
    p.add_argument(
        "--rescore", action="store_true", help="run nothing: score the cases already in OUTPUT again (after a change)"
    )
    p.add_argument(
        "--resume", action="store_true", help="reuse the cases already run in OUTPUT (their recording and run there)"
    )
    add_config_options(p)
    p.set_defaults(func=cmd_bench_guidance)

    p = verbs.add_parser(
        "bench-second-walk",
        help="the suggested second walk followed (simulated) and run together with the first: do the cameras the "
        "guidance named reach ok within 2 cm? -> markdown",
    )
    _walk_bench_arguments(
        p,
        ["corner"],
        "first walks per seed (as bench-guidance's)",
        "directory for the recordings and runs (bench-guidance's: its recordings and first runs are reused)",
    )
    add_config_options(p)
    p.set_defaults(func=cmd_bench_second_walk)

    p = verbs.add_parser("bench-graph", help="the real graph's speed (yowo run --rate 0) per stage -> BENCHMARKS.md")
    p.add_argument("--preset", nargs="+", default=["small"])
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument(
        "--sources",
        nargs="+",
        default=["keypoints", "images"],
        choices=("keypoints", "pose", "images"),
        help="CMC keypoint sources to time",
    )
    p.add_argument("-o", "--output", default="bench", help="directory for bags (shared with yowo bench) and runs")
    p.add_argument("--markdown", help="put the table into this file (e.g. BENCHMARKS.md), replacing an earlier one")
    add_config_options(p)
    p.set_defaults(func=cmd_bench_graph)

    p = verbs.add_parser(
        "bench-tum",
        help="real TUM RGB-D sequences through the graph with no CMCs: ATE beside published numbers -> BENCHMARKS.md",
    )
    p.add_argument(
        "sequences",
        nargs="+",
        help="TUM RGB-D sequence folders (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt), named as TUM names them",
    )
    p.add_argument("-o", "--output", default="bench/tum", help="directory for the imported recordings and runs")
    p.add_argument("--markdown", help="put the table into this file (e.g. BENCHMARKS.md), replacing an earlier one")
    add_config_options(p)
    p.set_defaults(func=cmd_bench_tum)

    p = verbs.add_parser("eval", help="metric tables of a results directory against a bag's ground truth")
    p.add_argument("results", help="results directory of yowo run / calibrate-cmc")
    p.add_argument("--bag", required=True, help="the recording, with /gt topics")
    p.add_argument("--metrics", metavar="JSON", help="also write the metrics to this file (e.g. RESULTS/metrics.json)")
    p.add_argument(
        "--gt-tum",
        metavar="TUM",
        help="write the recording's ground-truth ego trajectory in YOWO's map "
        "frame (origin and heading of the first ego pose, z up, floor at "
        "z = 0), for evo_ape against ego_trajectory.tum",
    )
    p.set_defaults(func=cmd_eval)

    add_import_verbs(verbs)  # import-tum: it writes ground truth, which only evaluation reads
    add_multiview_verbs(verbs)  # import-multiview: likewise (the reference calibration)
    add_multiview_bench_verb(verbs)  # bench-multiview: real recordings with a reference calibration
