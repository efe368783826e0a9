"""The input data contract of shared/DESIGN.md §2: which topics a recording
must/may hold, and discovery of the ego camera and the CMCs from topic names."""
from __future__ import annotations

from dataclasses import dataclass, field

from yowo_common.ros.bag import BagTopic, list_topics, recording_damage, unknown_type_reason

from yowo_common.topics import (EGO_COLOR, EGO_DEPTH, EGO_INFO, GT_PREFIX, cmc_image_topics,  # noqa: F401
                                cmc_info_topic, cmc_keypoints_topic, parse_cmc_topic)

from .layouts import InputMap, InputParams, map_inputs


@dataclass
class RecordingInputs:
    """What a recording offers YOWO, and what is wrong with it. `map` says which recorded
    topic fills each of YOWO's input names; the other fields speak of input names."""

    topics: list[BagTopic]
    has_ego: bool
    cmc_names: list[str]
    has_ground_truth: bool
    problems: list[str] = field(default_factory=list)
    map: InputMap = field(default_factory=InputMap)

    def count(self, name: str) -> int:
        """Messages recorded for an input name."""
        recorded = self.map.recorded(name)
        return next((t.count for t in self.topics if t.name == recorded), 0)


def discover_inputs(bag, params: InputParams | None = None) -> RecordingInputs:
    """The recording's inputs, found by YOWO's own names, the drivers' layouts and the
    mapping in `params`; InputMapError for a mapping that names a missing topic."""
    params = params or InputParams()
    topics = list_topics(bag)
    problems = [d for d in [recording_damage(bag)] if d]
    if not topics or all(t.count == 0 for t in topics):
        problems.append(f"{bag}: the recording holds no messages")
    problems += [f"{t.name}: skipped, {why}" for t in topics if (why := unknown_type_reason(t.msgtype))]
    readable = [t.name for t in topics if t.count > 0 and not unknown_type_reason(t.msgtype)]
    imap = map_inputs(readable, params.remap, params.ego_namespace)
    problems += imap.problems

    def present(name):
        return name in imap.roles

    ego_color = any(present(t) for t in EGO_COLOR)
    ego_depth = any(present(t) for t in EGO_DEPTH)
    has_ego = ego_color and ego_depth and present(EGO_INFO)
    if not has_ego and not any("ego camera:" in p for p in imap.problems):
        missing = [what for what, ok in (("colour " + " or ".join(EGO_COLOR), ego_color),
                                         ("depth " + " or ".join(EGO_DEPTH), ego_depth),
                                         (EGO_INFO, present(EGO_INFO))) if not ok]
        problems.append(f"ego camera incomplete: missing {'; '.join(missing)} (no driver layout found either: "
                        "map the topics with -r /ego/color/image_raw:=TOPIC, see 'yowo info')")

    kinds: dict[str, set[str]] = {}
    for name in imap.roles:
        cmc = parse_cmc_topic(name)
        if cmc:
            kinds.setdefault(cmc[0], set()).add(cmc[1].split("/")[0])
    cmc_names = []
    for name in sorted(kinds):
        source = imap.recorded(cmc_image_topics(name)[0]) or imap.recorded(cmc_image_topics(name)[1])
        if "camera_info" not in kinds[name]:
            where = f" ({source.rsplit('/image_raw', 1)[0]}/camera_info)" if source else ""
            problems.append(f"CMC '{name}': no {cmc_info_topic(name)}{where}; the camera is skipped")
        elif not kinds[name] & {"image_raw", "agent_keypoints"}:
            problems.append(f"CMC '{name}': neither images nor agent keypoints; the camera is skipped")
        else:
            cmc_names.append(name)
    has_gt = any(t.name.startswith(GT_PREFIX) for t in topics)
    return RecordingInputs(topics, has_ego, cmc_names, has_gt, problems, imap)
