"""`yowo bench-second-walk`'s scoring on made-up runs: the cameras the first run named, their
verdict and registration before and after, and the count brought to ok within 2 cm."""

import json

import yaml

from yowo_eval.second_walk_bench import BEGIN, END, score, second_walk_markdown, summary


def fake_run(path, cameras: dict[str, tuple[str, str, float | None]]):
    """A run directory with cameras.yaml (status, coverage verdict) and metrics.json (errors)."""
    path.mkdir()
    cams = [
        {"name": n, "status": status, "coverage": {"verdict": verdict, "reasons": [] if verdict == "ok" else ["thin"]}}
        for n, (status, verdict, _) in cameras.items()
    ]
    (path / "cameras.yaml").write_text(yaml.safe_dump({"cameras": cams}))
    errors = [{"name": n, "eps_pos_m": e, "eps_rot_deg": 0.1} for n, (_, _, e) in cameras.items() if e is not None]
    (path / "metrics.json").write_text(json.dumps({"registration": {"cameras": errors}}))
    return path


def test_the_named_cameras_are_scored_before_and_after(tmp_path):
    first = fake_run(
        tmp_path / "first",
        {
            "cam00": ("ok", "needs more", 0.006),  # brought to ok within 2 cm
            "cam01": ("ok", "ok", 0.005),  # not named: not scored
            "cam02": ("weak", "needs more", 5.9),  # ok after, still too far off
            "cam03": ("failed", "needs more", None),  # not registered after either
        },
    )
    joined = fake_run(
        tmp_path / "joined",
        {
            "cam00": ("ok", "ok", 0.008),
            "cam01": ("ok", "ok", 0.004),
            "cam02": ("weak", "ok", 0.064),
            "cam03": ("failed", "needs more", None),
        },
    )
    cams = score(first, joined)
    assert sorted(cams) == ["cam00", "cam02", "cam03"]
    assert (cams["cam00"]["ok_after"], cams["cam00"]["within_m"]) == (True, True)
    assert (cams["cam02"]["ok_after"], cams["cam02"]["within_m"]) == (True, False)
    assert cams["cam02"]["eps_pos_before_m"] == 5.9 and cams["cam02"]["status_after"] == "weak"
    assert (cams["cam03"]["ok_after"], cams["cam03"]["within_m"]) == (False, False)
    assert cams["cam03"]["reasons_after"] == ["thin"]

    cases = [
        {"preset": "small", "kind": "corner", "seed": 0, "waypoints": 5, "exit": 0, "cameras": cams},
        {"preset": "small", "kind": "corner", "seed": 1, "skipped": "the first run suggests no second walk"},
    ]
    s = summary(cases)
    assert (s["recordings"], s["named"], s["ok_after"], s["within"], s["both"]) == (1, 3, 2, 1, 1)
    md = second_walk_markdown(cases, "yowo bench-second-walk --seeds 0 1")
    assert md.startswith(BEGIN) and md.rstrip().endswith(END)
    assert "1 of 3 named cameras over 1 recordings" in md
    assert "| small corner s0 | 5 | cam02 | ok |  | weak / weak | 590.0 / 6.4 |" in md
    assert "the first run suggests no second walk" in md
