"""Generate a synthetic YOWO recording: scene, CMCs, the agent's walk, rendered
ego RGB-D and CMC images, simulated keypoints and ground truth, as an MCAP
rosbag2 that follows docs/design.md §3."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point32, Polygon, PolygonStamped, Pose, PoseArray, PoseStamped
from std_msgs.msg import Float64, Header, String

from yowo_common import topics
from yowo_common.camera import CameraModel
from yowo_common.ros.bag import BagWriter
from yowo_common.rosconv import (
    array_to_points,
    depth_to_mm,
    encode_color_jpeg,
    encode_depth_png,
    encode_raw,
    matrix_to_pose,
    model_to_camera_info,
    ns_to_time,
)
from yowo_msgs.msg import AgentKeypoints, Keypoint2D

from .body import agent_keypoints_3d, agent_mesh
from .bystanders import GT_KEYPOINT_IDS, Bystander, info_yaml, plan_bystanders
from .deficient import plan_deficient_walk, truth_yaml
from .detector import detect
from .follow import FollowWalk
from .imu import ImuData, bias_message, calibration_messages, imu_message, simulate_imu
from .presets import CapturePreset, DepthNoise
from .render import Renderer
from .rig import Cmc, place_cmc
from .scene import Scene, build_scene
from .walk import FloorRoutes, Walk, plan_walk

START_NS = 1_700_000_000 * 10**9  # recordings start at a fixed epoch: deterministic stamps
EGO_FRAME = "ego_optical_frame"


@dataclass(kw_only=True)
class CaptureSummary:
    path: Path
    duration_s: float
    ego_frames: int
    cmc_frames: int
    cmc_frames_with_agent: int
    cmcs: list[Cmc]
    render_seconds: float
    rendered_frames: int
    imu_samples: int = 0
    bystanders: int = 0


def place_cmcs(scene: Scene, preset: CapturePreset, rng: np.random.Generator) -> list[Cmc]:
    if len(preset.cmcs_per_room) > len(scene.rooms):
        raise ValueError(
            f"preset '{preset.name}' wants cameras in {len(preset.cmcs_per_room)} rooms; "
            f"the scene has {len(scene.rooms)}"
        )
    cmcs = []
    for room, count in zip(scene.rooms, preset.cmcs_per_room):
        for _ in range(count):
            cmcs.append(place_cmc(f"cam{len(cmcs):02d}", room, room.ceiling_height, preset.cmc, rng))
    return cmcs


def apply_depth_noise(depth: np.ndarray, model: DepthNoise, rng: np.random.Generator) -> np.ndarray:
    z = depth.copy()
    z[(z < model.min_m) | (z > model.max_m)] = np.nan
    z += rng.normal(size=z.shape).astype(np.float32) * (model.sigma_a_m + model.sigma_b * (z - 0.4) ** 2)
    jump = np.zeros(z.shape, bool)
    jump[:, 1:] |= np.abs(np.diff(depth, axis=1)) > model.edge_dropout_m
    jump[1:, :] |= np.abs(np.diff(depth, axis=0)) > model.edge_dropout_m
    z[jump | (rng.random(z.shape) < model.dropout)] = np.nan
    return z


def add_image_noise(rgb: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    if sigma <= 0:
        return rgb
    return np.clip(rgb + rng.normal(0, sigma, rgb.shape), 0, 255).astype(np.uint8)


class _Recorder:
    """Encodes images the way the preset asks and writes them with CameraInfo."""

    def __init__(self, bag: BagWriter, preset: CapturePreset):
        self.bag, self.preset = bag, preset

    def color(
        self,
        image_topics: tuple[str, str],
        info_topic: str,
        rgb: np.ndarray,
        cam: CameraModel,
        header: Header,
        stamp: int,
    ):
        """`image_topics`: (raw, compressed) as yowo_common.topics names them."""
        if self.preset.raw_images:
            self.bag.write(image_topics[0], encode_raw(rgb, "rgb8", header), stamp)
        else:
            self.bag.write(image_topics[1], encode_color_jpeg(rgb, header, self.preset.jpeg_quality), stamp)
        self.bag.write(info_topic, model_to_camera_info(cam, header), stamp)

    def depth(self, depth: np.ndarray, header: Header, stamp: int):
        if self.preset.raw_images:
            self.bag.write(topics.EGO_DEPTH[0], encode_raw(depth_to_mm(depth), "16UC1", header), stamp)
        else:
            self.bag.write(topics.EGO_DEPTH[1], encode_depth_png(depth, header), stamp)


def _schedule(duration_s: float, preset: CapturePreset, n_cmc: int, rng, start_ns: int) -> list[tuple[int, str, int]]:
    """(stamp_ns, kind, index) for every ego and CMC frame, in time order; each CMC
    runs on its own clock phase (views are not simultaneous)."""
    events = [(start_ns + int(round(t * 1e9)), "ego", 0) for t in np.arange(0.0, duration_s, 1.0 / preset.ego_hz)]
    for c in range(n_cmc):
        offset = rng.uniform(0, 1.0 / preset.cmc_hz)
        events += [
            (start_ns + int(round(t * 1e9)), "cmc", c) for t in np.arange(offset, duration_s, 1.0 / preset.cmc_hz)
        ]
    return sorted(events)


def agent_in_view(cmc: Cmc, keypoints: dict[int, np.ndarray], margin_px: float = 80.0) -> bool:
    """Whether a person (the agent or a bystander) with these keypoints may show in the
    CMC's image (walls not considered): a frame with nobody in view is the background."""
    uv, ok = cmc.camera.project_world(cmc.T_world_cam, np.array(list(keypoints.values())))
    lo, hi = -margin_px, np.array([cmc.camera.width, cmc.camera.height]) + margin_px
    return bool(np.any(ok & np.all((uv > lo) & (uv < hi), axis=1)))


@dataclass(kw_only=True)
class CaptureSetup:
    """Everything a capture is made of before rendering (deterministic for a seed)."""

    preset: CapturePreset
    scene: Scene
    cmcs: list[Cmc]
    walk: Walk
    ego_camera: CameraModel
    rng: np.random.Generator
    clock_offsets_ns: dict[str, int] = field(default_factory=dict)  # CMC clock - ego clock (preset's option)
    bystanders: list[Bystander] = field(default_factory=list)  # other people walking about (preset's option)
    deficient: list[dict] = field(default_factory=list)  # what the walk made deficient (preset's option)
    start_ns: int = START_NS  # the recording's first stamp (later for a second walk)


def clock_offsets(preset: CapturePreset, seed: int, cmcs: list[Cmc]) -> dict[str, int]:
    """Each CMC's clock offset [ns], uniform in +-cmc_clock_offset_s. A generator of its
    own: the option changes nothing else of the recording (same walk, same noise)."""
    if preset.cmc_clock_offset_s == 0:
        return {}
    rng = np.random.default_rng([seed, 17])
    return {c.name: int(round(rng.uniform(-1, 1) * preset.cmc_clock_offset_s * 1e9)) for c in cmcs}


def build_capture(preset: CapturePreset, seed: int, follow: FollowWalk | None = None) -> CaptureSetup:
    """`follow`: a second walk through the same building, cameras and clocks (follow.py)."""
    rng = np.random.default_rng(seed)
    scene = build_scene(replace(preset.scene, seed=seed))
    cmcs = place_cmcs(scene, preset, rng)
    routes = FloorRoutes(scene.free_space_polygon())
    deficient, start = [], scene.rooms[0].center_xy()  # a second walk starts where the first did
    if follow is not None:
        walk = routes.walk_through([start, *follow.waypoints_xy], [0.0, *follow.pauses_s], preset.walk, rng)
    elif preset.deficient.active:
        walk, deficient = plan_deficient_walk(scene, cmcs, routes.free, start, preset, seed, rng)
    else:
        walk = plan_walk(routes, start, [c.target_xy for c in cmcs], preset.walk, rng)
    # After the agent's walk and from their own generator: nothing of the agent's changes.
    places = [c.target_xy for c in cmcs] + [r.center_xy() for r in scene.rooms]
    bystanders = plan_bystanders(preset.bystanders, routes, places, walk, seed)
    ego_cam = CameraModel.from_fov(preset.ego_width, preset.ego_height, preset.ego_hfov_deg)
    return CaptureSetup(
        preset=preset,
        scene=scene,
        cmcs=cmcs,
        walk=walk,
        ego_camera=ego_cam,
        rng=rng,
        clock_offsets_ns=clock_offsets(preset, seed, cmcs),
        bystanders=bystanders,
        deficient=deficient,
        start_ns=START_NS if follow is None else follow.start_ns,
    )


def generate(
    preset: CapturePreset,
    seed: int,
    out_path,
    progress: Callable[[int, int], None] | None = None,
    follow: FollowWalk | None = None,
) -> CaptureSummary:
    """Render and record the capture of ``preset`` for ``seed`` into the rosbag2 ``out_path``.
    The simulated detector's keypoints (/cmc/<name>/agent_keypoints) are the agent's only,
    as from a detector that already tracks it; bystanders show in the images and in the
    ground truth (/gt/bystanders/...)."""
    setup = build_capture(preset, seed, follow)
    scene, cmcs, walk, ego_cam, rng = setup.scene, setup.cmcs, setup.walk, setup.ego_camera, setup.rng
    start_ns = setup.start_ns
    bystanders = setup.bystanders
    renderer = Renderer(scene)
    render_s, rendered = 0.0, 0

    def render(camera, T, agent=None):
        nonlocal render_s, rendered
        t0 = time.perf_counter()
        out = renderer.render(camera, T, agent=agent)
        render_s += time.perf_counter() - t0
        rendered += 1
        return out

    backgrounds = [render(c.camera, c.T_world_cam) for c in cmcs]
    events = _schedule(walk.duration_s, preset, len(cmcs), rng, start_ns)
    counts = {"ego": 0, "cmc": 0, "agent": 0}
    imu = simulate_imu(walk, preset.imu_params, seed, start_ns) if preset.imu else None
    out_path = Path(out_path)
    with BagWriter(out_path) as bag:
        rec = _Recorder(bag, preset)
        _write_static_ground_truth(bag, scene, cmcs, setup.clock_offsets_ns, start_ns)
        if bystanders:
            bag.write(topics.GT_BYSTANDER_INFO, String(data=info_yaml(bystanders)), start_ns, latched=True)
        if setup.deficient:
            bag.write(topics.GT_DEFICIENT, String(data=truth_yaml(setup.deficient)), start_ns, latched=True)
        imu_writer = _ImuWriter(bag, imu, preset, start_ns) if imu is not None else None
        for n, (stamp, kind, idx) in enumerate(events):
            if imu_writer:
                imu_writer.until(stamp)
            t = (stamp - start_ns) / 1e9
            xy, heading, phase = walk.state_at(t)
            others = [b.keypoints(t) for b in bystanders]
            if kind == "ego":
                T = walk.ego_pose_at(t)
                # The renderer skips whoever is behind the camera or outside its image.
                seen = [b.mesh(t) for b in bystanders] if preset.bystanders_in_ego_view else []
                rgb, depth, _ = render(ego_cam, T, agent=seen or None)
                header = Header(stamp=ns_to_time(stamp), frame_id=EGO_FRAME)
                rec.color(
                    topics.EGO_COLOR,
                    topics.EGO_INFO,
                    add_image_noise(rgb, preset.image_noise, rng),
                    ego_cam,
                    header,
                    stamp,
                )
                rec.depth(apply_depth_noise(depth, preset.depth, rng), header, stamp)
                bag.write(
                    topics.GT_EGO_POSE,
                    PoseStamped(header=Header(stamp=header.stamp, frame_id="map"), pose=matrix_to_pose(T)),
                    stamp,
                )
                counts["ego"] += 1
            else:
                cmc = cmcs[idx]
                kps = agent_keypoints_3d(xy, heading, walk.height_m, phase)
                truth_stamp, stamp = stamp, stamp + setup.clock_offsets_ns.get(cmc.name, 0)  # the CMC's clock
                header = Header(stamp=ns_to_time(stamp), frame_id=f"{cmc.name}_optical_frame")
                visible = agent_in_view(cmc, kps)
                if preset.cmc_images:
                    people = [agent_mesh(xy, heading, walk.height_m, phase)] if visible else []
                    people += [b.mesh(t) for b, k in zip(bystanders, others) if agent_in_view(cmc, k)]
                    rgb = render(cmc.camera, cmc.T_world_cam, people)[0] if people else backgrounds[idx][0]
                    rec.color(
                        topics.cmc_image_topics(cmc.name),
                        topics.cmc_info_topic(cmc.name),
                        add_image_noise(rgb, preset.image_noise, rng),
                        cmc.camera,
                        header,
                        stamp,
                    )
                else:
                    bag.write(topics.cmc_info_topic(cmc.name), model_to_camera_info(cmc.camera, header), stamp)
                det = detect(cmc.camera, cmc.T_world_cam, kps, backgrounds[idx][1], preset.detector, rng)
                if preset.cmc_keypoints:
                    bag.write(
                        topics.cmc_keypoints_topic(cmc.name),
                        AgentKeypoints(
                            header=header,
                            camera_name=cmc.name,
                            keypoints=[
                                Keypoint2D(id=int(i), x=float(u), y=float(v), confidence=float(c))
                                for i, (u, v), c in zip(det.ids, det.uv, det.confidence)
                            ],
                        ),
                        stamp,
                    )
                bag.write(
                    topics.GT_AGENT_KEYPOINTS,
                    PoseArray(
                        header=Header(stamp=ns_to_time(truth_stamp), frame_id="map"),
                        poses=[Pose(position=p) for p in array_to_points([kps[k] for k in sorted(kps)])],
                    ),
                    truth_stamp,
                )
                if bystanders:
                    bag.write(
                        topics.GT_BYSTANDER_KEYPOINTS,
                        PoseArray(
                            header=Header(stamp=ns_to_time(truth_stamp), frame_id="map"),
                            poses=[
                                Pose(position=p)
                                for p in array_to_points([k[i] for k in others for i in GT_KEYPOINT_IDS])
                            ],
                        ),
                        truth_stamp,
                    )
                counts["cmc"] += 1
                counts["agent"] += int(len(det.ids) > 0)
            if progress:
                progress(n + 1, len(events))
        if imu_writer:
            imu_writer.until(None)
    return CaptureSummary(
        path=out_path,
        duration_s=walk.duration_s,
        ego_frames=counts["ego"],
        cmc_frames=counts["cmc"],
        cmc_frames_with_agent=counts["agent"],
        cmcs=cmcs,
        render_seconds=render_s,
        rendered_frames=rendered,
        imu_samples=0 if imu is None else len(imu.stamps_ns),
        bystanders=len(bystanders),
    )


class _ImuWriter:
    """Writes /ego/imu and /gt/ego/imu_bias interleaved with the frames (time order), after
    the latched calibration (/tf_static: ego camera -> IMU; /ego/imu/calibration)."""

    def __init__(self, bag: BagWriter, imu: ImuData, preset: CapturePreset, start_ns: int):
        self.bag, self.imu, self.params, self.next = bag, imu, preset.imu_params, 0
        for topic, msg in calibration_messages(self.params, EGO_FRAME, start_ns).items():
            bag.write(topic, msg, start_ns, latched=True)

    def until(self, stamp_ns: int | None) -> None:
        """Every sample stamped at or before stamp_ns (None: all that are left)."""
        stamps = self.imu.stamps_ns
        end = len(stamps) if stamp_ns is None else int(np.searchsorted(stamps, stamp_ns, side="right"))
        for i in range(self.next, end):
            self.bag.write(topics.EGO_IMU, imu_message(self.imu, i, self.params), int(stamps[i]))
            self.bag.write(topics.GT_EGO_IMU_BIAS, bias_message(self.imu, i, self.params), int(stamps[i]))
        self.next = max(self.next, end)


def _write_static_ground_truth(
    bag: BagWriter, scene: Scene, cmcs: list[Cmc], clock_offsets_ns: dict[str, int], start_ns: int
) -> None:
    header = Header(stamp=ns_to_time(start_ns), frame_id="map")
    for cmc in cmcs:
        bag.write(
            topics.gt_cmc_pose_topic(cmc.name),
            PoseStamped(header=header, pose=matrix_to_pose(cmc.T_world_cam)),
            start_ns,
            latched=True,
        )
    # Only with the option: a synchronised recording stays as it was (no offset topic = 0).
    for name, offset in clock_offsets_ns.items():
        bag.write(topics.gt_cmc_clock_offset_topic(name), Float64(data=offset / 1e9), start_ns, latched=True)
    for poly in scene.floor_polygons:
        msg = PolygonStamped(
            header=header, polygon=Polygon(points=[Point32(x=float(x), y=float(y), z=0.0) for x, y in poly])
        )
        bag.write(topics.GT_FLOOR, msg, start_ns, latched=True)
