from yowo_common.streams import StreamCompletion


def test_complete_only_after_upstreams_finish_and_all_messages_arrive():
    s = StreamCompletion({"/a": "replay", "/b": "replay", "/k": "tracker"})
    for _ in range(3):
        s.on_received("/a")
    assert not s.complete
    s.on_upstream_finished("replay", ["/a", "/b", "/other"], [4, 0, 9])
    assert not s.complete and "tracker to finish" in s.waiting_for() and "/a: 3/4" in s.waiting_for()
    s.on_received("/a")
    s.on_upstream_finished("tracker", ["/k"], [2])
    assert not s.complete
    s.on_received("/k")
    s.on_received("/k")
    assert s.complete and s.waiting_for() == "nothing"
