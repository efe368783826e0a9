"""The benchmark's report tables (markdown rendering only): clock offsets, from the cases'
per-camera offset errors and the same recordings' synchronised case; verdicts, from each
camera's status and error."""

from yowo_eval.bench_markdown import TRUE_CLOCKS, markdown

ENV = {"cpu": "test", "cores": 2, "python": "3", "numpy": "2", "gtsam": "4", "date": "today"}


def summary(pos_avg: float) -> dict:
    return {
        "count": 3,
        "pos_avg": pos_avg,
        "pos_min": 0.0,
        "pos_max": pos_avg,
        "rot_avg": 0.3,
        "rot_min": 0.0,
        "rot_max": 0.5,
    }


def case(
    scenario: str,
    seed: int,
    pos_avg: float,
    clock_errors_ms: dict | None = None,
    synced_pos_avg: float | None = None,
    full: dict | None = None,
) -> dict:
    def relative(pos: float) -> dict:
        return {
            "summary": summary(pos),
            "calibrated": 3,
            "cameras": 3,
            "seconds": 1.0,
            "errors": {},
            "groups": {"g0": ["a", "b", "c"]},
        }

    rel = {"YOWO": relative(pos_avg)}
    if clock_errors_ms is not None:
        rel["YOWO"]["clock_errors_ms"] = clock_errors_ms
    if synced_pos_avg is not None:
        rel[TRUE_CLOCKS] = relative(synced_pos_avg)
    out = {
        "preset": "small",
        "scenario": scenario,
        "seed": seed,
        "relative": rel,
        "bound": {"cameras": 0, "position_m": {}, "rotation_deg": {}, "mean_position_m": {}, "mean_rotation_deg": {}},
    }
    if full is not None:
        out |= {"full": full, "peak_memory_mb": 100.0}
    return out


def full(yowo_pos: float, synced_pos: float, to_ego_ms: dict) -> dict:
    def reg(pos: float) -> dict:
        return summary(pos) | {"registered": 3, "cameras": 3, "errors": {}}

    return {
        "registration": {
            "YOWO without joint optimisation": reg(yowo_pos),
            "YOWO": reg(yowo_pos),
            TRUE_CLOCKS: reg(synced_pos),
        },
        "ate": {"joint": 0.01},
        "layout_iou": 0.9,
        "layout_iou_joint": 0.9,
        "seconds": {"ego": 1.0, "cmc": 1.0, "fusion": 1.0},
        "recording_s": 30.0,
        "realtime_factor": 0.1,
        "cmcs": 3,
        "clock_errors_to_ego_ms": to_ego_ms,
    }


def clock_rows(text: str) -> list[str]:
    section = text.split("## CMC clock offsets")[1].split("\n## ")[0]
    return [line for line in section.splitlines() if line.startswith("| small |")]


def test_clock_table_gives_offset_errors_and_the_ratios_to_the_same_recordings_synchronised():
    cases = [
        case("normal", 0, 0.001),
        case("normal", 1, 0.001),
        case("clock_offsets", 0, 0.011, {"b": 1.0, "c": -3.0}, 0.010, full(0.022, 0.020, {"a": 4.0, "b": -1.0})),
        case("clock_offsets", 1, 0.011, {"b": 0.5}, 0.012, full(0.030, 0.020, {"a": 0.5})),
    ]
    text = markdown({"cases": cases, "presets": ["small"], "seeds": [0, 1]}, "yowo bench", ENV)
    assert "## CMC clock offsets" in text
    (row,) = clock_rows(text)
    # to the reference |1.0|, |3.0|, |0.5|: median 1.0, max 3.0, 2 of 3 within 2 ms; to the ego |4.0|, |1.0|,
    # |0.5|: median 1.0, max 4.0, 2 of 3; relative 0.011 / 0.011 = 1.00 (not the normal recordings' 0.001);
    # registration 0.026 / 0.020 = 1.30
    assert row.split(" | ")[2:] == ["3", "1.0", "3.0", "0.67", "3", "1.0", "4.0", "0.67", "1.00", "1.30 |"]
    synchronised_only = markdown({"cases": cases[:2], "presets": ["small"], "seeds": [0, 1]}, "yowo bench", ENV)
    assert "## CMC clock offsets" not in synchronised_only


def test_clock_table_without_the_synchronised_case_says_so():
    cases = [case("clock_offsets", 0, 0.011, {"b": 1.0})]
    text = markdown({"cases": cases, "presets": ["small"], "seeds": [0]}, "yowo bench", ENV)
    (row,) = clock_rows(text)
    assert row.split(" | ")[2:] == ["1", "1.0", "1.0", "1.00", "0", "n/a", "n/a", "n/a", "n/a", "n/a |"]


def test_verdict_table_counts_statuses_and_the_ok_cameras_that_were_off():
    def with_statuses(pos_errors: dict, statuses: dict) -> dict:
        f = full(0.05, 0.05, {})
        f["registration"]["YOWO"] |= {"errors": {n: [e, 0.1] for n, e in pos_errors.items()}, "statuses": statuses}
        return f

    cases = [
        case(
            "texture_poor",
            0,
            0.01,
            full=with_statuses({"a": 0.02, "b": 0.14, "c": 0.30}, {"a": "ok", "b": "ok", "c": "weak"}),
        ),
        case(
            "texture_poor", 1, 0.01, full=with_statuses({"a": 0.04, "b": 0.06}, {"a": "ok", "b": "weak", "c": "failed"})
        ),
    ]
    text = markdown({"cases": cases, "presets": ["small"], "seeds": [0, 1]}, "yowo bench", ENV)
    section = text.split("## Verdicts")[1].split("\n## ")[0]
    (row,) = [line for line in section.splitlines() if line.startswith("| small |")]
    # ok: 0.02, 0.14, 0.04 (avg 0.0667, max 0.14, one beyond 0.10 m); weak: 0.30, 0.06 (avg 0.18)
    assert row.split(" | ")[2:] == ["3 / 2 / 1", "0.0667", "0.1400", "1", "0.1800 |"]
    old = markdown(
        {"cases": [case("normal", 0, 0.01, full=full(0.05, 0.05, {}))], "presets": ["small"], "seeds": [0]},
        "yowo bench",
        ENV,
    )
    assert "## Verdicts" not in old  # cases recorded before the statuses were
