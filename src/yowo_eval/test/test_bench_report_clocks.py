"""The benchmark's clock-offset table: from the cases' per-camera offset errors and the
synchronised recordings of the same preset (markdown rendering only)."""
from yowo_eval.bench_report import markdown

ENV = {"cpu": "test", "cores": 2, "python": "3", "numpy": "2", "gtsam": "4", "date": "today"}


def case(scenario: str, seed: int, pos_avg: float, clock_errors_ms: dict | None = None) -> dict:
    yowo = {"summary": {"count": 3, "pos_avg": pos_avg, "pos_min": 0.0, "pos_max": pos_avg, "rot_avg": 0.3,
                        "rot_min": 0.0, "rot_max": 0.5}, "calibrated": 3, "cameras": 3, "seconds": 1.0,
            "errors": {}, "groups": {"g0": ["a", "b", "c"]}}
    if clock_errors_ms is not None:
        yowo["clock_errors_ms"] = clock_errors_ms
    return {"preset": "small", "scenario": scenario, "seed": seed, "relative": {"YOWO": yowo},
            "bound": {"cameras": 0, "position_m": {}, "rotation_deg": {}, "mean_position_m": {},
                      "mean_rotation_deg": {}}}


def test_clock_table_gives_offset_errors_and_the_ratio_to_the_synchronised_case():
    cases = [case("normal", 0, 0.008), case("normal", 1, 0.012),
             case("clock_offsets", 0, 0.011, {"b": 1.0, "c": -3.0}), case("clock_offsets", 1, 0.011, {"b": 0.5})]
    text = markdown({"cases": cases, "presets": ["small"], "seeds": [0, 1]}, "yowo bench", ENV)
    assert "## CMC clock offsets" in text
    (row,) = [line for line in text.splitlines() if line.startswith("| small | clock_offsets | 3 |")]
    # |errors| 1.0, 3.0, 0.5: median 1.0, max 3.0, 2 of 3 within 2 ms; 0.011 / 0.010 = 1.10
    assert row.split(" | ")[3:7] == ["1.0", "3.0", "0.67", "1.10 |"]
    synchronised_only = markdown({"cases": cases[:2], "presets": ["small"], "seeds": [0, 1]}, "yowo bench", ENV)
    assert "## CMC clock offsets" not in synchronised_only
