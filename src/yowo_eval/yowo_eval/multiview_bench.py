"""`yowo bench-multiview MANIFEST.yaml -o WORKDIR`: real multi-camera recordings of a person
with a reference calibration, each imported with `yowo import-multiview` and
calibrated with `yowo calibrate-cmc` in several variants, one configuration (`--set`) for
all, the relative pose error after a per-group similarity alignment as `yowo eval` computes
it -> WORKDIR/results.json and the markdown section `real-multiview`.
One module above the usual size: the manifest's checks, the variants' runs and their table
belong to this one command and change together.

The manifest is a YAML list of recordings (or a mapping with the list under `recordings`);
paths are relative to the manifest's folder:

    - name: p2s_balancing                  # unique; names the bags and runs
      session: p2s_balancing               # a Pose2Sim folder, or caliscope's xy_<TRACKER>.csv
      calibration: p2s_balancing/calibration/Calib.toml   # optional (the importer's default)
      keypoint_format: BODY_25B            # the importer's --keypoint-format (caliscope: its tracker, HOLISTIC)
      skeleton: body25b                    # the declared skeleton, cmc.keypoints.skeleton (a name or a YAML table)
      videos: true                         # optional (false): also the pose-model variant on videos/
      fps: 60                              # optional: when the folder has no Config.toml frame_rate nor videos
      source: {repository: perfanalytics/pose2sim, commit: f287b0e5, path: Pose2Sim/...}
      licence: BSD-3-Clause
      motion: standing                     # seated, standing or walking (free text)
      reference: Qualisys motion capture, avg residual 0.40-0.50

Variants of each recording (`--variants` chooses among them):
- derived: imported as `import-multiview` does by default (ids 0 and 1, head top and ground
  point, derived by the importer), `calibrate-cmc --cmc-source keypoints`;
- detector: imported `--as-detector` (the detector's own numbering + 2, no ids 0/1),
  calibrated with `--set cmc.keypoints.skeleton=<skeleton>`;
- undeclared: the same recording without the declaration;
- pose: recordings with videos, imported `--videos`, `calibrate-cmc --cmc-source pose`.

Every import and calibration runs as its own `yowo` process with a time limit, so one that
fails is recorded with its reason and the bench goes on."""

from __future__ import annotations

import json
import math
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from datetime import date
from pathlib import Path

import yaml

SECTION = "real-multiview"
# (bag kind, label) per variant key, in the order they run and are reported.
VARIANTS = {
    "derived": ("derived", "derived"),
    "detector": ("detector", "detector"),
    "undeclared": ("detector", "detector, undeclared"),
    "pose": ("videos", "pose model"),
}
REQUIRED_TEXT = ("name", "keypoint_format", "skeleton", "licence", "motion", "reference")
KNOWN_KEYS = {*REQUIRED_TEXT, "session", "calibration", "videos", "fps", "source"}


@dataclass(frozen=True, kw_only=True)
class Recording:
    """One manifest entry, its paths resolved against the manifest's folder."""

    name: str
    session: Path
    calibration: Path | None
    keypoint_format: str
    skeleton: str  # a format name, or the absolute path of a YAML table
    videos: bool
    fps: float | None
    source: dict
    licence: str
    motion: str
    reference: str

    @property
    def caliscope(self) -> bool:
        return self.session.suffix.lower() == ".csv"

    def source_text(self) -> str:
        """'owner/repo@commit' (the commit shortened to 8)."""
        return f"{self.source['repository']}@{str(self.source['commit'])[:8]}"


@dataclass(frozen=True)
class Variant:
    key: str
    label: str
    bag_kind: str
    import_args: tuple[str, ...]
    calibrate_args: tuple[str, ...]


@dataclass
class Case:
    recording: str
    variant: str
    label: str
    status: str = "failed"  # ok | failed
    reason: str = ""
    cameras_registered: int | None = None
    cameras_total: int | None = None
    groups: int | None = None
    pos_pct_avg: float | None = None
    pos_pct_max: float | None = None
    pos_avg_m: float | None = None
    rot_avg_deg: float | None = None
    rot_max_deg: float | None = None
    wall_s: float | None = None
    import_s: float | None = None
    notes: list[str] = field(default_factory=list)
    command: str = ""


# ---------------------------------------------------------------- manifest


def _source(value, where: str) -> dict:
    """{repository, commit, path} from a mapping or 'owner/repo@commit[:path]'."""
    if isinstance(value, str):
        m = re.fullmatch(r"([^@\s]+)@([0-9A-Za-z]+)(?::(.+))?", value.strip())
        if not m:
            raise ValueError(f"{where}: source '{value}': expected 'owner/repo@commit[:path]' or a mapping")
        return {"repository": m[1], "commit": m[2], "path": m[3] or ""}
    if not isinstance(value, dict):
        raise ValueError(f"{where}: source: expected {{repository, commit, path}} or 'owner/repo@commit[:path]'")
    missing = [k for k in ("repository", "commit") if not str(value.get(k) or "").strip()]
    if missing:
        raise ValueError(f"{where}: source: missing {', '.join(missing)}")
    return {"repository": str(value["repository"]), "commit": str(value["commit"]), "path": str(value.get("path", ""))}


def _entry(raw, index: int, manifest: Path) -> Recording:
    from yowo_cmc.skeletons import load_skeleton

    from .multiview_readers import all_formats

    name = raw.get("name") if isinstance(raw, dict) else None
    where = f"{manifest}: entry {index}" + (f" ({name})" if isinstance(name, str) and name else "")
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: expected a mapping of name, session, keypoint_format, skeleton, ...")
    unknown = sorted(set(raw) - KNOWN_KEYS)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(KNOWN_KEYS))})")
    missing = [k for k in (*REQUIRED_TEXT, "session", "source") if raw.get(k) in (None, "")]
    if missing:
        raise ValueError(f"{where}: missing {', '.join(missing)}")
    bad = [k for k in (*REQUIRED_TEXT, "session") if not isinstance(raw[k], str)]
    if bad:
        raise ValueError(f"{where}: {', '.join(bad)}: expected text")
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
        raise ValueError(f"{where}: name '{name}': letters, digits, '_', '.', '-' only (it names folders)")
    base = manifest.parent
    session = (base / raw["session"]).resolve()
    if not session.exists():
        raise ValueError(f"{where}: session {session}: no such folder or file")
    csv = session.suffix.lower() == ".csv"
    if not csv and not session.is_dir():
        raise ValueError(f"{where}: session {session}: expected a Pose2Sim folder or caliscope's xy_<TRACKER>.csv")
    calibration = None
    if raw.get("calibration") not in (None, ""):
        calibration = (base / str(raw["calibration"])).resolve()
        if not calibration.is_file():
            raise ValueError(f"{where}: calibration {calibration}: no such file")
    if not csv and raw["keypoint_format"] not in all_formats():
        raise ValueError(
            f"{where}: keypoint_format '{raw['keypoint_format']}' is not one the importer reads "
            f"({', '.join(all_formats())})"
        )
    skeleton = raw["skeleton"]
    if skeleton.lower().endswith((".yaml", ".yml")):
        skeleton = str((base / skeleton).resolve())
    load_skeleton(skeleton, f"{where}: skeleton")  # ValueError naming the entry
    videos = raw.get("videos", False)
    if not isinstance(videos, bool):
        raise ValueError(f"{where}: videos: expected true or false, got {videos!r}")
    if videos and csv:
        raise ValueError(f"{where}: videos: a caliscope table has no videos to import")
    if videos and not (session / "videos").is_dir():
        raise ValueError(f"{where}: videos: true, but {session / 'videos'} does not exist")
    fps = raw.get("fps")
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, (int, float)) or not fps > 0):
        raise ValueError(f"{where}: fps: expected a positive number, got {fps!r}")
    return Recording(
        name=name,
        session=session,
        calibration=calibration,
        keypoint_format=raw["keypoint_format"],
        skeleton=skeleton,
        videos=videos,
        fps=float(fps) if fps is not None else None,
        source=_source(raw["source"], where),
        licence=raw["licence"],
        motion=raw["motion"],
        reference=raw["reference"],
    )


def read_manifest(path) -> list[Recording]:
    """The manifest's recordings; ValueError naming the file and the entry on bad input."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the manifest ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML ({exc})") from None
    if isinstance(doc, dict) and "recordings" in doc:
        doc = doc["recordings"]
    if not isinstance(doc, list) or not doc:
        raise ValueError(f"{path}: expected a list of recordings (or 'recordings:' holding one)")
    recordings = [_entry(raw, k, path) for k, raw in enumerate(doc, start=1)]
    seen: set[str] = set()
    for k, r in enumerate(recordings, start=1):
        if r.name in seen:
            raise ValueError(f"{path}: entry {k} ({r.name}): the name is used by an earlier entry")
        seen.add(r.name)
    return recordings


# ---------------------------------------------------------------- plan


def plan_variants(rec: Recording, keys=tuple(VARIANTS)) -> list[Variant]:
    """The variants of one recording, in VARIANTS' order (pose only with videos)."""
    unknown = [k for k in keys if k not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variant(s) {', '.join(unknown)} (choose from {', '.join(VARIANTS)})")
    out = []
    for key, (kind, label) in VARIANTS.items():
        if key not in keys or (key == "pose" and not rec.videos):
            continue
        imp = {"derived": (), "detector": ("--as-detector",), "videos": ("--videos",)}[kind]
        cal = {
            "derived": ("--cmc-source", "keypoints"),
            "detector": ("--cmc-source", "keypoints", "--set", f"cmc.keypoints.skeleton={rec.skeleton}"),
            "undeclared": ("--cmc-source", "keypoints"),
            "pose": ("--cmc-source", "pose"),
        }[key]
        out.append(Variant(key, label, kind, imp, cal))
    return out


def import_command(rec: Recording, bag: Path, variant: Variant) -> list[str]:
    cmd = [sys.executable, "-m", "yowo_bringup.cli", "import-multiview", str(rec.session), "-o", str(bag)]
    if rec.calibration:
        cmd += ["--calibration", str(rec.calibration)]
    if not rec.caliscope:  # a caliscope table's points are its tracker's (no format to choose)
        cmd += ["--keypoint-format", rec.keypoint_format]
        cmd += ["--fps", f"{rec.fps:g}"] if rec.fps else []
    return cmd + list(variant.import_args)


def calibrate_command(bag: Path, out: Path, variant: Variant, config: list[str], timeout_s: float) -> list[str]:
    """`yowo calibrate-cmc`: the bench's configuration first, then the variant's own options."""
    return [
        sys.executable,
        "-m",
        "yowo_bringup.cli",
        "calibrate-cmc",
        str(bag),
        "-o",
        str(out),
        "--replace",
        "--timeout",
        f"{timeout_s:g}",
        *config,
        *variant.calibrate_args,
    ]


def check_config(config: list[str]) -> None:
    """The variants set the declared skeleton themselves: a --set of it would hide the difference."""
    for arg in config:
        if arg.replace(" ", "").startswith(("cmc.keypoints.skeleton=", "cmc.keypoints.cameras=")):
            raise ValueError(
                f"--set {arg}: bench-multiview declares each recording's skeleton itself (its 'skeleton' in the "
                "manifest) for the detector variant and none for the others"
            )


# ---------------------------------------------------------------- running


def failure_reason(returncode: int | None, stdout: str, stderr: str) -> str:
    """Why a `yowo` process failed, in one line: the CLI's own message (`yowo VERB: ...`),
    else the cameras calibrate-cmc left out, else the last line it wrote."""
    if returncode is None:
        return "timed out"
    said = [ln for ln in stderr.splitlines() if re.match(r"yowo [a-z-]+: ", ln)]
    if said:
        return re.sub(r"^yowo [a-z-]+: ", "", said[-1]).strip()[:400]
    left_out = not_calibrated(stdout)
    if left_out:
        return "; ".join(left_out)[:400]
    lines = [ln.strip() for ln in (stderr or stdout).splitlines() if ln.strip()]
    return (lines[-1][:400] if lines else "") + f" (exit {returncode})"


def not_calibrated(stdout: str) -> list[str]:
    """calibrate-cmc's 'not calibrated: CAMERA: why' lines, without the prefix."""
    return [ln.split(":", 1)[1].strip() for ln in stdout.splitlines() if ln.startswith("not calibrated:")]


def _run(cmd: list[str], log: Path, timeout_s: float) -> tuple[int | None, str, str, float]:
    """(exit code or None on timeout, stdout, stderr, wall seconds); both streams kept in `log`."""
    t0 = time.monotonic()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        code, out, err = r.returncode, r.stdout, r.stderr
    except subprocess.TimeoutExpired as exc:
        code = None
        out = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else exc.stdout or ""
        err = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else exc.stderr or ""
    wall = time.monotonic() - t0
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text(f"$ {shlex.join(cmd)}\n# exit {code}, {wall:.1f} s\n--- stdout\n{out}\n--- stderr\n{err}\n")
    return code, out, err, wall


def evaluate_case(case: Case, run: Path, bag: Path, gt) -> None:
    """Fill the case's numbers from the run's cameras.yaml against the bag's reference `gt`."""
    from .results_eval import evaluate

    try:
        metrics = evaluate(run, bag, gt)
    except ValueError as exc:
        case.status, case.reason = "failed", f"eval: {exc}"
        return
    rel = metrics.get("relative")
    if rel is None:
        case.status, case.reason = "failed", metrics.get("relative_note", "no relative pose to evaluate")
        case.cameras_registered = 0
        return
    doc = yaml.safe_load((run / "cameras.yaml").read_text())
    case.groups = len({c.get("group") for c in doc.get("cameras", []) if c.get("group")})
    case.cameras_registered = len(rel["cameras"])
    s, pct = rel["summary"], rel["pos_pct_of_mean_baseline"]
    case.pos_pct_avg, case.pos_pct_max = float(pct["avg"]), float(pct["max"])
    case.pos_avg_m, case.rot_avg_deg, case.rot_max_deg = float(s["pos_avg"]), float(s["rot_avg"]), float(s["rot_max"])
    case.status = "ok"


def run_case(
    rec: Recording,
    variant: Variant,
    bag: Path,
    imported: tuple[int | None, str, float],
    run: Path,
    config: list[str],
    timeout_s: float,
) -> Case:
    """One variant of one recording: its bag's import outcome (exit, reason, seconds), then
    calibrate-cmc in its own process, then the evaluation."""
    case = Case(recording=rec.name, variant=variant.key, label=variant.label, import_s=round(imported[2], 1))
    if imported[0] != 0:
        case.reason = f"import: {imported[1]}"
        return case
    from .ground_truth import read_ground_truth

    gt = read_ground_truth(bag)
    case.cameras_total = len(gt.cameras)  # also for a calibration that fails: 0 of them
    cmd = calibrate_command(bag, run, variant, config, timeout_s)
    case.command = "yowo " + shlex.join(cmd[3:])
    code, out, err, wall = _run(cmd, run.parent / f"{run.name}.log", timeout_s + 120)
    case.wall_s, case.notes = round(wall, 1), not_calibrated(out)
    if code != 0:
        case.reason = failure_reason(code, out, err)
        if code is None:
            case.reason = f"timed out after {timeout_s + 120:.0f} s"
        return case
    evaluate_case(case, run, bag, gt)
    return case


def import_bag(
    rec: Recording, variant: Variant, bag: Path, timeout_s: float, reuse: bool
) -> tuple[int | None, str, float]:
    """(exit, reason, seconds) of importing the recording as the variant needs it."""
    if reuse and (bag / "metadata.yaml").exists():
        return 0, "", 0.0
    shutil.rmtree(bag, ignore_errors=True)  # a bag of this bench's own folder, from an earlier run
    code, out, err, wall = _run(import_command(rec, bag, variant), bag.parent / f"{bag.name}.import.log", timeout_s)
    return code, "" if code == 0 else failure_reason(code, out, err), wall


def run_multiview_bench(
    manifest: Path,
    out_dir: Path,
    markdown_path: Path | None,
    config: list[str],
    variants=tuple(VARIANTS),
    timeout_s: float = 900.0,
    resume: bool = False,
    command: str | None = None,
    log=print,
) -> dict:
    from .bench import code_version
    from .graph_bench import replace_section

    recordings = read_manifest(manifest)
    check_config(config)
    plans = {r.name: plan_variants(r, variants) for r in recordings}
    command = command or "yowo " + shlex.join(sys.argv[1:])
    out_dir.mkdir(parents=True, exist_ok=True)
    earlier = _earlier_cases(out_dir, config) if resume else {}
    results = {
        "command": command,
        "commit": code_version(),
        "date": date.today().isoformat(),
        "manifest": str(manifest),
        "config": config,
        "variants": list(variants),
        "recordings": [_recording_dict(r) for r in recordings],
        "cases": [],
    }
    for rec in recordings:
        imports: dict[str, tuple[int | None, str, float]] = {}
        for variant in plans[rec.name]:
            key = (rec.name, variant.key)
            if key in earlier:
                results["cases"].append(earlier[key])
                log(f"{rec.name} / {variant.label}: kept from the earlier results.json")
                continue
            bag = out_dir / "bags" / f"{rec.name}_{variant.bag_kind}"
            if variant.bag_kind not in imports:
                imports[variant.bag_kind] = import_bag(rec, variant, bag, timeout_s, reuse=resume)
            run = out_dir / "runs" / rec.name / variant.key
            case = run_case(rec, variant, bag, imports[variant.bag_kind], run, config, timeout_s)
            for folder in (manifest.resolve().parent, out_dir.resolve()):  # paths in reasons as the manifest gives them
                case.reason = case.reason.replace(f"{folder}/", "")
            results["cases"].append(asdict(case))
            log(f"{rec.name} / {variant.label}: {case_line(asdict(case))}")
            write_outputs(results, out_dir, markdown_path, replace_section)
    write_outputs(results, out_dir, markdown_path, replace_section)
    return results


def _earlier_cases(out_dir: Path, config: list[str]) -> dict:
    path = out_dir / "results.json"
    if not path.exists():
        return {}
    old = json.loads(path.read_text())
    if old.get("config") != config:
        return {}
    return {(c["recording"], c["variant"]): c for c in old.get("cases", [])}


def _recording_dict(r: Recording) -> dict:
    d = asdict(r)
    return d | {
        "session": str(r.session),
        "calibration": str(r.calibration) if r.calibration else None,
        "source_text": r.source_text(),
    }


def write_outputs(results: dict, out_dir: Path, markdown_path: Path | None, replace_section) -> None:
    (out_dir / "results.json").write_text(json.dumps(results, indent=1))
    section = multiview_markdown(results)
    (out_dir / "MULTIVIEW.md").write_text(section)
    if markdown_path is not None:
        replace_section(markdown_path, section, SECTION)


# ---------------------------------------------------------------- report


def _num(v, fmt: str) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:{fmt}}"


def case_line(c: dict) -> str:
    if c["status"] != "ok":
        return f"failed: {c['reason']}"
    return (
        f"{c['cameras_registered']}/{c['cameras_total']} cameras, {_num(c['pos_pct_avg'], '.2f')} / "
        f"{_num(c['pos_pct_max'], '.2f')} % of the mean baseline, {_num(c['rot_avg_deg'], '.2f')} deg, "
        f"{_num(c['wall_s'], '.0f')} s"
    )


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _median(values: list[float]) -> float | None:
    v = sorted(values)
    if not v:
        return None
    mid = len(v) // 2
    return v[mid] if len(v) % 2 else (v[mid - 1] + v[mid]) / 2


def variant_summary(cases: list[dict]) -> list[dict]:
    """Per variant over the recordings it ran on: the median and the max of the avg position
    error [% of mean baseline], the max of the max, the median and max avg rotation error."""
    out = []
    for key, (_, label) in VARIANTS.items():
        cs = [c for c in cases if c["variant"] == key]
        if not cs:
            continue
        ok = [c for c in cs if c["status"] == "ok"]
        full = [c for c in ok if c["cameras_registered"] == c["cameras_total"]]
        pos = [c["pos_pct_avg"] for c in ok]
        rot = [c["rot_avg_deg"] for c in ok]
        out.append(
            {
                "variant": key,
                "label": label,
                "recordings": len(cs),
                "ok": len(ok),
                "all_cameras": len(full),
                "failed": len(cs) - len(ok),
                "pos_pct_avg_median": _median(pos),
                "pos_pct_avg_max": max(pos, default=None),
                "pos_pct_max_max": max((c["pos_pct_max"] for c in ok), default=None),
                "rot_avg_deg_median": _median(rot),
                "rot_avg_deg_max": max(rot, default=None),
            }
        )
    return out


def multiview_markdown(results: dict) -> str:
    from .bench_markdown import produced_by
    from .bench_report import markers

    begin, end = markers(SECTION)
    recs = {r["name"]: r for r in results["recordings"]}
    config = " ".join(results["config"]) or "the defaults"
    lines = [
        begin,
        "## Real multi-camera recordings of a person (`yowo bench-multiview`)",
        "",
        *produced_by(results["command"]),
        f"Commit {results['commit']}, {results['date']}; configuration for every run: `{config}`.",
        "",
        "Each recording is imported with `yowo import-multiview` and calibrated with `yowo calibrate-cmc`, each "
        "in its own process. Variants: **derived**, the importer's ids 0/1 (head top, ground point) derived from "
        "the recorded joints; **detector**, imported `--as-detector` (the detector's own numbering + 2, no ids "
        "0/1) and calibrated with the recording's skeleton declared (`cmc.keypoints.skeleton`); **detector, "
        "undeclared**, the same recording without the declaration; **pose model**, the videos through "
        "`--cmc-source pose`. Errors after a similarity alignment of each group to the reference calibration "
        "(`yowo eval`): position as % of the mean baseline between the reference cameras; cameras: those in a "
        "calibrated group of two or more / the reference's; s: wall seconds of `calibrate-cmc`.",
        "",
        "| recording | source@commit | licence | motion | reference | variant | cameras | avg / max [% of mean "
        "baseline] | avg rot [deg] | s | notes |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    previous = None
    for c in results["cases"]:
        r = recs.get(c["recording"], {})
        first = c["recording"] != previous
        previous = c["recording"]
        info = (
            [
                c["recording"],
                r.get("source_text", "-"),
                r.get("licence", "-"),
                r.get("motion", "-"),
                r.get("reference", "-"),
            ]
            if first
            else [""] * 5
        )
        if c["status"] == "ok":
            cams = f"{c['cameras_registered']} / {c['cameras_total']}"
            err = f"{_num(c['pos_pct_avg'], '.2f')} / {_num(c['pos_pct_max'], '.2f')}"
            groups = [f"{c['groups']} groups"] if (c.get("groups") or 0) > 1 else []
            notes = "; ".join(groups + [f"not calibrated: {n}" for n in c.get("notes", [])]) or ""
            rot = _num(c["rot_avg_deg"], ".2f")
        else:
            total = c.get("cameras_total")
            cams = f"0 / {total}" if total else "-"
            err, rot, notes = "failed", "-", c["reason"]
        lines.append(
            "| "
            + " | ".join(_cell(x) for x in [*info, c["label"], cams, err, rot, _num(c.get("wall_s"), ".0f"), notes])
            + " |"
        )
    lines += [
        "",
        "Per variant over the recordings (runs that failed are counted, not averaged):",
        "",
        "| variant | calibrated / recordings (all cameras) | avg position [% of mean baseline]: median / max "
        "| max position: max | avg rot [deg]: median / max |",
        "|---|---|---|---|---|",
    ]
    for s in variant_summary(results["cases"]):
        lines.append(
            f"| {s['label']} | {s['ok']} / {s['recordings']} ({s['all_cameras']}) "
            f"| {_num(s['pos_pct_avg_median'], '.2f')} / {_num(s['pos_pct_avg_max'], '.2f')} "
            f"| {_num(s['pos_pct_max_max'], '.2f')} "
            f"| {_num(s['rot_avg_deg_median'], '.2f')} / {_num(s['rot_avg_deg_max'], '.2f')} |"
        )
    return "\n".join(lines + ["", end, ""])


# ---------------------------------------------------------------- command line


def cmd_bench_multiview(args) -> int:
    """Real multi-camera recordings (a manifest) through import-multiview and calibrate-cmc."""
    config = [a for s in (args.set or []) for a in ("--set", s)] + (["--config", args.config] if args.config else [])
    manifest, out = Path(args.manifest), Path(args.output)
    results = run_multiview_bench(
        manifest,
        out,
        Path(args.markdown) if args.markdown else None,
        config,
        variants=tuple(args.variants),
        timeout_s=args.timeout,
        resume=args.resume,
    )
    print(
        f"wrote {out / 'results.json'} and {out / 'MULTIVIEW.md'}" + (f" and {args.markdown}" if args.markdown else "")
    )
    return 0 if any(c["status"] == "ok" for c in results["cases"]) else 1


def add_verb(verbs) -> None:
    from yowo_bringup.cli import add_config_options

    p = verbs.add_parser(
        "bench-multiview",
        help="real multi-camera recordings of a person (a manifest) through import-multiview and calibrate-cmc "
        "in several variants, against their reference calibration -> results.json and a markdown section",
    )
    p.add_argument("manifest", help="YAML list of recordings (see yowo_eval.multiview_bench's docstring)")
    p.add_argument("-o", "--output", required=True, help="work folder: bags/, runs/, results.json, MULTIVIEW.md")
    p.add_argument("--markdown", help="put the section into this file (e.g. BENCHMARKS.md), replacing an earlier one")
    p.add_argument(
        "--variants",
        nargs="+",
        default=list(VARIANTS),
        choices=list(VARIANTS),
        help="which variants to run (pose: only recordings with videos)",
    )
    p.add_argument("--timeout", type=float, default=900.0, help="seconds allowed to each import and calibrate-cmc")
    p.add_argument(
        "--resume",
        action="store_true",
        help="keep the cases of OUTPUT/results.json run with the same configuration, reuse its recordings",
    )
    add_config_options(p)
    p.set_defaults(func=cmd_bench_multiview)
