from yowo_eval.graph_bench import BEGIN, END, keep_section, replace_section, speed_markdown

CASE = {
    "bag": "small_normal_s0",
    "source": "keypoints",
    "exit": 0,
    "recording_s": 40.0,
    "wall_s": 66.0,
    "ratio": 1.65,
    "registration_pos_avg_m": 0.0123,
    "registration_rot_avg_deg": 0.201,
    "ego_ate_m": 0.0031,
    "peak_memory_mb": 1234.4,
    "resources": {
        "keypoint_tracker_a": {"cpu_s": 2.0, "wall_s": 60.0, "peak_rss_mb": 210.0},
        "keypoint_tracker_b": {"cpu_s": 4.0, "wall_s": 62.0, "peak_rss_mb": 230.0},
        "ego_mapper": {"cpu_s": 30.5, "wall_s": 63.0, "peak_rss_mb": 800.0},
    },
}


def test_the_table_has_the_ratio_and_each_stage_once(tmp_path):
    md = speed_markdown([CASE], "yowo bench-graph --preset small")
    row = next(line for line in md.splitlines() if line.startswith("| small_normal_s0"))
    assert "| 1.65 | 66 | 40 | 0.0123 / 0.201 | 0.0031 | 1234 |" in row
    # Trackers: mean CPU and lifetime, the largest peak.
    assert "keypoint_tracker (each process): 3.0 / 61 / 230" in row and "ego_mapper: 30.5 / 63 / 800" in row
    # The graph's peak and the stages that held most of it then (trackers summed).
    held = speed_markdown(
        [
            {
                **CASE,
                "peak_memory_by_process_mb": {
                    "keypoint_tracker_a": 60.0,
                    "keypoint_tracker_b": 70.0,
                    "ego_mapper": 700.0,
                    "supervisor": 40.0,
                    "fusion": 364.4,
                },
            }
        ],
        "c",
    )
    assert "| 1234<br>ego_mapper 700<br>fusion 364<br>keypoint_trackers 130 |" in held, held
    failed = speed_markdown([{**CASE, "exit": 1}], "c")
    assert "failed (exit 1)" in failed


def test_the_section_is_replaced_in_place_and_survives_a_rerender(tmp_path):
    doc = tmp_path / "BENCHMARKS.md"
    doc.write_text("# BENCHMARKS\n\nold tables\n")
    replace_section(doc, speed_markdown([CASE], "first"))
    replace_section(doc, speed_markdown([{**CASE, "ratio": 0.45}], "second"))
    text = doc.read_text()
    assert text.count(BEGIN) == 1 and "second" in text and "first" not in text and "old tables" in text
    rerendered = keep_section(text, "# BENCHMARKS\n\nnew tables\n")
    assert "new tables" in rerendered and "old tables" not in rerendered and "| 0.45 |" in rerendered
    assert rerendered.index(BEGIN) < rerendered.index(END)


TOPIC = {"messages": 10, "queue_wait_ms": {"p50": 1.0, "p95": 2.0, "max": 3.0}, "handling_s": 0.5}
TIMING = {
    "ego_mapper": {
        "spawned_s": 0.1,
        "created_s": 3.0,
        "finalize_start_s": 40.0,
        "finalize_end_s": 52.5,
        "topics": {
            "/a": {**TOPIC, "first_s": 9.0, "last_s": 38.0},
            "/b": {**TOPIC, "queue_wait_ms": {"p50": 1, "p95": 900.0, "max": 950.0}, "first_s": 9.1, "last_s": 39.0},
        },
    },
    "replay": {
        "spawned_s": 0.2,
        "created_s": 2.0,
        "announced_s": 6.1,
        "playing_s": 8.9,
        "played_s": 37.0,
        "seconds": {"ack_wait /a": 1.5, "ack_wait /b": 2.0},
        "topics": {},
    },
}


def test_the_timeline_says_when_each_stage_worked_and_how_long_inputs_waited():
    md = speed_markdown([{**CASE, "timing": TIMING}], "c")
    ego = next(line for line in md.splitlines() if "| ego_mapper |" in line)
    # Worst topic's p95 wait, callbacks summed over topics, finalisation's length.
    assert "| 0.1 / 3.0 | 9.0 / 39.0 | 12.5 | 52.5 | 900 | 1.0 |" in ego, ego
    replay = next(line for line in md.splitlines() if "| replay |" in line)
    assert "stages announced 6.1, playing 8.9 / done 37.0" in replay and "held back 3.5 s" in replay


def test_hand_written_notes_inside_the_section_survive_a_new_table(tmp_path):
    from yowo_eval.graph_bench import NOTES_BEGIN, NOTES_END

    doc = tmp_path / "BENCHMARKS.md"
    replace_section(doc, speed_markdown([CASE], "first"))
    text = doc.read_text().replace(END, f"{NOTES_BEGIN}\nthe profile says X\n{NOTES_END}\n{END}")
    doc.write_text(text + "after\n")
    replace_section(doc, speed_markdown([{**CASE, "ratio": 0.45}], "second"))
    text = doc.read_text()
    assert "the profile says X" in text and "| 0.45 |" in text and "first" not in text and text.endswith("after\n")
    assert text.index(BEGIN) < text.index(NOTES_BEGIN) < text.index(END)
