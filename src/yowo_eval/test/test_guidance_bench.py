"""`yowo bench-guidance`'s scoring on small made-up inputs: precision and recall of "needs more"
against the cameras deficient by construction, the doorway's hit, the verdicts read from a run."""

import math

import pytest
import yaml

from yowo_eval.guidance_bench import (
    BEGIN,
    END,
    corner_named,
    deficient_cameras,
    doorway_hit,
    final_guidance,
    guidance_markdown,
    precision_recall,
    read_weak_places,
    summary,
)


def test_precision_and_recall_of_needs_more():
    # (deficient by construction, the guidance says "needs more")
    pairs = [(True, True), (True, False), (False, True), (False, True), (False, False), (True, True)]
    s = precision_recall(pairs)
    assert (s["tp"], s["fp"], s["fn"], s["tn"], s["cameras"]) == (2, 2, 1, 1, 6)
    assert s["precision"] == pytest.approx(0.5) and s["recall"] == pytest.approx(2 / 3)
    perfect = precision_recall([(True, True), (False, False), (False, False)])
    assert perfect["precision"] == 1.0 and perfect["recall"] == 1.0
    # Nothing said, nothing deficient: undefined, not 0 or 1.
    quiet = precision_recall([(False, False), (False, False)])
    assert quiet["precision"] is None and quiet["recall"] is None
    assert precision_recall([(True, False)])["recall"] == 0.0


def test_the_deficient_cameras_are_the_corner_walks_ones():
    truth = [
        {"kind": "corner", "camera": "cam03", "corner": "top-left"},
        {"kind": "doorway", "door_x_m": 6.05, "door_y_m": 3.2},
    ]
    assert deficient_cameras(truth) == {"cam03"}
    assert deficient_cameras([]) == set()


def test_a_weak_place_near_the_doorway_hits_it():
    door = (6.0, 3.0)
    near = {"kind": "track misses the walk", "x_m": 6.9, "y_m": 3.9}  # 1.27 m away
    far = {"kind": "walked once", "x_m": 9.0, "y_m": 3.0}  # 3 m away
    hit = doorway_hit([far, near], door)
    assert hit["hit"] and hit["kind"] == "track misses the walk"
    assert hit["nearest_m"] == pytest.approx(math.hypot(0.9, 0.9), abs=1e-3)
    miss = doorway_hit([far], door)
    assert not miss["hit"] and miss["nearest_m"] == pytest.approx(3.0)
    assert not doorway_hit([near], door, radius_m=1.0)["hit"]
    assert doorway_hit([], door) == {"hit": False, "nearest_m": None, "kind": None}


def test_the_corner_is_named_only_in_its_words():
    assert corner_named(["agent seen only in the image's top-left corner"], "top-left")
    assert not corner_named(["agent seen only in the image's top-right corner"], "top-left")
    assert not corner_named(["agent never seen in the image's left third"], "top-left")


def _case(kind, cams, **more):
    return {"preset": "small", "seed": 0, "kind": kind, "bag": f"b_{kind}", "exit": 0, "ratio": 1.1, **more} | {
        "cameras": {
            n: {"verdict": "needs more" if s else "ok", "reasons": [], "deficient": d, "needs_more": s}
            for n, (d, s) in cams.items()
        }
    }


def test_the_summary_and_section_over_cases():
    cases = [
        _case("sufficient", {"cam00": (False, False), "cam01": (False, True)}),
        _case(
            "corner",
            {"cam00": (True, True), "cam01": (False, False)},
            truth=[{"kind": "corner", "camera": "cam00", "corner": "top-left", "region": "ninth"}],
            corner_named=True,
        ),
        _case(
            "doorway",
            {"cam00": (False, False), "cam01": (False, False)},
            doorway={"hit": True, "nearest_m": 0.4, "kind": "walked once"},
        ),
        _case("doorway", {"cam00": (False, False)}, doorway={"hit": False, "nearest_m": 2.5, "kind": "walked once"}),
        {"preset": "small", "seed": 2, "kind": "corner", "skipped": "no camera has a reachable corner"},
    ]
    s = summary(cases)
    assert s["recordings"] == 4
    assert (s["all"]["tp"], s["all"]["fp"], s["all"]["fn"]) == (1, 1, 0)
    assert s["all"]["precision"] == 0.5 and s["all"]["recall"] == 1.0
    assert s["by_kind"]["corner"]["precision"] == 1.0 and s["by_kind"]["sufficient"]["fp"] == 1
    assert s["doorway"] == {"walks": 2, "hits": 1, "rate": 0.5}
    assert s["corner_named"] == {"walks": 1, "named": 1}
    text = guidance_markdown(cases, "yowo bench-guidance --preset small")
    assert text.startswith(BEGIN) and text.rstrip().endswith(END)
    assert "yowo bench-guidance --preset small" in text and "precision of `needs more` 50 %" in text
    assert "recall 100 %" in text and "1 of 2 doorway walks (50 %)" in text
    assert "cam00 (top-left ninth)" in text and "no such walk" in text


def test_the_verdicts_and_weak_places_are_read_from_the_results(tmp_path):
    cams = {
        "cameras": [
            {"name": "cam00", "coverage": {"verdict": "needs more", "reasons": ["agent seen only in x"]}},
            {"name": "cam01", "coverage": {"verdict": "ok", "reasons": []}},
        ]
    }
    (tmp_path / "cameras.yaml").write_text(yaml.safe_dump(cams))
    got = final_guidance(tmp_path)  # no result.mcap: cameras.yaml's coverage
    assert {n: g["verdict"] for n, g in got.items()} == {"cam00": "needs more", "cam01": "ok"}
    assert got["cam00"]["reasons"] == ["agent seen only in x"]
    assert read_weak_places(tmp_path) == []
    places = [{"kind": "walked once", "x_m": 1.0, "y_m": 2.0}]
    (tmp_path / "weak_places.yaml").write_text(yaml.safe_dump({"weak_places": places}))
    assert read_weak_places(tmp_path) == places


def test_the_true_coverage_of_a_corner_walk():
    """Where each camera truly saw the walker (the simulator's walk again): the corner walk's camera
    in its corner only, and the same recording's truth as the simulator recorded it."""
    from yowo_eval.guidance_bench import true_coverage
    from yowo_sim.capture import build_capture
    from yowo_sim.deficient import parse_deficient
    from yowo_sim.presets import get_preset

    (truth,) = build_capture(get_preset("small", deficient=parse_deficient(["corner:cam00"])), 1).deficient
    cov = true_coverage("small", "corner:cam00", 1)
    assert truth["corner"] == "top-left" and truth["region"] == "ninth"
    ninths = cov["cam00"]["ninths"]
    assert ninths[0][0] > 50 and sum(map(sum, ninths)) == ninths[0][0]
    assert cov["cam00"]["region_reason"] == "agent seen only in the image's top-left corner"
    assert set(cov) == {"cam00", "cam01", "cam02", "cam03", "cam04"}
