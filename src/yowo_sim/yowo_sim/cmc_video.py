"""A recording's ceiling cameras as an NVR exports them: one video file per camera, written by
OpenCV, with a start time off the recording's clock, and the recording without their images
and keypoints. The list of files (videos.yaml) gives each start as the NVR would: the first
frame's stamp plus the clock error."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import yaml
from std_msgs.msg import Float64

from yowo_common import topics
from yowo_common.ros.bag import BagWriter, list_topics, read_messages
from yowo_common.rosconv import decode_color, stamp_to_ns

FOURCC = "mp4v"  # MPEG-4 Part 2: an encoder every OpenCV build has


def write_cmc_videos(src, dst, video_dir, start_error_s: float = 3.0, no_camera_info: Sequence[str] = ()) -> dict:
    """Write each camera's images of `src` to `video_dir`/<name>.mp4 at its median frame rate and
    `dst` without those images and keypoints (and without the CameraInfo of the cameras in
    `no_camera_info`); every camera's ground-truth clock offset grows by `start_error_s`.
    Returns the videos.yaml content."""
    video_dir = Path(video_dir)
    video_dir.mkdir(parents=True, exist_ok=True)
    present = {t.name: t for t in list_topics(src)}
    cameras = sorted(
        {
            topics.parse_cmc_topic(t)[0]
            for t in present
            if topics.parse_cmc_topic(t) and topics.parse_cmc_topic(t)[1].startswith("image_raw")
        }
    )
    if not cameras:
        raise ValueError(f"{src}: no ceiling camera images to write as videos")
    image_topics = {
        t: topics.parse_cmc_topic(t)[0]
        for t in present
        if topics.parse_cmc_topic(t) and topics.parse_cmc_topic(t)[1].startswith("image_raw")
    }
    stamps = {c: [] for c in cameras}
    for topic, _, msg in read_messages(src, list(image_topics)):
        stamps[image_topics[topic]].append(stamp_to_ns(msg.header.stamp))
    fps = {c: 1e9 / float(np.median(np.diff(sorted(s)))) for c, s in stamps.items()}
    writers, entries = {}, []
    dropped = {*image_topics, *(topics.cmc_keypoints_topic(c) for c in cameras)}
    dropped |= {topics.cmc_info_topic(c) for c in no_camera_info}
    offsets = {c: 0.0 for c in cameras}
    with BagWriter(dst) as bag:
        for topic, log_ns, msg in read_messages(src):
            if topic in image_topics:
                c = image_topics[topic]
                rgb = decode_color(msg)
                if c not in writers:
                    path = video_dir / f"{c}.mp4"
                    writers[c] = cv2.VideoWriter(
                        str(path), cv2.VideoWriter_fourcc(*FOURCC), fps[c], (rgb.shape[1], rgb.shape[0])
                    )
                    if not writers[c].isOpened():
                        raise ValueError(f"{path}: OpenCV cannot write {FOURCC} video here")
                    start = stamp_to_ns(msg.header.stamp) / 1e9 + start_error_s
                    entries.append({"name": c, "file": path.name, "start": round(start, 9)})
                writers[c].write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            elif topic.startswith("/gt/cmc/") and topic.endswith("/clock_offset"):
                offsets[topic.split("/")[3]] = msg.data
            elif topic not in dropped:
                bag.write(topic, msg, log_ns, latched=present[topic].latched)
        first_ns = min(s[0] for s in stamps.values() if s)
        for c in cameras:  # the video's clock: the recorded one plus the NVR's error
            bag.write(
                topics.gt_cmc_clock_offset_topic(c), Float64(data=offsets[c] + start_error_s), first_ns, latched=True
            )
    for w in writers.values():
        w.release()
    doc = {"videos": entries}
    (video_dir / "videos.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return doc
