"""CCTV footage as video files beside an ego recording: which file is which camera, when it
started, and its frames as the Image messages a recorded camera would have given. An NVR
exports video with a wall-clock start time that can be seconds off; the clock-offset
estimation finds the rest (the planner widens its search for video cameras)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import yaml

from yowo_common import topics


def video_rules(rules, list_file: str = "") -> list[str]:
    """The NAME=FILE[@START] rules of the configuration: `rules` and those of a video list."""
    return [*rules, *(video_list(list_file) if list_file else [])]


class VideoError(ValueError):
    """A video input that cannot be used; the message names the file or the rule."""


@dataclass(frozen=True, kw_only=True)
class VideoInput:
    camera: str
    path: Path
    start_ns: int  # the first frame's time on the recording's clock (as given or from metadata)
    start_from: str  # where start_ns came from
    frames: int
    duration_s: float
    width: int
    height: int

    @property
    def rule(self) -> str:
        """NAME=FILE@START with the start as found (what the replay is given)."""
        return f"{self.camera}={self.path}@{self.start_ns / 1e9:.9f}"

    @property
    def topic(self) -> str:
        """The image topic its frames are played on."""
        return topics.cmc_image_topics(self.camera)[0]


_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def parse_video_rule(rule: str) -> tuple[str, Path, str]:
    """(camera, file, start text or '') of NAME=FILE[@START]; START is seconds since the epoch
    or an ISO 8601 time with its zone."""
    name, sep, rest = str(rule).partition("=")
    if not sep or not rest:
        raise VideoError(f"--cmc-video {rule} (inputs.videos): expected CAMERA=FILE[@START]")
    if not _NAME.match(name):
        raise VideoError(
            f"video '{rule}': camera name '{name}' must be letters, digits and '_', starting with a "
            f"letter (e.g. {re.sub(r'[^A-Za-z0-9_]', '_', name).lstrip('0123456789_') or 'cam1'})"
        )
    file, _, start = rest.rpartition("@") if "@" in rest else (rest, "", "")
    return name, Path(file), start


def video_list(path: str) -> list[str]:
    """NAME=FILE[@START] rules from a YAML list of {name, file, start} (start optional); files
    relative to the list's folder."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise VideoError(f"{path}: cannot read the video list: {exc}") from exc
    entries = doc.get("videos", doc) if isinstance(doc, dict) else doc
    if not isinstance(entries, list) or not all(isinstance(e, dict) and "name" in e and "file" in e for e in entries):
        raise VideoError(f"{path}: expected a list of {{name, file, start}} entries (start optional)")
    return [
        f"{e['name']}={(p.parent / str(e['file'])) if not Path(str(e['file'])).is_absolute() else e['file']}"
        + (f"@{e['start']}" if e.get("start") not in (None, "") else "")
        for e in entries
    ]


def _epoch_ns(text: str, where: str) -> int:
    try:
        return int(round(float(text) * 1e9))
    except ValueError:
        pass
    try:
        t = datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError as exc:
        raise VideoError(f"{where}: start '{text}' is neither seconds since the epoch nor an ISO 8601 time") from exc
    if t.tzinfo is None:
        raise VideoError(f"{where}: start '{text}' has no time zone (add Z or +hh:mm)")
    return int(round(t.astimezone(timezone.utc).timestamp() * 1e9))


def probe_video(rule: str) -> VideoInput:
    """A video input, its start from the rule or else from the file's creation_time; VideoError
    naming the file when it cannot be decoded or has no start."""
    import av

    camera, path, start = parse_video_rule(rule)
    if not path.is_file():
        raise VideoError(f"video of camera '{camera}': no such file {path}")
    try:
        with av.open(str(path)) as container:
            if not container.streams.video:
                raise VideoError(f"{path}: holds no video stream")
            stream = container.streams.video[0]
            first = next(container.decode(stream), None)
            if first is None:
                raise VideoError(f"{path}: no frame could be decoded")
            frames = stream.frames or 0
            duration_s = (
                float(stream.duration * stream.time_base)
                if stream.duration
                else container.duration / 1e6
                if container.duration
                else 0.0
            )
            created = container.metadata.get("creation_time", "") or stream.metadata.get("creation_time", "")
            size = (first.width, first.height)
    except av.error.FFmpegError as exc:
        raise VideoError(f"{path}: cannot decode the video ({exc})") from exc
    if start:
        start_ns, start_from = _epoch_ns(start, f"video {path}"), "given"
    elif created:
        start_ns, start_from = _epoch_ns(created, f"{path} creation_time"), f"the file's creation_time {created}"
    else:
        raise VideoError(
            f"{path}: no start time in its metadata; give it as {camera}={path}@START "
            "(seconds since the epoch or ISO 8601)"
        )
    if not frames and duration_s:
        frames = int(round(duration_s * float(stream.average_rate or 0)))
    return VideoInput(
        camera=camera,
        path=path,
        start_ns=start_ns,
        start_from=start_from,
        frames=frames,
        duration_s=duration_s,
        width=size[0],
        height=size[1],
    )


def video_images(video: VideoInput) -> Iterator[tuple[int, object]]:
    """(stamp [ns], sensor_msgs/Image rgb8) of every frame: the start plus its presentation time."""
    import av
    from std_msgs.msg import Header

    from yowo_common.rosconv import encode_raw, ns_to_time

    decoded = 0
    try:
        with av.open(str(video.path)) as container:
            stream = container.streams.video[0]
            t0 = None
            for frame in container.decode(stream):
                if frame.pts is None:
                    continue
                t = float(frame.pts * stream.time_base)
                t0 = t if t0 is None else t0
                stamp_ns = video.start_ns + int(round((t - t0) * 1e9))
                header = Header(stamp=ns_to_time(stamp_ns), frame_id=f"{video.camera}_optical_frame")
                yield stamp_ns, encode_raw(frame.to_ndarray(format="rgb24"), "rgb8", header)
                decoded += 1
    except av.error.FFmpegError as exc:
        raise VideoError(f"{video.path}: decoding stopped after {decoded} frames ({exc})") from exc
