"""`yowo bench-multiview`: a manifest's bad entries are named without a traceback; the variants
are planned as the issue says (the declared skeleton only for the detector variant, the pose
model only with videos, the bench's --set for all); the markdown table, its per-variant median
and max from a results dict; and end to end through real `yowo` processes, a synthetic
Pose2Sim-style session of a person walking in front of the two cameras of
test_multiview_import (calibrated to a fraction of a percent of the baseline, both variants)
beside a recording whose import fails (recorded with the importer's reason, the bench going on)."""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from yowo_bringup.cli import main
from yowo_eval.multiview_bench import (
    SECTION,
    failure_reason,
    multiview_markdown,
    plan_variants,
    read_manifest,
    variant_summary,
)

sys.path.insert(0, str(Path(__file__).parent))
from test_multiview_import import CAMS, JOINTS, H, W, toml_text, write_session  # noqa: E402

# A standing person's BODY_25B joints in the body frame (x right, y forward, z up) [m].
BODY = {
    "nose": (0, 0.09, 1.62),
    "left_eye": (0.03, 0.07, 1.66),
    "right_eye": (-0.03, 0.07, 1.66),
    "left_ear": (0.07, 0.0, 1.64),
    "right_ear": (-0.07, 0.0, 1.64),
    "left_shoulder": (0.19, 0, 1.44),
    "right_shoulder": (-0.19, 0, 1.44),
    "left_elbow": (0.22, 0, 1.15),
    "right_elbow": (-0.22, 0, 1.15),
    "left_wrist": (0.23, 0.05, 0.88),
    "right_wrist": (-0.23, 0.05, 0.88),
    "left_hip": (0.1, 0, 0.95),
    "right_hip": (-0.1, 0, 0.95),
    "left_knee": (0.1, 0.02, 0.5),
    "right_knee": (-0.1, 0.02, 0.5),
    "left_ankle": (0.1, -0.02, 0.08),
    "right_ankle": (-0.1, -0.02, 0.08),
    "neck": (0, 0, 1.5),
    "head_top": (0, 0.01, 1.76),
    "left_big_toe": (0.12, 0.17, 0.02),
    "left_small_toe": (0.16, 0.14, 0.02),
    "left_heel": (0.1, -0.06, 0.03),
    "right_big_toe": (-0.12, 0.17, 0.02),
    "right_small_toe": (-0.16, 0.14, 0.02),
    "right_heel": (-0.1, -0.06, 0.03),
}


def write_walk(root: Path, frames: int = 120) -> None:
    """A person walking a 0.5 m circle where both cameras of test_multiview_import look
    (world z up), swinging the arms; OpenPose JSON of their projections (K, distortion) with
    0.5 px noise, joints outside the 160 x 120 image not found; Config.toml at 30 fps."""
    (root / "calibration").mkdir(parents=True)
    (root / "calibration" / "Calib_test.toml").write_text(toml_text())
    (root / "Config.toml").write_text("[project]\nframe_rate = 30\n")
    rng = np.random.default_rng(1)
    for f in range(frames):
        a = 2 * np.pi * f / frames
        c, s = np.cos(a + np.pi), np.sin(a + np.pi)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        pos = np.array([-0.25, 0.05, 0.0]) + 0.5 * np.array([np.cos(a), np.sin(a), 0.0])
        swing = 0.15 * np.sin(12 * a)
        X = []
        for n in JOINTS:
            p = np.array(BODY[n], float)
            if "wrist" in n or "elbow" in n:
                p[1] += swing * (1 if "left" in n else -1) * (1.0 if "wrist" in n else 0.5)
            X.append(R @ p + pos)
        for k, cam in enumerate(CAMS.values(), start=1):
            uv, _ = cv2.projectPoints(
                np.array(X), np.array(cam["rvec"]), np.array(cam["tvec"]), np.array(cam["K"]), np.array(cam["D"])
            )
            uv = uv.reshape(-1, 2) + rng.normal(0, 0.5, (len(X), 2))
            seen = (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
            flat = np.column_stack([np.where(seen[:, None], uv, 0.0), np.where(seen, 0.9, 0.0)]).ravel()
            d = root / "pose" / f"cam0{k}_json"
            d.mkdir(parents=True, exist_ok=True)
            person = {"person_id": [-1], "pose_keypoints_2d": [round(float(v), 3) for v in flat]}
            (d / f"cam0{k}.{f:04d}.json").write_text(json.dumps({"version": 1.3, "people": [person]}))


def entry(name: str, session: str, **kw) -> dict:
    return {
        "name": name,
        "session": session,
        "keypoint_format": "BODY_25B",
        "skeleton": "body25b",
        "source": {"repository": "example/synthetic", "commit": "0123456789abcdef", "path": session},
        "licence": "CC0-1.0",
        "motion": "walking",
        "reference": "the generating poses",
    } | kw


def write_manifest(path: Path, entries) -> Path:
    path.write_text(yaml.safe_dump(entries, sort_keys=False))
    return path


# ---------------------------------------------------------------- manifest and plan


def test_manifest_resolves_paths_and_reads_sources(tmp_path):
    write_session(tmp_path / "data" / "s", frames=1, video=True)
    (tmp_path / "data" / "xy_HOLISTIC.csv").write_text("sync_index\n")
    m = write_manifest(
        tmp_path / "data" / "m.yaml",
        [
            entry("a", "s", videos=True, calibration="s/calibration/Calib_test.toml", fps=25),
            entry("b", "xy_HOLISTIC.csv", keypoint_format="HOLISTIC", skeleton="holistic", source="o/r@abc123:x/y"),
        ],
    )
    a, b = read_manifest(m)
    assert a.session == (tmp_path / "data" / "s").resolve() and a.videos and a.fps == 25.0
    assert a.calibration == (tmp_path / "data" / "s" / "calibration" / "Calib_test.toml").resolve()
    assert a.source_text() == "example/synthetic@01234567" and not a.caliscope
    assert b.caliscope and b.source == {"repository": "o/r", "commit": "abc123", "path": "x/y"} and not b.videos


@pytest.mark.parametrize(
    "change, message",
    [
        ({"skeleton": "body26"}, "entry 1 (r1): skeleton: unknown keypoint skeleton 'body26'"),
        ({"session": "nowhere"}, "entry 1 (r1): session"),
        ({"keypoint_format": "BODY_99"}, "entry 1 (r1): keypoint_format 'BODY_99' is not one the importer reads"),
        ({"licence": None}, "entry 1 (r1): missing licence"),
        ({"source": "no commit"}, "entry 1 (r1): source 'no commit'"),
        ({"videos": True}, "entry 1 (r1): videos: true, but"),
        ({"videos": "yes"}, "entry 1 (r1): videos: expected true or false"),
        ({"fps": -3}, "entry 1 (r1): fps: expected a positive number"),
        ({"name": "a b"}, "entry 1 (a b): name 'a b': letters"),
        ({"colour": "red"}, "entry 1 (r1): unknown key(s) colour"),
    ],
)
def test_bad_entries_are_named(tmp_path, capsys, change, message):
    write_session(tmp_path / "s", frames=1)
    m = write_manifest(tmp_path / "m.yaml", [entry("r1", "s") | change])
    with pytest.raises(ValueError) as err:
        read_manifest(m)
    assert str(err.value).startswith(f"{m}: ") and message in str(err.value)
    # The verb: exit 2, the message, no traceback.
    assert main(["bench-multiview", str(m), "-o", str(tmp_path / "w")]) == 2
    stderr = capsys.readouterr().err
    assert message in stderr and "Traceback" not in stderr


def test_duplicate_names_and_not_a_list(tmp_path):
    write_session(tmp_path / "s", frames=1)
    m = write_manifest(tmp_path / "m.yaml", [entry("r", "s"), entry("r", "s")])
    with pytest.raises(ValueError, match=r"entry 2 \(r\): the name is used by an earlier entry"):
        read_manifest(m)
    m.write_text("name: r\n")
    with pytest.raises(ValueError, match="expected a list of recordings"):
        read_manifest(m)


def test_variants_plan(tmp_path, capsys):
    write_session(tmp_path / "s", frames=1, video=True)
    m = write_manifest(tmp_path / "m.yaml", [entry("v", "s", videos=True), entry("k", "s")])
    with_video, without = read_manifest(m)
    plan = {v.key: v for v in plan_variants(with_video)}
    assert list(plan) == ["derived", "detector", "undeclared", "pose"]
    assert [v.key for v in plan_variants(without)] == ["derived", "detector", "undeclared"]
    assert [v.key for v in plan_variants(with_video, ("pose", "derived"))] == ["derived", "pose"]
    # One bag for the detector with and without the declaration; the skeleton declared only there.
    assert plan["detector"].bag_kind == plan["undeclared"].bag_kind == "detector"
    assert plan["detector"].import_args == ("--as-detector",) and plan["pose"].import_args == ("--videos",)
    declared = [v.key for v in plan.values() if any("cmc.keypoints.skeleton=" in a for a in v.calibrate_args)]
    assert declared == ["detector"] and "cmc.keypoints.skeleton=body25b" in plan["detector"].calibrate_args
    assert plan["pose"].calibrate_args == ("--cmc-source", "pose")
    # The bench's own configuration may not declare a skeleton: that is the variants' difference.
    assert main(["bench-multiview", str(m), "-o", str(tmp_path / "w"), "--set", "cmc.keypoints.skeleton=coco17"]) == 2
    assert "declares each recording's skeleton itself" in capsys.readouterr().err


def test_failure_reasons():
    assert failure_reason(2, "", "yowo import-multiview: /x/pose: holds no .json keypoint files\n") == (
        "/x/pose: holds no .json keypoint files"
    )
    out = "group g0: cam_01 (1.0 px)\nnot calibrated: cam_02: too few frames\nnot calibrated: cam_03: no agent\n"
    assert failure_reason(1, out, "") == "cam_02: too few frames; cam_03: no agent"
    assert failure_reason(None, "", "") == "timed out"
    assert failure_reason(-9, "", "Killed\n") == "Killed (exit -9)"


# ---------------------------------------------------------------- markdown


def case(rec, variant, label, **kw) -> dict:
    base = dict(recording=rec, variant=variant, label=label, status="ok", reason="", cameras_total=4, groups=1)
    base |= dict(cameras_registered=4, wall_s=60.0, notes=[])
    return base | kw


def test_markdown_from_results():
    recs = [
        {"name": n, "source_text": f"o/{n}@abcdef12", "licence": "BSD-3-Clause", "motion": "standing", "reference": "Q"}
        for n in ("r1", "r2", "r3")
    ]
    cases = [
        case("r1", "derived", "derived", pos_pct_avg=1.0, pos_pct_max=2.0, rot_avg_deg=0.5),
        case("r1", "detector", "detector", pos_pct_avg=1.5, pos_pct_max=2.5, rot_avg_deg=0.7),
        case("r2", "derived", "derived", pos_pct_avg=3.0, pos_pct_max=9.0, rot_avg_deg=1.5, cameras_registered=3),
        case("r2", "detector", "detector", status="failed", reason="import: a | b", cameras_total=None, wall_s=None),
        case("r3", "derived", "derived", pos_pct_avg=2.0, pos_pct_max=4.0, rot_avg_deg=1.0, notes=["cam_4: no agent"]),
        case("r3", "detector", "detector", status="failed", reason="cam_1: too few", cameras_registered=None),
    ]
    results = {"command": "yowo bench-multiview m.yaml -o w", "commit": "abc1234", "date": "2026-12-07"}
    text = multiview_markdown(results | {"config": ["--set", "cmc.x=1"], "recordings": recs, "cases": cases})
    assert text.startswith(f"<!-- {SECTION}:begin -->") and text.rstrip().endswith(f"<!-- {SECTION}:end -->")
    assert "yowo bench-multiview m.yaml -o w" in text and "Commit abc1234, 2026-12-07" in text
    assert "`--set cmc.x=1`" in text
    rows = [ln for ln in text.splitlines() if ln.startswith(("| r1 ", "| r2 ", "| r3 ", "|  |"))]
    assert rows[0].startswith(
        "| r1 | o/r1@abcdef12 | BSD-3-Clause | standing | Q | derived | 4 / 4 | 1.00 / 2.00 | 0.50 | 60 |"
    )
    assert rows[1].startswith("|  |  |  |  |  | detector | 4 / 4 | 1.50 / 2.50 |")  # the recording named once
    assert "| derived | 3 / 4 | 3.00 / 9.00 | 1.50 |" in rows[2]
    assert "| detector | - | failed | - | - | import: a \\| b |" in rows[3]  # the reason, its | escaped
    assert rows[4].endswith("| not calibrated: cam_4: no agent |")
    assert "| detector | 0 / 4 | failed | - | 60 | cam_1: too few |" in rows[5]  # calibrated none of 4
    summary = {s["variant"]: s for s in variant_summary(cases)}
    assert (summary["derived"]["ok"], summary["derived"]["all_cameras"]) == (3, 2)
    assert summary["derived"]["pos_pct_avg_median"] == 2.0 and summary["derived"]["pos_pct_avg_max"] == 3.0
    assert summary["derived"]["pos_pct_max_max"] == 9.0 and summary["derived"]["rot_avg_deg_median"] == 1.0
    assert (summary["detector"]["ok"], summary["detector"]["failed"]) == (1, 2)
    assert "| derived | 3 / 3 (2) | 2.00 / 3.00 | 9.00 | 1.00 / 1.50 |" in text
    assert "| detector | 1 / 3 (1) | 1.50 / 1.50 | 2.50 | 0.70 / 0.70 |" in text


# ---------------------------------------------------------------- end to end


def test_end_to_end_through_yowo_processes(tmp_path, capsys):
    """Two `calibrate-cmc` runs (about 25 s each) and three imports."""
    write_walk(tmp_path / "data" / "walk")
    write_session(tmp_path / "data" / "broken", frames=2)  # BODY_25B joints, declared COCO_17 below
    m = write_manifest(
        tmp_path / "data" / "manifest.yaml",
        [entry("walk", "walk"), entry("broken", "broken", keypoint_format="COCO_17", skeleton="coco17", fps=25)],
    )
    markdown = tmp_path / "REAL.md"
    markdown.write_text(f"# Kept\n\n<!-- {SECTION}:begin -->\nold\n<!-- {SECTION}:end -->\n\nafter\n")
    work = tmp_path / "work"
    rc = main(
        ["bench-multiview", str(m), "-o", str(work), "--variants", "derived", "detector", "--markdown", str(markdown)]
    )
    assert rc == 0, capsys.readouterr()

    results = json.loads((work / "results.json").read_text())
    cases = {(c["recording"], c["variant"]): c for c in results["cases"]}
    assert list(cases) == [("walk", "derived"), ("walk", "detector"), ("broken", "derived"), ("broken", "detector")]
    for v in ("derived", "detector"):
        c = cases["walk", v]
        assert c["status"] == "ok", c
        assert (c["cameras_registered"], c["cameras_total"], c["groups"]) == (2, 2, 1)
        assert 0.0 < c["pos_pct_avg"] <= c["pos_pct_max"] < 1.0  # 0.5 px of noise on a 160 px image
        assert 0.0 < c["rot_avg_deg"] < 0.5 and c["wall_s"] > 0
        assert (work / "runs" / "walk" / v / "cameras.yaml").exists()
    assert "cmc.keypoints.skeleton=body25b" in cases["walk", "detector"]["command"]
    assert "cmc.keypoints.skeleton" not in cases["walk", "derived"]["command"]
    for v in ("derived", "detector"):
        c = cases["broken", v]
        assert c["status"] == "failed" and c["wall_s"] is None  # no calibration after a failed import
        assert c["reason"].startswith("import: ") and "has 25 joints; COCO_17 has 17" in c["reason"]
        assert "import: broken/pose/cam01_json/" in c["reason"] and str(tmp_path) not in c["reason"]
    assert results["recordings"][0]["source_text"] == "example/synthetic@01234567"

    text = markdown.read_text()
    assert text.startswith("# Kept\n") and text.rstrip().endswith("after") and "\nold\n" not in text
    section = (work / "MULTIVIEW.md").read_text()
    assert section.strip() in text
    walk = cases["walk", "derived"]
    assert f"| derived | 2 / 2 | {walk['pos_pct_avg']:.2f} / {walk['pos_pct_max']:.2f} |" in section
    assert "| detector | - | failed | - | - | import: " in section
    assert "| derived | 1 / 2 (1) |" in section and "| detector | 1 / 2 (1) |" in section
