"""`yowo import-tum`: a TUM RGB-D benchmark sequence folder (rgb/, depth/, rgb.txt,
depth.txt, groundtruth.txt; https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats)
-> a rosbag2 MCAP recording with the contract's ego topics and the ground truth on
/gt/ego/pose. The ground truth is written for the evaluation only (the pipeline never
reads /gt/), which is why the importer lives in yowo_eval."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path

import numpy as np

# The colour camera's calibration per Kinect (the TUM site's "Intrinsic Camera Calibration of
# the Kinect" table): fx, fy, cx, cy and d0..d4 in OpenCV's plumb_bob order (k1 k2 p1 p2 k3).
# The depth images are registered to the colour camera, so these serve both. fr3's images
# were undistorted by TUM already (zero coefficients); "ros" is the ROS default TUM
# recommends when the distortion is to be ignored.
INTRINSICS = {
    "fr1": ((517.3, 516.5, 318.6, 255.3), (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "fr2": ((520.9, 521.0, 325.1, 249.7), (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "fr3": ((535.4, 539.2, 320.1, 247.6), (0.0, 0.0, 0.0, 0.0, 0.0)),
    "ros": ((525.0, 525.0, 319.5, 239.5), (0.0, 0.0, 0.0, 0.0, 0.0)),
}
DEPTH_FACTOR = 5000.0  # TUM depth PNGs: 5000 units per metre, 0 = no measurement
MAX_DIFFERENCE_S = 0.02  # associate.py's default --max_difference
GT_FRAME = "world"  # the motion-capture system's frame (not YOWO's map)
EGO_FRAME = "ego_optical_frame"


class TumImportError(ValueError):
    """Bad input, with the file named; the CLI prints it without a traceback."""


@dataclass
class TumSequence:
    folder: Path
    rgb: list[tuple[int, str]]  # (stamp ns, path relative to the folder), file order
    depth: list[tuple[int, str]]
    groundtruth: list[tuple[int, np.ndarray]] = field(default_factory=list)  # (stamp ns, tx ty tz qx qy qz qw)


def stamp_ns(text: str, where: str) -> int:
    """TUM's decimal seconds -> integer nanoseconds, exactly (a float64 loses ~100 ns at 1.3e9 s)."""
    try:
        return int(Decimal(text) * 1_000_000_000)
    except InvalidOperation:
        raise TumImportError(f"{where}: '{text}' is not a timestamp in seconds") from None


def _lines(path: Path):
    if not path.is_file():
        raise TumImportError(
            f"{path}: missing (a TUM RGB-D sequence folder holds rgb.txt, depth.txt, groundtruth.txt, rgb/ and depth/)"
        )
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        line = line.strip()
        if line and not line.startswith("#"):  # TUM files start with '#' comment lines
            yield f"{path}:{n}", line.replace(",", " ").split()


def read_file_list(path: Path) -> list[tuple[int, str]]:
    """rgb.txt / depth.txt: 'timestamp filename' per line."""
    out = []
    for where, parts in _lines(path):
        if len(parts) != 2:
            raise TumImportError(f"{where}: expected 'timestamp filename', got {' '.join(parts)!r}")
        out.append((stamp_ns(parts[0], where), parts[1]))
    if not out:
        raise TumImportError(f"{path}: lists no images")
    return out


def read_groundtruth(path: Path) -> list[tuple[int, np.ndarray]]:
    """groundtruth.txt: 'timestamp tx ty tz qx qy qz qw' per line."""
    out = []
    for where, parts in _lines(path):
        if len(parts) != 8:
            raise TumImportError(f"{where}: expected 'timestamp tx ty tz qx qy qz qw', got {' '.join(parts)!r}")
        try:
            values = np.array([float(v) for v in parts[1:]])
        except ValueError:
            raise TumImportError(f"{where}: not numbers: {' '.join(parts[1:])!r}") from None
        if not np.isfinite(values).all() or abs(np.linalg.norm(values[3:]) - 1.0) > 1e-3:
            raise TumImportError(f"{where}: not a pose with a unit quaternion: {' '.join(parts[1:])!r}")
        out.append((stamp_ns(parts[0], where), values))
    if not out:
        raise TumImportError(f"{path}: holds no poses")
    return out


def read_sequence(folder) -> TumSequence:
    folder = Path(folder)
    if not folder.is_dir():
        raise TumImportError(f"{folder}: no such folder")
    missing = [n for n in ("rgb.txt", "depth.txt", "groundtruth.txt", "rgb", "depth") if not (folder / n).exists()]
    if len(missing) == 5:
        raise TumImportError(
            f"{folder}: not a TUM RGB-D sequence folder (no rgb.txt, depth.txt, groundtruth.txt, rgb/ or depth/ in it)"
        )
    if missing:
        raise TumImportError(
            f"{folder}: missing {', '.join(missing)} (a TUM RGB-D sequence folder holds rgb.txt, "
            "depth.txt, groundtruth.txt, rgb/ and depth/)"
        )
    return TumSequence(
        folder,
        read_file_list(folder / "rgb.txt"),
        read_file_list(folder / "depth.txt"),
        read_groundtruth(folder / "groundtruth.txt"),
    )


def associate(first_ns, second_ns, max_difference_s: float = MAX_DIFFERENCE_S) -> list[tuple[int, int]]:
    """Index pairs (i, j) as TUM's associate.py pairs two stamp lists (offset 0): every pair
    closer than max_difference is a candidate; the closest candidates are taken first, each
    stamp at most once; the pairs come back in the order of the first list."""
    a, b = np.asarray(first_ns, np.int64), np.asarray(second_ns, np.int64)
    limit = int(round(max_difference_s * 1e9))
    order = np.argsort(b, kind="stable")
    sb = b[order]
    candidates = []
    for i, s in enumerate(a):
        lo, hi = np.searchsorted(sb, s - limit, "right"), np.searchsorted(sb, s + limit, "left")
        candidates += [(abs(int(s) - int(sb[k])), i, int(order[k])) for k in range(lo, hi)]
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in sorted(candidates):
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def camera_for(folder: Path, choice: str = "auto"):
    """The colour camera's CameraModel: from the sequence name (rgbd_dataset_freiburg1_xyz ->
    fr1) when `choice` is auto, else fr1/fr2/fr3/ros."""
    from yowo_common.camera import CameraModel

    if choice == "auto":
        m = re.search(r"freiburg([123])|(?<![a-z0-9])fr([123])(?![0-9])", folder.resolve().name.lower())
        if not m:
            raise TumImportError(
                f"{folder}: cannot tell the Kinect from the folder name (expected freiburg1/2/3 or "
                "fr1/2/3 in it); give --camera fr1|fr2|fr3|ros or --intrinsics"
            )
        choice = f"fr{m.group(1) or m.group(2)}"
    if choice not in INTRINSICS:
        raise TumImportError(f"unknown camera '{choice}' (auto, {', '.join(INTRINSICS)})")
    (fx, fy, cx, cy), dist = INTRINSICS[choice]
    return choice, CameraModel(640, 480, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.array(dist))


def _read_png(path: Path, depth: bool) -> np.ndarray:
    import cv2

    if not path.is_file():
        raise TumImportError(f"{path}: missing (listed in {'depth' if depth else 'rgb'}.txt)")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise TumImportError(f"{path}: not a readable image")
    if depth and (img.ndim != 2 or img.dtype != np.uint16):
        raise TumImportError(
            f"{path}: a TUM depth image is a 16-bit single-channel PNG; this one is "
            f"{img.dtype} with {1 if img.ndim == 2 else img.shape[2]} channel(s)"
        )
    if not depth and (img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8):
        raise TumImportError(
            f"{path}: a TUM colour image is an 8-bit 3-channel PNG; this one is {img.dtype} "
            f"with {1 if img.ndim == 2 else img.shape[2]} channel(s)"
        )
    return img


@dataclass(kw_only=True)
class ImportSummary:
    bag: Path
    camera: str
    frames: int
    rgb_unmatched: int
    depth_unmatched: int
    gt_poses: int
    duration_s: float


def import_tum(
    folder,
    bag,
    camera: str = "auto",
    intrinsics=None,
    distortion=None,
    max_difference_s: float = MAX_DIFFERENCE_S,
    max_frames: int | None = None,
    progress=None,
) -> ImportSummary:
    """Write the sequence as a recording: per associated colour/depth pair, both on the colour
    frame's stamp (the association decides the pair; the ego mapper pairs by stamp) -- colour
    as the PNG file's bytes (lossless, no re-encoding), depth as compressedDepth in mm -- with
    its CameraInfo; every ground-truth pose on /gt/ego/pose at its own mocap stamp (the
    evaluation associates by nearest stamp, as TUM's evaluate_ate does). `intrinsics`
    (fx, fy, cx, cy) and `distortion` (k1 k2 p1 p2 k3) override the table's."""
    from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
    from sensor_msgs.msg import CompressedImage
    from std_msgs.msg import Header

    from yowo_common import topics
    from yowo_common.camera import CameraModel
    from yowo_common.ros.bag import BagError, BagWriter
    from yowo_common.rosconv import encode_depth_png, model_to_camera_info, ns_to_time

    seq = read_sequence(folder)
    try:
        name, cam = camera_for(seq.folder, camera)
    except TumImportError:
        if intrinsics is None:
            raise
        name, cam = "custom", None  # an unknown folder name with the intrinsics given
    if intrinsics is not None or distortion is not None:
        K = (
            cam.K
            if intrinsics is None
            else np.array([[intrinsics[0], 0, intrinsics[2]], [0, intrinsics[1], intrinsics[3]], [0, 0, 1.0]])
        )
        D = (cam.D if cam is not None else np.zeros(5)) if distortion is None else np.asarray(distortion, float)
        cam, name = CameraModel(640, 480, K, D), f"{name} with overrides"
    pairs = associate([s for s, _ in seq.rgb], [s for s, _ in seq.depth], max_difference_s)
    if not pairs:
        raise TumImportError(
            f"{seq.folder}: no colour image has a depth image within {max_difference_s} s "
            "(rgb.txt and depth.txt do not belong to one recording?)"
        )
    pairs = pairs[:max_frames] if max_frames else pairs
    bag = Path(bag)
    if bag.exists():
        raise TumImportError(f"{bag}: already exists; refusing to overwrite a recording")
    written = 0
    try:
        with BagWriter(bag) as out:
            for k, (i, j) in enumerate(pairs):
                stamp, rgb_file = seq.rgb[i]
                color_path, depth_path = seq.folder / rgb_file, seq.folder / seq.depth[j][1]
                rgb = _read_png(color_path, depth=False)
                raw_depth = _read_png(depth_path, depth=True)
                for what, img, p in (("colour", rgb, color_path), ("depth", raw_depth, depth_path)):
                    if img.shape[:2] != (cam.height, cam.width):
                        raise TumImportError(
                            f"{p}: {img.shape[1]}x{img.shape[0]} {what} image; the camera is {cam.width}x{cam.height}"
                        )
                header = Header(stamp=ns_to_time(stamp), frame_id=EGO_FRAME)
                out.write(
                    topics.EGO_COLOR[1],
                    CompressedImage(header=header, format="rgb8; png compressed bgr8", data=color_path.read_bytes()),
                    stamp,
                )
                depth_m = np.where(raw_depth > 0, raw_depth / DEPTH_FACTOR, np.nan)
                out.write(topics.EGO_DEPTH[1], encode_depth_png(depth_m, header), stamp)
                out.write(topics.EGO_INFO, model_to_camera_info(cam, header), stamp)
                written += 1
                if progress:
                    progress(k + 1, len(pairs))
            first, last = seq.rgb[pairs[0][0]][0], seq.rgb[pairs[-1][0]][0]
            for s, (tx, ty, tz, qx, qy, qz, qw) in seq.groundtruth:
                out.write(
                    topics.GT_EGO_POSE,
                    PoseStamped(
                        header=Header(stamp=ns_to_time(s), frame_id=GT_FRAME),
                        pose=Pose(position=Point(x=tx, y=ty, z=tz), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)),
                    ),
                    s,
                )
    except BagError as exc:
        raise TumImportError(str(exc)) from None
    except TumImportError:
        import shutil

        shutil.rmtree(bag, ignore_errors=True)  # no half recording left behind
        raise
    return ImportSummary(
        bag=bag,
        camera=name,
        frames=written,
        rgb_unmatched=len(seq.rgb) - len(pairs),
        depth_unmatched=len(seq.depth) - len(pairs),
        gt_poses=len(seq.groundtruth),
        duration_s=(last - first) / 1e9,
    )


def cmd_import_tum(args) -> int:
    from .progress import with_progress

    s = with_progress(
        lambda progress: import_tum(
            args.sequence,
            args.output,
            args.camera,
            args.intrinsics,
            args.distortion,
            args.max_difference,
            args.max_frames,
            progress=progress,
        )
    )
    print(
        f"wrote {s.bag}: {s.frames} colour/depth pairs over {s.duration_s:.1f} s (camera {s.camera}; "
        f"{s.rgb_unmatched} colour and {s.depth_unmatched} depth images without a partner within "
        f"{args.max_difference} s left out), {s.gt_poses} ground-truth poses on /gt/ego/pose"
    )
    print(
        f"next: yowo run {s.bag} -o RESULTS   (ego-only: the recording has no CMCs), then "
        f"yowo eval RESULTS --bag {s.bag}"
    )
    return 0


def add_verbs(verbs) -> None:
    p = verbs.add_parser(
        "import-tum", help="convert a TUM RGB-D sequence folder into a recording (ego topics and ground truth)"
    )
    p.add_argument("sequence", help="the sequence folder (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt)")
    p.add_argument("-o", "--output", required=True, help="the rosbag2 (MCAP) recording to write")
    p.add_argument(
        "--camera",
        default="auto",
        choices=("auto", *INTRINSICS),
        help="colour camera calibration: the TUM table's fr1/fr2/fr3 or the ROS default; auto: from the folder name",
    )
    p.add_argument(
        "--intrinsics",
        type=float,
        nargs=4,
        metavar=("FX", "FY", "CX", "CY"),
        help="override the table's focal lengths and principal point [px]",
    )
    p.add_argument(
        "--distortion",
        type=float,
        nargs=5,
        metavar=("K1", "K2", "P1", "P2", "K3"),
        help="override the table's plumb_bob distortion coefficients",
    )
    p.add_argument(
        "--max-difference",
        type=float,
        default=MAX_DIFFERENCE_S,
        help="largest colour/depth stamp difference of a pair [s] (associate.py's default)",
    )
    p.add_argument("--max-frames", type=int, help="import only the first N pairs")
    p.set_defaults(func=cmd_import_tum)
