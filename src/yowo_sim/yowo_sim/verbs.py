"""What yowo_sim adds to the `yowo` command line (an entry point in its setup.py, found
by yowo_bringup.plugins): `simulate` and `demo`."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

# --layout choices: YOWO's own names, or a real driver's (yowo_sim.driver_layout.LAYOUTS).
LAYOUT_HELP = {
    "yowo": "YOWO's own topics (/ego/..., /cmc/<name>/...)",
    "realsense": "realsense2_camera 4.x: /camera/camera/color, aligned_depth_to_color, gyro/sample + accel/sample",
    "realsense_united": "realsense2_camera with unite_imu_method 2: one /camera/camera/imu",
    "azure": "Azure Kinect / Orbbec Femto driver: /rgb, /depth_to_rgb, /imu",
    "zed": "zed-ros2-wrapper: /zed/zed_node/rgb/image_rect_color, 32FC1 depth_registered in metres, imu/data",
}


def cmd_simulate(args) -> int:
    """Generate a synthetic recording with ground truth."""
    from rich.progress import Progress

    from yowo_sim.capture import generate
    from yowo_sim.presets import get_preset

    output = Path(args.output)
    if args.no_camera_info and args.layout == "yowo" and not args.cmc_videos:
        raise ValueError("--no-camera-info needs a driver --layout or --cmc-videos")
    if args.cmc_videos and args.layout != "yowo":
        raise ValueError("--cmc-videos writes YOWO's own layout beside the videos; leave out --layout")
    if output.exists():
        raise ValueError(f"{output}: already exists; refusing to overwrite a recording")
    # A driver layout or videos are converted from YOWO's layout, simulated beside the output
    # (same disk) and then removed.
    converted = args.layout != "yowo" or args.cmc_videos
    recording = output.with_name(f".{output.name}.yowo-layout") if converted else output
    if recording != output:
        shutil.rmtree(recording, ignore_errors=True)  # left by an interrupted run

    overrides = {}
    if args.no_cmc_images:
        overrides["cmc_images"] = False
    if args.raw:
        overrides["raw_images"] = True
    if args.ego_hz:
        overrides["ego_hz"] = args.ego_hz
    if args.cmc_hz:
        overrides["cmc_hz"] = args.cmc_hz
    if args.cmc_clock_offset:
        overrides["cmc_clock_offset_s"] = args.cmc_clock_offset
    if args.no_imu:
        overrides["imu"] = False
    if args.bystanders:
        overrides["bystanders"] = replace(get_preset(args.preset).bystanders, count=args.bystanders)
    if args.deficient:
        from yowo_sim.deficient import parse_deficient

        overrides["deficient"] = parse_deficient(args.deficient)
    preset = get_preset(args.preset, **overrides)
    follow = None
    if args.follow:
        from yowo_sim.follow import follow_walk

        if not args.after:
            raise ValueError("--follow needs --after FIRST_RECORDING (the first walk's simulated recording)")
        follow = follow_walk(args.follow, args.after, args.gap)
    with Progress() as bar:
        task = bar.add_task(f"simulating '{args.preset}' (seed {args.seed})", total=None)
        try:
            summary = generate(
                preset,
                args.seed,
                recording,
                progress=lambda done, total: bar.update(task, completed=done, total=total),
                follow=follow,
            )
            if args.cmc_videos:
                from yowo_sim.cmc_video import write_cmc_videos

                bar.update(task, description=f"writing the CMC videos into {args.cmc_videos}")
                write_cmc_videos(recording, output, args.cmc_videos, args.video_start_error, args.no_camera_info or ())
            elif recording != output:
                from yowo_sim.driver_layout import write_driver_layout

                bar.update(task, description=f"writing the '{args.layout}' layout")
                write_driver_layout(recording, output, args.layout, args.no_camera_info)
        finally:
            if recording != output:
                shutil.rmtree(recording, ignore_errors=True)
    if args.preview:
        from yowo_sim.capture import build_capture
        from yowo_sim.preview import render_preview

        render_preview(build_capture(preset, args.seed, follow), args.preview)
        print(f"preview: {args.preview}")
    fps = summary.rendered_frames / max(summary.render_seconds, 1e-9)
    print(
        f"wrote {output} ({args.layout} layout): {summary.duration_s:.1f} s walk, {summary.ego_frames} ego frames, "
        f"{summary.cmc_frames} CMC frames ({summary.cmc_frames_with_agent} with the agent detected), "
        f"{len(summary.cmcs)} CMCs, {summary.imu_samples} IMU samples"
        + (f", {summary.bystanders} bystanders" if summary.bystanders else "")
        + f"; rendering {fps:.1f} frames/s"
    )
    return 0


def cmd_demo(args) -> int:
    """Make (or reuse) a sample recording, run the full graph on it, show the metrics."""
    from rich.progress import Progress

    from yowo_sim.capture import generate
    from yowo_sim.presets import get_preset

    bag = Path(args.bag)
    if not (bag / "metadata.yaml").exists():
        with Progress() as bar:
            task = bar.add_task(f"generating the sample recording {bag} (preset {args.preset}, seed 0)", total=None)
            generate(get_preset(args.preset), 0, bag, progress=lambda d, t: bar.update(task, completed=d, total=t))
    from yowo_bringup.cli import build_parser, cmd_run

    code = cmd_run(build_parser().parse_args(["run", str(bag), "-o", args.output]))
    print(f"\nreport: {Path(args.output) / 'report.html'}")
    return code


def add_verbs(verbs) -> None:
    p = verbs.add_parser("simulate", help="generate a synthetic recording with ground truth")
    p.add_argument("--preset", default="small", help="tiny | small | standard | large | floor50 (default: small)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", required=True, help="new rosbag2 directory to write (MCAP)")
    p.add_argument("--no-cmc-images", action="store_true", help="record CMC keypoints only, no images")
    p.add_argument("--raw", action="store_true", help="raw sensor_msgs/Image instead of compressed")
    p.add_argument("--ego-hz", type=float, help="ego camera rate (default 15)")
    p.add_argument("--cmc-hz", type=float, help="CMC rate (default 10)")
    p.add_argument(
        "--cmc-clock-offset",
        type=float,
        metavar="S",
        help="unsynchronised CMC clocks: each off the ego's by up to +-S seconds (default 0)",
    )
    p.add_argument("--no-imu", action="store_true", help="record no /ego/imu (an RGB-D camera without an IMU)")
    p.add_argument(
        "--bystanders",
        type=int,
        default=0,
        metavar="N",
        help="N other people walking about, some passing the agent; their keypoints only in /gt/bystanders/ "
        "(default 0)",
    )
    p.add_argument(
        "--deficient",
        nargs="+",
        default=[],
        metavar="KIND",
        help="a walk deficient on purpose, recorded on /gt/deficient: 'corner' (a camera drawn from the seed), "
        "'corner:CAM' or 'corner:CAM:top-left' (that camera sees the walker only in one corner of its image: "
        "a ninth, else a quadrant), 'doorway' (two rooms joined by one pass through a doorway); or its reference, "
        "'covering' (the walk passes every ninth of every camera's image it can reach: sufficient on purpose)",
    )
    p.add_argument(
        "--follow",
        metavar="RUN_DIR",
        help="a second walk that follows RUN_DIR/second_walk.yaml (the walk guidance's suggestion), through the "
        "same building, cameras and clocks (give the first walk's --preset, --seed and options), recorded --gap "
        "seconds after --after ends; run both with 'yowo run FIRST SECOND'",
    )
    p.add_argument("--after", metavar="BAG", help="the first walk's simulated recording (for --follow)")
    p.add_argument("--gap", type=float, default=60.0, metavar="S", help="silence between the walks (default 60 s)")
    p.add_argument("--preview", metavar="PNG", help="also write a picture: ego frame, CMC frame, top view")
    p.add_argument(
        "--layout",
        choices=list(LAYOUT_HELP),
        default="yowo",
        help="topic names, frames and encodings as written by: "
        + "; ".join(f"{k}: {v}" for k, v in LAYOUT_HELP.items())
        + ". Driver layouts put the CMCs under /cctv/<name>/ (image_transport compressed, PNG for "
        "--raw) and record no /ego/imu/calibration (default: yowo)",
    )
    p.add_argument(
        "--no-camera-info",
        nargs="+",
        default=[],
        metavar="CAM",
        help="record no camera_info for these CMCs (cam00, ...; needs a driver --layout or --cmc-videos)",
    )
    p.add_argument(
        "--cmc-videos",
        metavar="DIR",
        help="the CMCs' images as OpenCV-written video files in DIR (<name>.mp4, and videos.yaml with "
        "each start as an NVR's clock gives it), the recording without their images and keypoints",
    )
    p.add_argument(
        "--video-start-error",
        type=float,
        default=3.0,
        metavar="S",
        help="how far each video's start in videos.yaml is off the recording's clock (default 3 s)",
    )
    p.set_defaults(func=cmd_simulate)

    p = verbs.add_parser("demo", help="generate a sample recording, run the full graph, print the metrics")
    p.add_argument("--preset", default="small")
    p.add_argument("--bag", default="bags/demo_small", help="where the sample recording is (made if missing)")
    p.add_argument("-o", "--output", default="results/demo")
    p.set_defaults(func=cmd_demo)
