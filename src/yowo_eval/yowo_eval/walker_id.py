"""Walker identification: whose keypoints each camera's tracker handed on, frame by frame,
against the simulator's ground truth of every person (the walker on /gt/agent/keypoints,
bystanders on /gt/bystanders/keypoints). A frame belongs to the person whose true head
top and ground point project nearest to its ids 0 and 1."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from yowo_common import topics
from yowo_common.camera import CameraModel

from .ground_truth import GroundTruth, read_ground_truth

IDS = (0, 1)  # head top, ground point: every detector's, derived from the pose model's joints


@dataclass(kw_only=True)
class CameraIdentification:
    camera: str
    frames: int  # frames the tracker handed on
    walker: int  # of them, the walker's
    bystander: int  # of them, a bystander's
    walker_in_view: int  # of the camera's images, those whose true walker head top and ground point are in it

    @property
    def accuracy(self) -> float | None:
        return self.walker / self.frames if self.frames else None


def people_by_stamp(bag) -> dict[int, np.ndarray]:
    """Truth stamp -> (P, 2, 3) head top and ground point of every person in the simulator's
    frame, the walker first."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import points_to_array, stamp_to_ns

    walker, others = {}, {}
    for topic, _, msg in read_messages(bag, [topics.GT_AGENT_KEYPOINTS, topics.GT_BYSTANDER_KEYPOINTS]):
        pts = points_to_array([p.position for p in msg.poses])
        stamp = stamp_to_ns(msg.header.stamp)
        if topic == topics.GT_AGENT_KEYPOINTS:
            walker[stamp] = pts[list(IDS)]
        else:
            others[stamp] = pts.reshape(-1, 2, 3)
    return {s: np.concatenate([w[None], others.get(s, np.zeros((0, 2, 3)))]) for s, w in walker.items()}


def identify(
    bag,
    frames: dict[str, list],
    models: dict[str, CameraModel],
    image_stamps_ns: dict[str, list[int]],
    gt: GroundTruth | None = None,
) -> list[CameraIdentification]:
    """`frames`: camera -> its handed-on KeypointFrames; `image_stamps_ns`: camera -> the
    stamps of its images (both on the camera's clock); `models`: intrinsics."""
    gt = gt or read_ground_truth(bag)
    people = people_by_stamp(bag)
    stamps = np.array(sorted(people))
    out = []
    for name in sorted(frames):
        cam = models[name]
        T_cam_map = np.linalg.inv(gt.cameras[name])
        T_cam_sim = T_cam_map @ gt.T_map_sim

        def at(stamp_ns: int) -> np.ndarray | None:
            truth = gt.true_time_ns(name, stamp_ns)  # noqa: B023 (this camera's, used in its loop)
            k = int(np.clip(np.searchsorted(stamps, truth), 0, len(stamps) - 1))
            return people[int(stamps[k])] if abs(int(stamps[k]) - truth) <= 1_000_000 else None

        def project(points_sim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return cam.project((T_cam_sim[:3, :3] @ points_sim.T).T + T_cam_sim[:3, 3])  # noqa: B023

        walker = bystander = 0
        for f in frames[name]:
            pts = at(f.stamp_ns)
            seen = [i for i, kid in enumerate(IDS) if kid in f.ids]
            if pts is None or not seen:
                continue
            uv = np.array([f.uv[list(f.ids).index(IDS[i])] for i in seen])
            proj = project(pts[:, seen].reshape(-1, 3))[0]
            d = np.linalg.norm(proj.reshape(len(pts), len(seen), 2) - uv, axis=2).mean(axis=1)
            walker += int(np.argmin(d)) == 0
            bystander += int(np.argmin(d)) != 0
        in_view = 0
        for s in image_stamps_ns.get(name, []):
            pts = at(s)
            if pts is not None:
                uv, in_front = project(pts[0])
                in_view += bool(in_front.all() and cam.in_image(uv).all())
        out.append(
            CameraIdentification(
                camera=name,
                frames=walker + bystander,
                walker=walker,
                bystander=bystander,
                walker_in_view=in_view,
            )
        )
    return out


def identify_run(results_dir, bag) -> list[CameraIdentification]:
    """The identification of a finished run: the keypoints its result.mcap recorded."""
    from pathlib import Path

    from yowo_cmc.keypoint_input import frame_from_msg
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import camera_info_to_model, stamp_to_ns

    frames: dict[str, list] = {}
    for topic, _, msg in read_messages(Path(results_dir) / "result.mcap"):
        name = topic.split("/")[3] if topic.startswith("/yowo/cmc/") and topic.endswith("/agent_keypoints") else ""
        if name:
            frames.setdefault(name, []).append(frame_from_msg(msg))
    models, image_stamps = {}, {}
    for topic, _, msg in read_messages(bag, [topics.cmc_info_topic(n) for n in frames]):
        name = topic.split("/")[2]
        models.setdefault(name, camera_info_to_model(msg))
        image_stamps.setdefault(name, []).append(stamp_to_ns(msg.header.stamp))  # one per image
    return identify(bag, frames, models, image_stamps)
