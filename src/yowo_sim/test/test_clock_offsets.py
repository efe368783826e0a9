"""Unsynchronised CMC clocks (preset option cmc_clock_offset_s): a CMC's messages carry its
own clock, the ground truth names the offsets, and nothing else of the recording changes."""

from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import pytest
from mcap.reader import make_reader

from yowo_common.ros.bag import list_topics, read_messages
from yowo_common.rosconv import message_fields, stamp_to_ns
from yowo_common.topics import GT_AGENT_KEYPOINTS, gt_cmc_clock_offset_topic, parse_cmc_topic
from yowo_sim.capture import generate
from yowo_sim.presets import get_preset

SEED = 4


@pytest.fixture(scope="module")
def synced_and_offset(tmp_path_factory):
    root = tmp_path_factory.mktemp("clock")
    preset = replace(get_preset("tiny"), cmc_images=False)
    generate(preset, SEED, root / "synced")
    summary = generate(replace(preset, cmc_clock_offset_s=1.0), SEED, root / "offset")
    return root / "synced", root / "offset", summary


def _by_topic(path):
    out = defaultdict(list)
    for topic, log_ns, msg in read_messages(path):
        out[topic].append((log_ns, msg))
    return out


def test_cmc_messages_carry_their_own_clock(synced_and_offset):
    synced, offset, summary = synced_and_offset
    a, b = _by_topic(synced), _by_topic(offset)
    truth = {c.name: b[gt_cmc_clock_offset_topic(c.name)][0][1].data for c in summary.cmcs}
    assert all(abs(d) <= 1.0 for d in truth.values())
    assert min(abs(d) for d in truth.values()) > 0.01 and len(set(truth.values())) == len(truth)
    assert not any(t.startswith("/gt/cmc/") and t.endswith("/clock_offset") for t in a)  # synchronised: no topic
    assert set(b) - set(a) == {gt_cmc_clock_offset_topic(c.name) for c in summary.cmcs}
    for topic, msgs in a.items():
        assert len(b[topic]) == len(msgs), topic
        shift = round(truth[parse_cmc_topic(topic)[0]] * 1e9) if parse_cmc_topic(topic) else 0
        for (log_a, msg_a), (log_b, msg_b) in zip(msgs, b[topic]):
            assert log_b - log_a == shift, topic
            if hasattr(msg_b, "header"):
                assert stamp_to_ns(msg_b.header.stamp) - stamp_to_ns(msg_a.header.stamp) == shift, topic
                msg_b.header.stamp = msg_a.header.stamp
            # Same walk, same noise: only the stamps differ.
            assert message_fields(msg_a) == message_fields(msg_b), topic
    # The agent's ground truth stays on the reference (ego) clock.
    assert [s for s, _ in a[GT_AGENT_KEYPOINTS]] == [s for s, _ in b[GT_AGENT_KEYPOINTS]]


def test_offset_recording_is_a_valid_bag(synced_and_offset):
    _, offset, _ = synced_and_offset
    log_times, per_topic = [], defaultdict(list)
    for topic, log_ns, _ in read_messages(offset):
        log_times.append(log_ns)
        per_topic[topic].append(log_ns)
    assert log_times == sorted(log_times)  # the reader merges the out-of-order writes
    for topic, stamps in per_topic.items():
        assert len(stamps) == 1 or all(x < y for x, y in zip(stamps, stamps[1:])), topic
    counts = {t.name: t.count for t in list_topics(offset)}
    assert counts == {t: len(s) for t, s in per_topic.items()}
    (mcap_file,) = Path(offset).glob("*.mcap")
    with open(mcap_file, "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=True)]
    assert times == log_times
