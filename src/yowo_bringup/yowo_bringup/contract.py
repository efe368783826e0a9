"""The input data contract of shared/DESIGN.md §2: which topics a recording
must/may hold, and discovery of the ego camera and the CMCs from topic names."""
from __future__ import annotations

from dataclasses import dataclass, field

from yowo_common.ros.bag import BagTopic, list_topics, recording_damage

from yowo_common.topics import (EGO_COLOR, EGO_DEPTH, EGO_INFO, GT_PREFIX, cmc_image_topics,  # noqa: F401
                                cmc_info_topic, cmc_keypoints_topic, parse_cmc_topic)


@dataclass
class RecordingInputs:
    """What a recording offers YOWO, and what is wrong with it."""

    topics: list[BagTopic]
    has_ego: bool
    cmc_names: list[str]
    has_ground_truth: bool
    problems: list[str] = field(default_factory=list)


def discover_inputs(bag) -> RecordingInputs:
    topics = list_topics(bag)
    by_name = {t.name: t for t in topics}
    problems = [d for d in [recording_damage(bag)] if d]
    if not topics or all(t.count == 0 for t in topics):
        problems.append(f"{bag}: the recording holds no messages")

    def present(name):
        return name in by_name and by_name[name].count > 0

    ego_color = any(present(t) for t in EGO_COLOR)
    ego_depth = any(present(t) for t in EGO_DEPTH)
    has_ego = ego_color and ego_depth and present(EGO_INFO)
    if not has_ego:
        missing = [what for what, ok in (("colour " + " or ".join(EGO_COLOR), ego_color),
                                         ("depth " + " or ".join(EGO_DEPTH), ego_depth),
                                         (EGO_INFO, present(EGO_INFO))) if not ok]
        problems.append(f"ego camera incomplete: missing {'; '.join(missing)}")

    kinds: dict[str, set[str]] = {}
    for t in topics:
        cmc = parse_cmc_topic(t.name)
        if cmc and t.count > 0:
            kinds.setdefault(cmc[0], set()).add(cmc[1].split("/")[0])
    cmc_names = []
    for name in sorted(kinds):
        if "camera_info" not in kinds[name]:
            problems.append(f"CMC '{name}': no {cmc_info_topic(name)}; the camera is skipped")
        elif not kinds[name] & {"image_raw", "agent_keypoints"}:
            problems.append(f"CMC '{name}': neither images nor agent keypoints; the camera is skipped")
        else:
            cmc_names.append(name)
    has_gt = any(t.name.startswith(GT_PREFIX) for t in topics)
    return RecordingInputs(topics, has_ego, cmc_names, has_gt, problems)
