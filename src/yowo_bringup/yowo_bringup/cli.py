"""The `yowo` command line. Each verb is a function taking the parsed arguments
and returning the process exit code; heavy imports happen inside the verb."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from yowo_common import topics
from yowo_common.ros.bag import BagError, recording_label

from .plugins import add_verbs, evaluator


def cmd_info(args) -> int:
    """Summarise a recording: topics, types, counts, and the CMCs found."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from .contract import discover_inputs

    console = Console()
    inputs = discover_inputs(args.bag, config_from_args(args).inputs)
    table = Table(title=recording_label(args.bag))
    for col in ("topic", "type", "messages"):
        table.add_column(col)
    for t in inputs.topics:
        table.add_row(t.name, t.msgtype, str(t.count))
    console.print(table)
    console.print(
        f"ego camera: {'yes' if inputs.has_ego else 'no'}; "
        f"CMCs ({len(inputs.cmc_names)}): {', '.join(inputs.cmc_names) or '-'}; "
        f"ground truth: {'yes' if inputs.has_ground_truth else 'no'}"
    )
    if inputs.map.renamed:
        mapping = Table(title="inputs (YOWO's name <- recorded topic)")
        for col in ("input", "recorded topic"):
            mapping.add_column(col)
        for name, recorded in sorted(inputs.map.roles.items()):
            if recorded != name:
                mapping.add_row(name, recorded)
        console.print(mapping)
    for note in inputs.map.notes:
        console.print(f"found: {escape(note)}")
    for problem in inputs.problems:
        console.print(f"[yellow]warning:[/] {escape(problem)}")
    return 0


# The default time limit of a recording's run: start-up and finalisations, plus a multiple of
# its length well above the slowest measured processing rate.
TIMEOUT_BASE_S, TIMEOUT_PER_S = 600.0, 10.0


def _timeout_s(args) -> float:
    if args.timeout is not None:
        return args.timeout
    from yowo_common.ros.bag import recording_span

    start, end = recording_span(args.bag)
    return TIMEOUT_BASE_S + TIMEOUT_PER_S * (end - start) / 1e9


def _execute(args, mode: str):
    """Plan and run the graph; returns the outcome or None (message printed) on failure."""
    import time

    args.started = time.monotonic()
    from .graph_runner import RunFailed, execute
    from .guidance import GuidanceLines, GuidancePage
    from .outdir import claimed_output
    from .progress import console_progress
    from .ros_domain import PRIVATE, SHARED, graph_network
    from .run import plan_live, plan_run

    config = config_from_args(args)
    if args.profile:
        from .profiling import py_spy

        py_spy()  # not installed: said before anything starts
    if args.verb == "live":
        plan = plan_live(
            args.cameras,
            args.output,
            mode=mode,
            source=args.cmc_source,
            image_topic=args.image_topic,
            ego_topics=(args.ego_color, args.ego_depth, args.ego_info),
            config=config,
            run_id=args.run_id,
        )
        what = f"live run {plan.run_id} (end the walk with 'yowo end-walk')"
        domain = SHARED  # live cameras are on the user's graph
    else:
        plan = plan_run(args.bag, args.output, mode=mode, config=config, source=args.cmc_source, run_id=args.run_id)
        what = f"{plan.mode} run {plan.run_id} of {recording_label(args.bag)}"
        if plan.mode_reason:  # the user asked for a full run; say plainly why it is not one
            print(f"ego-only run (the map alone, no camera is registered): {plan.mode_reason}")
        # Private unless asked: lingering serves the user's /tf_static subscribers.
        domain = args.domain or (SHARED if args.linger > 0 else PRIVATE)
    plan.select(args.nodes)
    network = graph_network(domain if domain in (PRIVATE, SHARED) else int(domain))
    for note in plan.inputs.get("layout", []):
        print(f"input: {note}")
    if "imu" in plan.inputs:
        imu = plan.inputs["imu"]
        print(
            "ego IMU: "
            + (
                f"{', '.join(imu['topics'])}; extrinsics from {imu['extrinsics']}; noise from {imu['noise']}"
                if imu["used"]
                else f"not used: {imu['reason']}"
            )
        )
    for w in plan.warnings:
        print(f"warning: {w}", file=sys.stderr)
    print(
        f"{what}: {len(plan.cameras)} CMCs ({', '.join(plan.cameras) or 'none'}), "
        f"{len(plan.local_nodes)} nodes in {len(plan.local_processes)} processes here; graph on "
        f"{network.describe()}; "
        f"logs in {Path(args.output) / 'logs'}"
    )
    with claimed_output(args.output, args.replace):
        progress = console_progress(f"{args.verb} {plan.run_id}")
        # Live, the walker is told which camera needs more while walking; a page that reloads
        # itself shows every camera (guidance_live.html, also for a replayed recording).
        page = GuidancePage(Path(args.output) / "guidance_live.html", plan.source)
        lines = GuidanceLines() if args.verb == "live" else None

        def on_guidance(msg) -> None:
            page(msg)
            if lines is not None:
                lines(msg)

        try:
            timeout_s = args.timeout if args.verb == "live" else _timeout_s(args)
            return execute(
                plan,
                timeout_s=timeout_s,
                network=network,
                linger_s=getattr(args, "linger", 0.0),
                progress=progress,
                profile_dir=Path(args.profile) if args.profile else None,
                guidance=on_guidance,
            )
        except RunFailed as exc:
            failure = exc
        finally:
            progress.close()  # before the message: a live bar would redraw over it
    print(f"yowo {args.verb}: {failure}\n(partial results, if any, are in {args.output})", file=sys.stderr)
    return None


def _elapsed(args) -> str:
    import time

    seconds = time.monotonic() - args.started
    return f"done in {int(seconds // 60)} min {seconds % 60:.0f} s; "


def cmd_run(args) -> int:
    """The full pipeline through the real node graph: map + every CMC registered in it."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from .run import EGO, FULL

    out = _execute(args, FULL)
    if out is None:
        return 1
    metrics, ev = Path(args.output) / "metrics.json", evaluator()
    if out.mode == EGO:
        if metrics.exists() and ev is not None:
            ev.print_tables(json.loads(metrics.read_text()), Console())
        print(
            f"{_elapsed(args)}results: {args.output}/ (ego-only: ego_trajectory.tum, map.ply, layout.json, report.html, result.mcap; "
            "cameras.yaml says why no camera was registered)"
        )
        return 0 if (Path(args.output) / "ego_trajectory.tum").exists() else 1
    table = Table(title="registered cameras (map frame)")
    for col in ("camera", "group", "method", "verdict", "position [m]", "RMSE [px]", "reason"):
        table.add_column(escape(col))  # brackets are rich markup unless escaped
    for c in out.cameras:
        pos = ", ".join(f"{v:.3f}" for v in c.T_world_cam[:3, 3]) if c.T_world_cam is not None else "-"
        table.add_row(c.name, c.group or "-", c.method, c.status, pos, f"{c.rmse_px:.2f}", escape(c.reason))
    Console().print(table)
    if metrics.exists() and ev is not None:
        ev.print_tables(json.loads(metrics.read_text()), Console())
    print(
        f"{_elapsed(args)}results: {args.output}/ (report.html, cameras.yaml, ego_trajectory.tum, map.ply, layout.json after the "
        "joint optimisation; ego_trajectory_ego.tum, map_ego.ply, layout_ego.json the ego stage's; result.mcap)"
    )
    return 0 if any(c.T_world_cam is not None for c in out.cameras) else 1


def cmd_live(args) -> int:
    """The graph on live camera topics: full registration, or relative calibration (--cmc-only)."""
    from .run import CMC, FULL

    out = _execute(args, CMC if args.cmc_only else FULL)
    if out is None:
        return 1
    if args.cmc_only:  # the groups and the cameras in none
        done = sum(len(g.names) for g in out.cameras)
        total = done + len(out.ungrouped)
    else:
        done = sum(c.T_world_cam is not None for c in out.cameras)
        total = len(out.cameras)
    print(f"{_elapsed(args)}results: {args.output}/ ({done} of {total} cameras calibrated; see cameras.yaml)")
    return 0


def cmd_calibrate_cmc(args) -> int:
    """CMC-only relative calibration through the real node graph (no ego camera needed)."""
    from .run import CMC

    out = _execute(args, CMC)
    if out is None:
        return 1
    for g in out.cameras:
        print(f"group {g.group_id}: " + ", ".join(f"{n} ({g.rmse_px[n]:.2f} px)" for n in g.names))
    for name, why in out.ungrouped.items():
        print(f"not calibrated: {name}: {why}")
    print(f"{_elapsed(args)}results in {args.output}/cameras.yaml")
    return 0 if out.cameras else 1


def config_from_args(args):
    """The configuration tree: --config FILE, then every --set section.key=value, then the
    options that are shorthands for keys (--rate, --max-restarts)."""
    from .config import load_config

    shorthands = [f"replay.rate={args.rate}"] if getattr(args, "rate", None) is not None else []
    if getattr(args, "max_restarts", None) is not None:
        shorthands.append(f"supervisor.max_restarts={args.max_restarts}")
    config = load_config(args.config, (args.set or []) + shorthands)
    # Input options add to the configuration's inputs section.
    inputs = config.inputs
    for option, key in (("remap", "remap"), ("intrinsics", "intrinsics"), ("cmc_video", "videos")):
        if getattr(args, option, None):
            inputs = replace(inputs, **{key: getattr(inputs, key) + tuple(getattr(args, option))})
    if getattr(args, "cmc_videos", None):
        inputs = replace(inputs, video_list=args.cmc_videos)
    return replace(config, inputs=inputs)


def _add_input_options(p) -> None:
    p.add_argument(
        "bag",
        nargs="+",
        help="rosbag2 directory or .mcap file; several are read as one recording in time order (a second "
        "walk of the same building and cameras, e.g. the one guidance.html suggests, added to the first)",
    )
    p.add_argument(
        "-r",
        "--remap",
        action="append",
        metavar="INPUT:=TOPIC",
        help="which recorded topic is one of YOWO's inputs, ROS remapping style, e.g. "
        "-r /ego/color/image_raw:=/cam/rgb/image_raw (repeatable; adds to inputs.remap). Common "
        "driver layouts (realsense2_camera, Azure Kinect / Orbbec, ZED) and image_transport camera "
        "namespaces are found without it; 'yowo info' shows what was found",
    )
    p.add_argument(
        "--intrinsics",
        action="append",
        metavar="CAMERA=FILE",
        help="a ceiling camera's intrinsics from a calibration file: camera_calibration_parsers YAML, "
        "Kalibr camchain, COLMAP cameras.txt or OpenCV YAML/XML (repeatable; inputs.intrinsics). A "
        "camera without CameraInfo or file has its intrinsics estimated",
    )
    p.add_argument(
        "--cmc-video",
        action="append",
        metavar="CAMERA=FILE[@START]",
        help="a ceiling camera's footage as a video file; START: seconds since the epoch or ISO 8601 "
        "(default: the file's creation_time); may be seconds off, the clock offsets are estimated "
        "(repeatable; inputs.videos)",
    )
    p.add_argument(
        "--cmc-videos", metavar="YAML", help="a list of {name, file, start} video entries (inputs.video_list)"
    )


def _add_run_options(p) -> None:
    _add_input_options(p)
    p.add_argument("-o", "--output", required=True, help="results directory")
    p.add_argument("--rate", type=float, help="replay speed (x real time; 0 = as fast as possible): replay.rate")
    add_config_options(p)
    p.add_argument(
        "--timeout",
        type=float,
        help=f"give up after this many seconds (default: {TIMEOUT_BASE_S:.0f} s plus {TIMEOUT_PER_S:g} "
        "times the recording's length)",
    )
    p.add_argument(
        "--linger",
        type=float,
        default=0.0,
        help="keep the graph up this many seconds after the results are written (late /tf_static subscribers)",
    )
    p.add_argument(
        "--cmc-source",
        choices=("auto", "keypoints", "pose", "images"),
        default="auto",
        help="CMC agent keypoints: recorded /cmc/<n>/agent_keypoints, the human-pose model on the "
        "images (falling back to the model-free detector for a camera where it finds nobody), "
        "the model-free image detector, or auto (keypoints when recorded, else pose)",
    )
    p.add_argument(
        "--domain",
        metavar="private|shared|ID",
        help="DDS graph of the run: 'private' (default; a ROS domain no other run on this host uses, "
        "localhost discovery), 'shared' (your ROS_DOMAIN_ID and discovery settings; the default "
        "with --linger), or a domain id (a graph split across hosts with --nodes)",
    )
    _add_graph_options(p)


def _add_graph_options(p) -> None:
    p.add_argument(
        "--replace",
        action="store_true",
        help="the results folder holds an earlier run's results: remove them first (without it such a "
        "folder is refused)",
    )
    p.add_argument(
        "--run-id",
        help="the run's id, in every status message (default: a new one); give every host of a split run the same",
    )
    p.add_argument(
        "--nodes",
        nargs="+",
        metavar="PATTERN",
        help="start only these nodes here (names or patterns, e.g. replay 'keypoint_tracker_*'); the "
        "others run on other hosts of the same --domain and --run-id",
    )
    p.add_argument(
        "--max-restarts",
        type=int,
        help="restart a node that dies up to this many times (it is sent what it missed): supervisor.max_restarts",
    )
    p.add_argument(
        "--profile",
        metavar="DIR",
        help="record every node process with py-spy into DIR (<node>.txt, collapsed stacks for "
        "flamegraph.pl or speedscope) and summarise each node's top functions in DIR/summary.md",
    )


def add_config_options(p) -> None:
    p.add_argument(
        "--config",
        metavar="YAML",
        help="configuration file: sections of the tree (replay, ego, cmc, "
        "fusion, supervisor) with the keys to change; "
        "'yowo config' prints every key with its default",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="SECTION.KEY=VALUE",
        help="change one key of the configuration tree, e.g. ego.odometry.scale=1 (repeatable)",
    )


def cmd_config(args) -> int:
    """Print the resolved configuration tree (defaults, --config, --set) as YAML, each key
    with its one-line description and unit as a comment."""
    from yowo_common.config import dump_described

    print(dump_described(config_from_args(args)), end="")
    return 0


def cmd_end_walk(args) -> int:
    """Live operation: tell the running stages that the walk is over."""
    from .run_monitor_node import end_walk

    end_walk(args.linger, args.run_id or "")
    print("end of walk announced on /yowo/replay/status" + (f" to run {args.run_id}" if args.run_id else ""))
    return 0


def _version() -> str:
    from importlib.metadata import version

    return f"yowo {version('yowo_bringup')} (ROS 2 Jazzy, rclpy {version('ros-jazzy-rclpy')})"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="yowo", description="YOWO: map a scene and register its ceiling cameras from one walk."
    )
    parser.add_argument("--version", action="version", version=_version())
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")

    p = verbs.add_parser("info", help="list a recording's topics and the cameras YOWO finds in it")
    _add_input_options(p)
    add_config_options(p)
    p.set_defaults(func=cmd_info)

    p = verbs.add_parser("run", help="map the scene and register every CMC in it (the full node graph)")
    _add_run_options(p)
    p.set_defaults(func=cmd_run)

    p = verbs.add_parser("calibrate-cmc", help="relative calibration of each CMC group from agent keypoints only")
    _add_run_options(p)
    p.set_defaults(func=cmd_calibrate_cmc)
    p = verbs.add_parser("live", help="run the graph on live camera topics (no recording) until 'yowo end-walk'")
    p.add_argument("--cameras", nargs="+", required=True, help="CMC names (topics /cmc/<name>/...)")
    p.add_argument("-o", "--output", required=True, help="results directory")
    p.add_argument("--cmc-only", action="store_true", help="relative calibration of the CMC groups only")
    p.add_argument(
        "--cmc-source",
        choices=("keypoints", "pose", "images"),
        default="keypoints",
        help="agent keypoints from /cmc/<n>/agent_keypoints, the human-pose model or the model-free image detector",
    )
    p.add_argument("--image-topic", default="image_raw/compressed", help="CMC image topic under /cmc/<name>/")
    p.add_argument("--ego-color", default=topics.EGO_COLOR[1])
    p.add_argument("--ego-depth", default=topics.EGO_DEPTH[0])
    p.add_argument("--ego-info", default=topics.EGO_INFO)
    add_config_options(p)
    p.add_argument("--timeout", type=float, default=24 * 3600.0, help="give up after this many seconds")
    _add_graph_options(p)
    p.set_defaults(func=cmd_live)

    p = verbs.add_parser("end-walk", help="live operation: the walk is over, let every stage finalise")
    p.add_argument(
        "--linger", type=float, default=10.0, help="seconds to keep the announcement up once a stage has matched"
    )
    p.add_argument("--run-id", help="the live run to end (default: any live run on this ROS domain)")
    p.set_defaults(func=cmd_end_walk)

    p = verbs.add_parser(
        "config",
        help="print the configuration tree: every key with its value (defaults, "
        "--config, --set), as a --config file takes it",
    )
    add_config_options(p)
    p.set_defaults(func=cmd_config)

    add_verbs(verbs)  # of installed extensions (yowo_sim: simulate, demo; yowo_eval: bench, eval)
    for verb_parser in verbs.choices.values():  # a wrong option gets its own verb's usage
        verb_parser.set_defaults(verb_parser=verb_parser)
    return parser


def main(argv=None) -> int:
    from .ros_domain import NoFreeDomain

    args, unknown = build_parser().parse_known_args(argv)
    if unknown:
        args.verb_parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    try:
        return args.func(args)
    except (BagError, ValueError, NoFreeDomain) as exc:
        print(f"yowo {args.verb}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
