import yaml

from yowo_bringup.progress import (
    DONE,
    FAILED,
    RUNNING,
    WAITING,
    ProgressLines,
    RunProgress,
    final_step_rates,
    record_final_steps,
)


def test_share_eta_and_states():
    p = RunProgress(
        elapsed_s=30.0,
        played=250,
        total=1000,
        resent=40,
        playing_since_s=10.0,
        stages={"ego_mapper": RUNNING, "keypoint_tracker_a": DONE, "group_sfm": WAITING, "fusion": FAILED},
    )
    assert p.share == 0.25
    # A quarter took 20 s of playing: three quarters take 60 s more.
    assert abs(p.eta_s - 60.0) < 1e-9
    line = p.line()
    assert "replayed  25 % (250/1000 messages)" in line and "40 re-sent" in line and "ETA 60 s" in line
    assert "stages done 2/4" in line and "running: ego_mapper" in line and "waiting: group_sfm" in line


def test_the_eta_follows_the_slowest_stage_past_the_replay():
    stages = {"ego_mapper": RUNNING, "group_sfm": RUNNING}
    # The replay is over after 20 s of playing; the ego mapper has taken in half of it: 20 s more.
    p = RunProgress(
        elapsed_s=30.0,
        played=1000,
        total=1000,
        playing_since_s=10.0,
        stages=stages,
        consumed={"ego_mapper": 0.5, "group_sfm": 1.0},
    )
    assert abs(p.eta_s - 20.0) < 1e-9 and "ETA 20 s" in p.line()
    # Halfway through the replay, a stage a quarter of the way through its share sets the pace.
    p = RunProgress(
        elapsed_s=30.0, played=500, total=1000, playing_since_s=10.0, stages=stages, consumed={"ego_mapper": 0.25}
    )
    assert abs(p.eta_s - 20.0 * (1 - 0.125) / 0.125) < 1e-9
    assert (
        RunProgress(
            elapsed_s=30.0, played=1000, total=1000, playing_since_s=10.0, stages=stages, consumed={"ego_mapper": 1.0}
        ).eta_s
        is None
    )


def test_no_eta_before_playing_or_when_live():
    assert RunProgress(elapsed_s=5.0, played=0, total=1000).eta_s is None
    assert RunProgress(elapsed_s=5.0, played=1000, total=1000, playing_since_s=1.0).eta_s is None  # the replay is over
    live = RunProgress(elapsed_s=5.0, played=0, total=0, stages={"fusion": RUNNING})
    assert live.share is None and live.eta_s is None and "live" in live.line()


def test_lines_are_rate_limited():
    lines = []
    show = ProgressLines(lines.append, period_s=3600.0)
    for i in range(5):
        show(RunProgress(elapsed_s=float(i), played=i, total=10))
    assert len(lines) == 1 and lines[0].startswith("[   0.0 s] replayed")


def test_the_live_bar_fits_80_columns_with_share_eta_and_stages():
    import io

    from rich.console import Console

    from yowo_bringup.progress import ProgressBar

    bar = ProgressBar("run 1234567890ab")
    bar(
        RunProgress(
            elapsed_s=12.0,
            played=500,
            total=1000,
            playing_since_s=1.0,
            resent=3,
            stages={f"keypoint_tracker_cam{i:02d}": "running" for i in range(40)} | {"fusion": "done"},
            consumed={"keypoint_tracker_cam00": 0.5},
        )
    )
    table = bar._bar.make_tasks_table(bar._bar.tasks)
    bar.close()
    console = Console(file=io.StringIO(), width=80)
    console.print(table)
    (row,) = [line for line in console.file.getvalue().splitlines() if line.strip()]
    assert len(row) <= 80 and "━" in row and "50%" in row and "ETA 0:33" in row, row
    assert "1/41 stages, 3 re-sent" in row, row


def test_a_stage_that_receives_nothing_of_a_played_topic_is_named_once():
    from yowo_bringup.run_monitor_node import silent_inputs
    from yowo_msgs.msg import ReplayStatus, StageStatus

    replay = ReplayStatus(topics=["/cmc/a/image_raw", "/ego/color/image_raw"], published_counts=[40, 0])
    statuses = {
        "keypoint_tracker_a": StageStatus(
            state=StageStatus.STATE_RUNNING, input_topics=["/cmc/a/image_raw"], received_counts=[0]
        ),
        "ego_mapper": StageStatus(
            state=StageStatus.STATE_RUNNING, input_topics=["/ego/color/image_raw"], received_counts=[0]
        ),  # nothing played on it yet: not silent
        "keypoint_tracker_b": StageStatus(
            state=StageStatus.STATE_RUNNING, input_topics=["/cmc/a/image_raw"], received_counts=[3]
        ),
    }
    seen, told = {}, set()
    assert silent_inputs(replay, statuses, seen, told, now_s=10.0, after_s=60.0) == []
    (said,) = silent_inputs(replay, statuses, seen, told, now_s=71.0, after_s=60.0)
    assert "keypoint_tracker_a" in said and "none of the 40 messages" in said and "/cmc/a/image_raw" in said
    assert silent_inputs(replay, statuses, seen, told, now_s=200.0, after_s=60.0) == []  # said once


def test_the_eta_adds_the_final_steps_along_the_graph():
    rates = {"keypoint_tracker": 0.01, "ego_mapper": 0.05, "group_sfm": 0.02, "fusion": 0.03}  # s per message
    p = RunProgress(
        elapsed_s=30.0,
        played=1000,
        total=1000,
        playing_since_s=10.0,
        stages={"keypoint_tracker_a": RUNNING, "ego_mapper": RUNNING, "group_sfm": WAITING, "fusion": WAITING},
        consumed={"keypoint_tracker_a": 1.0, "ego_mapper": 1.0},
        final_rates=rates,
        finishing_since_s={"keypoint_tracker_a": 25.0, "ego_mapper": 28.0},
    )
    # Trackers 10 s from 25 s: 5 s left; ego 50 s from 28 s: 48 s; group SfM 20 s after the
    # trackers: 25 s; fusion 30 s after all of them: 78 s.
    assert p.eta_covers_final_steps and abs(p.eta_s - 78.0) < 1e-9
    assert "ETA 78 s;" in p.line() and p.eta_text() == "ETA 1:18"
    # Without a history for the fusion, the intake alone, marked.
    partial = RunProgress(**{**p.__dict__, "final_rates": {k: v for k, v in rates.items() if k != "fusion"}})
    assert partial.eta_s is None
    busy = RunProgress(**{**partial.__dict__, "played": 500})
    assert busy.eta_s == 20.0 and "+ final steps" in busy.line() and busy.eta_text().endswith("+")


def test_the_final_step_history(tmp_path):
    path = tmp_path / "yowo" / "final_steps.yaml"
    assert final_step_rates(path) == {}
    record_final_steps({"keypoint_tracker_a": 3.0, "keypoint_tracker_b": 5.0, "ego_mapper": 10.0}, 1000, path)
    record_final_steps({"keypoint_tracker_a": 1.0, "ego_mapper": 30.0}, 1000, path)
    record_final_steps({"ego_mapper": 20.0}, 1000, path)
    rates = final_step_rates(path)
    # The trackers' slowest per run (0.005, then 0.001): median 0.003; the ego's median of three.
    assert abs(rates["keypoint_tracker"] - 0.003) < 1e-12 and abs(rates["ego_mapper"] - 0.02) < 1e-12
    for _ in range(15):
        record_final_steps({"fusion": 1.0}, 1000, path)
    assert len(yaml.safe_load(path.read_text())["fusion"]) == 10
    path.write_text("{not yaml: [")
    assert final_step_rates(path) == {}
