"""`yowo import-multiview`: a real multi-camera recording of a person -- per-camera 2D
keypoints (OpenPose JSON, as Pose2Sim keeps them in pose/<cam>_json/) and a reference
calibration (Pose2Sim's Calib*.toml: K, distortion, rvec/tvec) -- optionally with the
cameras' videos, -> a rosbag2 MCAP recording in YOWO's contract: per CMC CameraInfo,
AgentKeypoints (ids as in yowo_cmc.pose_keypoints: 0 head top and 1 ground point derived by
its code, body joints 2+) and, with --videos, the frames as JPEG CompressedImage; the
reference poses on /gt/cmc/<name>/pose for the evaluation only (hence in yowo_eval).

Pose2Sim pairs calibration cameras, keypoint folders and videos by sorted order; so does
this importer (and prints the pairing).

A caliscope recording (github mprib/caliscope, BSD-2-Clause) is read from its 2D keypoint
table `xy_<TRACKER>.csv` (one row per camera, frame and point: sync_index, port or cam_id,
frame_index, frame_time [s], point_id, img_loc_x, img_loc_y) and its calibration
(`config.toml` [cam_N] or `camera_array.toml` [cameras.N]: size, matrix, distortions,
rotation as a 3x3 matrix and translation, world -> camera). Frames are stamped by their
frame_time (caliscope's cameras are unsynchronised; these are their capture times on one
host clock). Points 0-32 are mediapipe's pose landmarks (BlazePose ids, ids 0 and 1
derived); other points (hands from 100, face from 500 for HOLISTIC) keep their id + 2.
The 4-camera demo of its tests (a seated person, holistic keypoints, a ChArUco reference):

    G="git --git-dir=<fetched caliscope>"; S=tests/sessions/4_cam_recording
    $G show f7c314b4:$S/config.toml > config.toml
    $G show f7c314b4:$S/recordings/recording_1/HOLISTIC/xy_HOLISTIC.csv > xy_HOLISTIC.csv
    yowo import-multiview xy_HOLISTIC.csv --calibration config.toml -o caliscope_kp

The Pose2Sim demo recording (github perfanalytics/pose2sim, BSD-3-Clause; its keypoints and
converted calibration are in the repository's history, not its newest tree):

    G="git --git-dir=<fetched pose2sim>"; T=Pose2Sim/Demo/S00_Demo_Session
    $G archive a948c20~1 $T/S00_P00_SingleParticipant/S00_P00_T01_BalancingTrial | tar x --strip-components=5
    $G show bea4835~1:$T/S00_Calibration/Calib_qualisys.toml > Calib_qualisys.toml
    yowo import-multiview . --calibration Calib_qualisys.toml -o p2s_kp             # keypoints
    yowo import-multiview . --calibration Calib_qualisys.toml --videos -o p2s_video # + videos
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .multiview_readers import (
    BLAZEPOSE,
    MultiviewImportError,
    ReferenceCamera,
    Video,
    all_formats,
    find_caliscope_calibration,
    format_joints,
    frame_files,
    joint_ids,
    read_caliscope_calibration,
    read_caliscope_keypoints,
    read_people,
    read_session,
)

START_NS = 1_000_000_000_000_000_000  # the recording's first frame (any fixed instant)
GT_FRAME = "map"  # the reference calibration's world frame, as it came


def person_pose(uv: np.ndarray, conf: np.ndarray, fmt: str, width: int, height: int):
    """One detected person as the pose model's PersonPose: ids 0 and 1 derived by the pose
    model's own rules (head_top, ground_point; a big toe stands for BlazePose's foot index),
    joints outside the image at confidence 0 as there, the box over the confident joints."""
    from yowo_cmc.params import PoseModelParams
    from yowo_cmc.pose_keypoints import GROUND, HEAD_TOP, PersonPose, derive_top_and_ground

    p = PoseModelParams()
    names = format_joints(fmt)
    conf = conf.copy()
    outside = (uv[:, 0] < -0.5) | (uv[:, 0] > width - 0.5) | (uv[:, 1] < -0.5) | (uv[:, 1] > height - 0.5)
    conf[outside] = 0.0
    top, ground = derive_top_and_ground(dict(zip(names, zip(uv, conf))), p)
    table = joint_ids(fmt)
    ids = np.array([HEAD_TOP, GROUND] + [table[n] for n in names if n in table], dtype=int)
    keep = [i for i, n in enumerate(names) if n in table]
    all_uv = np.vstack([top[:2], ground[:2], uv[keep]])
    all_conf = np.concatenate([[top[2], ground[2]], conf[keep]])
    seen = conf > 0
    score = float(conf[seen].mean()) if seen.any() else 0.0
    pts = uv[seen] if seen.any() else uv
    box = np.concatenate([pts.min(axis=0), pts.max(axis=0)])
    return PersonPose(score=score, box=box, ids=ids, uv=all_uv, confidence=all_conf)


@dataclass
class AgentTracker:
    """The agent among several people per frame: the best-scored person to start, then the
    one nearest the agent's last box centre within max_jump of the image diagonal (the
    nearest rather than the best: others may score higher); lost after lost_after frames
    without it. Counts the others. A recording without an ego camera has no walker's motion
    to tell people apart (yowo_cmc.walker)."""

    diagonal_px: float
    max_jump: float = 0.15
    lost_after: int = 10
    others: int = 0
    _previous: np.ndarray | None = field(default=None, repr=False)
    _missed: int = 0

    def pick(self, people):
        people = sorted(people, key=lambda p: -p.score)
        agent = people[0] if people and self._previous is None else None
        if people and self._previous is not None:
            centres = np.array([(p.box[:2] + p.box[2:]) / 2 for p in people])
            d = np.hypot(*(centres - self._previous).T)
            k = int(np.argmin(d))
            agent = people[k] if d[k] <= self.max_jump * self.diagonal_px else None
        if agent is None:
            self._missed += 1
            if self._missed >= self.lost_after:
                self._previous = None
            return None
        self.others += len(people) - 1
        self._previous, self._missed = (agent.box[:2] + agent.box[2:]) / 2, 0
        return agent


@dataclass(kw_only=True)
class CameraSummary:
    name: str
    keypoints_from: str | None
    video_from: str | None
    frames: int = 0
    with_agent: int = 0
    others: int = 0


@dataclass
class ImportSummary:
    bag: Path
    fps: float
    cameras: list[CameraSummary]


@contextmanager
def _recording(bag: Path, cameras: list[ReferenceCamera]):
    """A new recording with the reference poses latched on /gt/; removed again when the
    import fails (no half recording left behind)."""
    import shutil

    from geometry_msgs.msg import PoseStamped
    from std_msgs.msg import Header

    from yowo_common import topics
    from yowo_common.ros.bag import BagError, BagWriter
    from yowo_common.rosconv import matrix_to_pose, ns_to_time

    if bag.exists():
        raise MultiviewImportError(f"{bag}: already exists; refusing to overwrite a recording")
    try:
        with BagWriter(bag) as out:
            header0 = Header(stamp=ns_to_time(START_NS), frame_id=GT_FRAME)
            for ref in cameras:
                out.write(
                    topics.gt_cmc_pose_topic(ref.name),
                    PoseStamped(header=header0, pose=matrix_to_pose(ref.T_world_cam)),
                    START_NS,
                    latched=True,
                )
            yield out
    except BagError as exc:
        shutil.rmtree(bag, ignore_errors=True)
        raise MultiviewImportError(str(exc)) from None
    except MultiviewImportError:
        shutil.rmtree(bag, ignore_errors=True)
        raise


def _write_keypoints(out, name: str, header, ids, uv, confidence) -> int:
    """One AgentKeypoints message (the joints with confidence > 0): how many it holds."""
    from yowo_common import topics
    from yowo_common.rosconv import stamp_to_ns
    from yowo_msgs.msg import AgentKeypoints, Keypoint2D

    kps = [
        Keypoint2D(id=int(i), x=float(u), y=float(v), confidence=float(c))
        for i, (u, v), c in zip(ids, uv, confidence)
        if c > 0
    ]
    out.write(
        topics.cmc_keypoints_topic(name),
        AgentKeypoints(header=header, camera_name=name, keypoints=kps),
        stamp_to_ns(header.stamp),
    )
    return len(kps)


def import_multiview(
    folder,
    bag,
    calibration=None,
    keypoint_format: str = "BODY_25B",
    videos: bool = False,
    fps: float | None = None,
    max_frames: int | None = None,
    jpeg_quality: int = 90,
    progress=None,
    as_detector: bool = False,
) -> ImportSummary:
    """Write the session as a recording. `as_detector`: the agent's joints as the detector
    numbers them (+ 2, Keypoint2D.msg) without the derived ids 0 and 1, as a detector
    publishing on a topic gives them (declare its skeleton, cmc.keypoints, when calibrating). Frame i of every camera is stamped START_NS + i / fps
    (the cameras of these recordings are synchronised; the frame numbers say which images
    belong together). CameraInfo per frame (with --videos at the video's size, which may
    differ from the calibration's by the codec's padding: K stays); AgentKeypoints per
    keypoint frame (empty: nobody recognised); the reference poses latched on /gt/."""
    from std_msgs.msg import Header

    from yowo_cmc.pose_keypoints import ID_OFFSET
    from yowo_common import topics
    from yowo_common.camera import CameraModel
    from yowo_common.rosconv import encode_color_jpeg, model_to_camera_info, ns_to_time

    if keypoint_format not in all_formats():
        raise MultiviewImportError(f"unknown keypoint format '{keypoint_format}' ({', '.join(all_formats())})")
    s = read_session(folder, calibration, videos, fps)
    streams = [Video(v) for v in s.videos]
    rate = s.fps
    if not rate:
        raise MultiviewImportError(
            f"{folder}: no frame rate (Config.toml [project] frame_rate, or the videos'); give --fps"
        )
    bag = Path(bag)
    summaries = []
    try:
        with _recording(bag, s.cameras) as out:
            for k, ref in enumerate(s.cameras):
                kp_dir = s.keypoint_dirs[k] if s.keypoint_dirs else None
                video = streams[k] if streams else None
                summary = CameraSummary(
                    name=ref.name,
                    keypoints_from=kp_dir.name if kp_dir else None,
                    video_from=video.path.name if video else None,
                )
                files = dict(frame_files(kp_dir)) if kp_dir else {}
                indices = sorted(files) if files else list(range(video.count))
                if video:
                    indices = sorted(set(indices) | set(range(video.count)))
                indices = indices[:max_frames] if max_frames else indices
                cam = ref.camera
                tracker = AgentTracker(math.hypot(cam.width, cam.height))
                for n, i in enumerate(indices):
                    stamp = START_NS + round(i / rate * 1e9)
                    header = Header(stamp=ns_to_time(stamp), frame_id=f"{ref.name}_optical_frame")
                    if video:
                        rgb = video.frame(i)
                        if rgb is None:
                            if i in files:
                                raise MultiviewImportError(
                                    f"{video.path}: ends before frame {i}, which {files[i]} has keypoints for"
                                )
                            continue
                        if (rgb.shape[1], rgb.shape[0]) != (cam.width, cam.height):
                            cam = CameraModel(rgb.shape[1], rgb.shape[0], cam.K, cam.D, cam.distortion_model)
                        out.write(
                            topics.cmc_image_topics(ref.name)[1], encode_color_jpeg(rgb, header, jpeg_quality), stamp
                        )
                    out.write(topics.cmc_info_topic(ref.name), model_to_camera_info(cam, header), stamp)
                    summary.frames += 1
                    if i in files:
                        raw = read_people(files[i], keypoint_format)
                        people = [person_pose(uv, c, keypoint_format, cam.width, cam.height) for uv, c in raw]
                        agent = tracker.pick(people)
                        if agent is not None and as_detector:
                            uv, c = raw[next(j for j, p in enumerate(people) if p is agent)]
                            keypoints = (np.arange(len(c)) + ID_OFFSET, uv, c)
                        else:
                            keypoints = (agent.ids, agent.uv, agent.confidence) if agent else ([],) * 3
                        summary.with_agent += int(bool(_write_keypoints(out, ref.name, header, *keypoints)))
                    if progress:
                        progress(k + n / max(len(indices), 1), len(s.cameras))
                summary.others = tracker.others
                summaries.append(summary)
    finally:
        for v in streams:
            v.close()
    return ImportSummary(bag, rate, summaries)


def import_caliscope(xy_csv, bag, calibration=None, progress=None, as_detector: bool = False) -> ImportSummary:
    """Write a caliscope recording (see the module docstring) as a recording: per camera and
    frame CameraInfo and AgentKeypoints stamped by the frame's capture time. `as_detector`:
    every point as holistic numbers it (+ 2), without the derived ids 0 and 1."""
    from std_msgs.msg import Header

    from yowo_cmc.pose_keypoints import ID_OFFSET
    from yowo_common import topics
    from yowo_common.rosconv import model_to_camera_info, ns_to_time

    xy_csv = Path(xy_csv)
    frames = read_caliscope_keypoints(xy_csv)
    calib = Path(calibration) if calibration else find_caliscope_calibration(xy_csv)
    refs = read_caliscope_calibration(calib)
    unknown = sorted(set(frames) - set(refs))
    if unknown:
        raise MultiviewImportError(f"{xy_csv}: keypoints of camera(s) {unknown}, which {calib} does not pose")
    t0 = min(fr[0][0] for fr in frames.values())
    n_pose = len(format_joints(BLAZEPOSE))
    bag, summaries = Path(bag), []
    with _recording(bag, list(refs.values())) as out:
        for k, (cam_id, ref) in enumerate(sorted(refs.items())):
            summary = CameraSummary(name=ref.name, keypoints_from=xy_csv.name, video_from=None)
            cam = ref.camera
            for n, (t, ids, uv) in enumerate(frames.get(cam_id, [])):
                stamp = START_NS + round((t - t0) * 1e9)
                header = Header(stamp=ns_to_time(stamp), frame_id=f"{ref.name}_optical_frame")
                out.write(topics.cmc_info_topic(ref.name), model_to_camera_info(cam, header), stamp)
                body = (ids >= 0) & (ids < n_pose)
                pose_uv, pose_conf = np.zeros((n_pose, 2)), np.zeros(n_pose)
                pose_uv[ids[body]], pose_conf[ids[body]] = uv[body], 1.0  # caliscope keeps no confidence
                person = person_pose(pose_uv, pose_conf, BLAZEPOSE, cam.width, cam.height)
                extra = ids >= n_pose
                summary.frames += 1
                keypoints = (
                    (ids + ID_OFFSET, uv, np.ones(len(ids)))
                    if as_detector
                    else (
                        np.concatenate([person.ids, ids[extra] + ID_OFFSET]),
                        np.vstack([person.uv, uv[extra]]),
                        np.concatenate([person.confidence, np.ones(extra.sum())]),
                    )
                )
                summary.with_agent += int(bool(_write_keypoints(out, ref.name, header, *keypoints)))
                if progress:
                    progress(k + n / max(len(frames.get(cam_id, [])), 1), len(refs))
            summaries.append(summary)
    periods = [np.median(np.diff([fr[0] for fr in f])) for f in frames.values() if len(f) > 1]
    return ImportSummary(bag, 1.0 / float(np.median(periods)) if periods else float("nan"), summaries)


def cmd_import_multiview(args) -> int:
    from .progress import with_progress

    if str(args.session).lower().endswith(".csv"):
        s = with_progress(
            lambda progress: import_caliscope(
                args.session, args.output, args.calibration, progress=progress, as_detector=args.as_detector
            )
        )
    else:
        s = with_progress(
            lambda progress: import_multiview(
                args.session,
                args.output,
                args.calibration,
                args.keypoint_format,
                args.videos,
                args.fps,
                args.max_frames,
                progress=progress,
                as_detector=args.as_detector,
            )
        )
    print(f"wrote {s.bag}: {len(s.cameras)} cameras at {s.fps:g} frames/s, reference poses on /gt/cmc/<name>/pose")
    for c in s.cameras:
        src = ", ".join(
            x
            for x in (c.keypoints_from and f"keypoints {c.keypoints_from}", c.video_from and f"video {c.video_from}")
            if x
        )
        print(
            f"  {c.name}: {src}; {c.frames} frames"
            + (f", the agent in {c.with_agent}" if c.keypoints_from else "")
            + (f", {c.others} other people ignored" if c.others else "")
        )
    print(
        f"next: yowo calibrate-cmc {s.bag} -o RESULTS"
        + ("  (--cmc-source pose: the pose model on the video)" if args.videos else "")
        + (" --set cmc.keypoints.skeleton=FORMAT" if args.as_detector else "")
        + f", then yowo eval RESULTS --bag {s.bag}"
    )
    return 0


def add_verbs(verbs) -> None:
    p = verbs.add_parser(
        "import-multiview",
        help="convert a multi-camera recording of a person (OpenPose JSON "
        "keypoints, Pose2Sim calibration TOML, videos; or a caliscope "
        "xy_*.csv with its config.toml) into a recording",
    )
    p.add_argument(
        "session",
        help="the folder: pose/<camera>_json/*.json, Calib*.toml (or calibration/), videos/; "
        "or caliscope's xy_<TRACKER>.csv",
    )
    p.add_argument("-o", "--output", required=True, help="the rosbag2 (MCAP) recording to write")
    p.add_argument(
        "--calibration",
        help="the reference calibration TOML (default: Calib*.toml in the folder; "
        "caliscope: camera_array.toml or config.toml beside the table or above)",
    )
    p.add_argument(
        "--keypoint-format",
        default="BODY_25B",
        choices=all_formats(),
        help="the joints of pose_keypoints_2d (Pose2Sim's pose_model)",
    )
    p.add_argument("--videos", action="store_true", help="also import videos/* as the CMC images (JPEG)")
    p.add_argument("--fps", type=float, help="frame rate (default: Config.toml's frame_rate, else the videos')")
    p.add_argument("--max-frames", type=int, help="import only the first N frames of each camera")
    p.add_argument(
        "--as-detector",
        action="store_true",
        help="the joints as the detector numbers them (+ 2) without the derived head top and ground point; "
        "calibrate with --set cmc.keypoints.skeleton=FORMAT (body25b, holistic, ...)",
    )
    p.set_defaults(func=cmd_import_multiview)
