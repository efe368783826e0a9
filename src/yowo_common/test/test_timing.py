import yaml

from yowo_common.ros.timing import NodeTiming, relative_to


def test_queue_waits_handling_and_marks_relative_to_the_run(tmp_path):
    t = NodeTiming(created=1000.0)
    s = 1_000_000_000
    for i in range(20):  # received at 1001 + i, handled 5 ms (i < 19) or 500 ms (last) later
        wait = 5_000_000 if i < 19 else 500_000_000
        received = 1001 * s + i * s
        t.received(
            "/a",
            {"source_timestamp": received - 1_000_000, "received_timestamp": received},
            received + wait,
            received + wait + 2_000_000,
        )
    t.marks["finalize_start"] = 1030.0
    t.add_seconds("ack_wait /a", 0.25)
    t.add_seconds("ack_wait /a", 0.5)
    t.write(tmp_path / "n.yaml")
    doc = relative_to(yaml.safe_load((tmp_path / "n.yaml").read_text()), 990.0)
    a = doc["topics"]["/a"]
    assert a["messages"] == 20 and a["queue_wait_ms"]["p50"] == 5.0 and a["queue_wait_ms"]["max"] == 500.0
    assert a["latency_ms"]["p50"] == 6.0 and abs(a["handling_s"] - 0.04) < 1e-9
    assert a["first_s"] == 11.0 and abs(a["last_s"] - 30.5) < 0.01
    assert doc["created_s"] == 10.0 and doc["finalize_start_s"] == 40.0 and doc["seconds"] == {"ack_wait /a": 0.75}
