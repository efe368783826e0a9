"""Measures the pose models of yowo_cmc.pose_model (docs/pose_model.md).

photos (default): joint error against the hand-marked joints of
src/yowo_cmc/test/test_pose_model.py, and speed on 640x480 frames with one
interpreter thread on one core.

    taskset -c 0 .venv/bin/python -m yowo_eval.pose_model_bench [photos]

sim: the pose-model source (PoseKeypointSource, as the keypoint trackers run it) on a
simulated recording, against the simulator's ground truth (evaluation only): per
camera the detection rate over the images where the agent is in view, the per-joint
pixel error against the true projection of the body joint, and the left/right swap
rate (a pair is swapped when the crossed assignment is nearer the truth).

    .venv/bin/yowo simulate --preset small --seed 0 -o bags/small_s0
    .venv/bin/python -m yowo_eval.pose_model_bench sim bags/small_s0 --preset small --seed 0

multiview: the pose-model source on a real multi-camera recording with a reference
calibration (yowo import-multiview ... --videos): each keypoint id seen by >= 3 cameras
in one frame is triangulated with the reference poses and intrinsics, and its
reprojection residual per camera measures the keypoint noise without the group SfM
(--recorded: the recording's own keypoints instead, e.g. OpenPose's).

    .venv/bin/python -m yowo_eval.pose_model_bench multiview p2s_vid [--set refine_crop=false]

The true body joints come from rebuilding the recording's walk from its preset and seed
(yowo_sim.capture.build_capture); the script checks them against the recording's
/gt/agent/keypoints first.
"""

import argparse
import collections
import dataclasses
import importlib.util
import json
import pathlib
import time

import cv2
import numpy as np

from yowo_cmc.params import PeopleParams, PoseModelParams
from yowo_cmc.pose_keypoints import ID_OFFSET, MOVENET_JOINTS
from yowo_cmc.pose_model import PoseDetector
from yowo_cmc.pose_source import PoseKeypointSource

ROOT = pathlib.Path(__file__).resolve().parents[3]  # the source checkout (the photos are marked in its tests)


def photos():
    spec = importlib.util.spec_from_file_location("marks", ROOT / "src/yowo_cmc/test/test_pose_model.py")
    marks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(marks)
    for model, params in (
        ("movenet", PoseModelParams()),
        ("movenet-whole-frame", PoseModelParams(refine_crop=False)),
        ("blazepose", PoseModelParams(model="blazepose")),
    ):
        det = PoseDetector(params)
        errors = []
        for image, people in marks.MARKS.items():
            rgb = marks.photo(image)
            found = det.detect(rgb)
            for person in people:
                best = marks.match(found, person)
                nose = None if best is None else np.hypot(*(best.uv[2] - person["joints"]["nose"]))
                if nose is None or nose > 0.2 * person["height"]:  # the nearest is somebody else
                    print(f"{model}: {image} {person['who']}: not found")
                    continue
                for name, err in marks.joint_errors(det, best, person).items():
                    errors.append(err / person["height"])
                    print(
                        f"{model}: {image:10s} {person['who']:8s} {name:15s} {err:5.1f} px "
                        f"({100 * err / person['height']:.1f} % of {person['height']} px)"
                    )
        e = np.array(errors) * 100
        print(f"{model}: {len(e)} joints, error median {np.median(e):.1f} %, max {e.max():.1f} % of person height")
        frame = cv2.resize(marks.photo("bus")[230:840], (640, 480), interpolation=cv2.INTER_AREA)
        for _ in range(5):
            det.detect(frame)
        # As PoseKeypointSource runs it: the whole frame, then (refine_crop) the agent's crop.
        n, t0 = 50, time.perf_counter()
        for _ in range(n):
            people = det.detect(frame, refine=False)
            det.refine(frame, people[0])
        dt = (time.perf_counter() - t0) / n
        print(
            f"{model}: 640x480, 1 thread: {1000 * dt:.1f} ms per frame, {1 / dt:.1f} frames/s "
            f"({len(det.detect(frame))} persons"
            + ("; the agent refined on its crop)" if params.refine_crop and params.model == "movenet" else ")")
        )


# --- sim ---------------------------------------------------------------------------------------
NAMES = ("head_top", "ground") + MOVENET_JOINTS  # by id
PAIRS = [
    (i + ID_OFFSET, MOVENET_JOINTS.index("right" + n[4:]) + ID_OFFSET)
    for i, n in enumerate(MOVENET_JOINTS)
    if n.startswith("left")
]


def truth(bag, preset: str, seed: int):
    """Per camera: model, per image stamp (camera clock) the (19, 2) true pixels of ids
    0..18 and a (19,) in-image mask; checked against the recording's ground truth."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import camera_info_to_model, pose_to_matrix, stamp_to_ns
    from yowo_common.topics import GT_AGENT_KEYPOINTS, parse_cmc_topic, parse_gt_cmc_pose_topic
    from yowo_sim.body import agent_joints_3d, agent_keypoints_3d
    from yowo_sim.capture import START_NS, build_capture
    from yowo_sim.presets import get_preset

    setup = build_capture(get_preset(preset), seed)
    walk, offsets = setup.walk, setup.clock_offsets_ns

    def state(truth_ns):
        return walk.state_at((truth_ns - START_NS) / 1e9)

    poses, models, stamps, worst = {}, {}, collections.defaultdict(list), 0.0
    for topic, _, msg in read_messages(bag):
        if topic == GT_AGENT_KEYPOINTS:
            xy, heading, phase = state(stamp_to_ns(msg.header.stamp))
            kp = agent_keypoints_3d(xy, heading, walk.height_m, phase)
            got = np.array([[p.position.x, p.position.y, p.position.z] for p in msg.poses])
            worst = max(worst, float(np.abs(got - np.array([kp[k] for k in sorted(kp)])).max()))
        elif parse_gt_cmc_pose_topic(topic):
            poses[parse_gt_cmc_pose_topic(topic)] = pose_to_matrix(msg.pose)
        elif (parse_cmc_topic(topic) or ("", ""))[1] == "camera_info":
            name = parse_cmc_topic(topic)[0]
            models.setdefault(name, camera_info_to_model(msg))
            stamps[name].append(stamp_to_ns(msg.header.stamp))
    if worst > 1e-4:
        raise SystemExit(f"the rebuilt walk is not this recording's ({worst:.3f} m off): wrong --preset/--seed?")
    out = {}
    for name, cam in models.items():
        per = {}
        for s in stamps[name]:
            xy, heading, phase = state(s - offsets.get(name, 0))
            kp = agent_keypoints_3d(xy, heading, walk.height_m, phase)
            pts = np.vstack([kp[0], kp[1], agent_joints_3d(xy, heading, walk.height_m, phase)])
            uv, ok = cam.project_world(poses[name], pts)
            inside = (
                ok
                & (uv[:, 0] >= -0.5)
                & (uv[:, 0] < cam.width - 0.5)
                & (uv[:, 1] >= -0.5)
                & (uv[:, 1] < cam.height - 0.5)
            )
            per[s] = (uv, inside)
        out[name] = per
    return out


def run_source(bag, params: PoseModelParams):
    """Per camera: {stamp: KeypointFrame} the source emitted, and {stamp: persons found}."""
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import decode_color, stamp_to_ns
    from yowo_common.topics import parse_cmc_topic

    sources, emitted, persons = {}, collections.defaultdict(dict), collections.defaultdict(dict)
    t0, n = time.perf_counter(), 0
    for topic, _, msg in read_messages(bag):
        name, kind = parse_cmc_topic(topic) or ("", "")
        if not kind.startswith("image"):
            continue
        if name not in sources:
            sources[name] = PoseKeypointSource(name, params, 1, PeopleParams())
            detect = sources[name].detector.detect

            def counting(rgb, detect=detect, name=name, **kw):  # records what the model found, unchanged
                people = detect(rgb, **kw)
                persons[name][stamp] = len(people)  # noqa: B023 (the frame being detected: read when called)
                return people

            sources[name].detector.detect = counting
        stamp = stamp_to_ns(msg.header.stamp)
        sources[name].push(stamp, decode_color(msg))
        n += 1
    for name, source in sources.items():
        for f in source.flush(None):
            emitted[name][f.stamp_ns] = f
    return emitted, persons, sources, (time.perf_counter() - t0) / max(n, 1)


def sim(args):
    gt = truth(args.bag, args.preset, args.seed)
    changes = _changes(args.set) | ({"lr_resolve": False} if args.model_labels else {})
    emitted, persons, sources, dt = run_source(args.bag, dataclasses.replace(PoseModelParams(), **changes))
    ids = np.arange(len(NAMES))
    err = collections.defaultdict(list)  # id -> errors [px]
    rel = collections.defaultdict(list)  # id -> errors / person height in the image
    either = collections.defaultdict(list)  # id -> error to the nearer of its own and its pair's truth
    other = {a: b for a, b in PAIRS} | {b: a for a, b in PAIRS}
    cams = []
    swaps = collections.defaultdict(lambda: [0, 0])  # pair -> [swapped, both emitted]
    for name in sorted(gt):
        visible = {s for s, (_, inside) in gt[name].items() if inside[2:].sum() >= 9}  # most of the body in view
        seen = {s for s in visible if persons[name].get(s, 0) > 0}
        got = {s: f for s, f in emitted[name].items() if s in visible}
        false = len(set(emitted[name]) - visible)
        cam_swaps = [0, 0]
        gross = [0, 0]
        for s, f in got.items():
            uv_true, inside = gt[name][s]
            height = np.linalg.norm(uv_true[0] - uv_true[1])
            at = dict(zip(f.ids.tolist(), f.uv))
            for k, uv in at.items():
                e = float(np.linalg.norm(uv - uv_true[k]))
                err[k].append(e)
                rel[k].append(e / height)
                either[k].append(min(e, float(np.linalg.norm(uv - uv_true[other[k]]))) if k in other else e)
                gross[0] += e > 0.15 * height
                gross[1] += 1
            for a, b in PAIRS:
                if a in at and b in at:
                    kept = np.linalg.norm(at[a] - uv_true[a]) + np.linalg.norm(at[b] - uv_true[b])
                    crossed = np.linalg.norm(at[a] - uv_true[b]) + np.linalg.norm(at[b] - uv_true[a])
                    swaps[a][0] += crossed < kept
                    swaps[a][1] += 1
                    cam_swaps[0] += crossed < kept
                    cam_swaps[1] += 1
        cams.append(
            dict(
                camera=name,
                images=len(gt[name]),
                visible=len(visible),
                model_found=len(seen),
                agent_emitted=len(got),
                emitted_outside_view=false,
                detection_rate=len(got) / max(len(visible), 1),
                swap_rate=cam_swaps[0] / max(cam_swaps[1], 1),
                pairs=cam_swaps[1],
                gross_rate=gross[0] / max(gross[1], 1),
                keypoints=gross[1],
                summary=sources[name].summary() if name in sources else "no images",
            )
        )
    print(f"{args.bag}: pose model {changes or 'defaults'}: {1000 * dt:.1f} ms per image (model + source)\n")
    print(
        "| camera | images | agent in view | model found a person | agent emitted (rate) | emitted, agent not in"
        " view | L/R swapped pairs | keypoints > 15 % of height off |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for c in cams:
        print(
            f"| {c['camera']} | {c['images']} | {c['visible']} | {c['model_found']} | {c['agent_emitted']} "
            f"({100 * c['detection_rate']:.0f} %) | {c['emitted_outside_view']} | {100 * c['swap_rate']:.1f} % of "
            f"{c['pairs']} | {100 * c['gross_rate']:.1f} % of {c['keypoints']} |"
        )
    print("\n| id | joint | n | median px | p90 px | median % of height | median px, either side | L/R swapped |")
    print("|---|---|---|---|---|---|---|---|")
    joints = []
    for k in ids:
        if not err[k]:
            continue
        sw = swaps.get(int(k))
        e = np.array(err[k])
        row = dict(
            id=int(k),
            joint=NAMES[k],
            n=len(e),
            median_px=float(np.median(e)),
            p90_px=float(np.percentile(e, 90)),
            median_rel=float(np.median(rel[k])),
            median_either_px=float(np.median(either[k])),
            swap_rate=None if sw is None else sw[0] / max(sw[1], 1),
        )
        joints.append(row)
        print(
            f"| {k} | {NAMES[k]} | {row['n']} | {row['median_px']:.1f} | {row['p90_px']:.1f} | "
            f"{100 * row['median_rel']:.1f} | {row['median_either_px']:.1f} | "
            + ("" if sw is None else f"{100 * row['swap_rate']:.1f} % of {sw[1]}")
            + " |"
        )
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(dict(bag=str(args.bag), cameras=cams, joints=joints), indent=1))


# --- multiview ---------------------------------------------------------------------------------
def _changes(pairs) -> dict:
    """KEY=VALUE strings -> PoseModelParams fields, typed as their defaults."""
    out = {}
    for kv in pairs:
        k, v = kv.split("=", 1)
        kind = type(getattr(PoseModelParams(), k))
        out[k] = v.lower() in ("1", "true", "yes") if kind is bool else kind(v)
    return out


def multiview(args):
    from yowo_cmc.keypoint_input import frame_from_msg
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import camera_info_to_model, decode_color, pose_to_matrix, stamp_to_ns
    from yowo_common.topics import parse_cmc_topic, parse_gt_cmc_pose_topic

    changes = _changes(args.set)
    params = dataclasses.replace(PoseModelParams(), **changes)
    poses, models, sources, frames = {}, {}, {}, collections.defaultdict(dict)
    for topic, _, msg in read_messages(args.bag):
        if parse_gt_cmc_pose_topic(topic):
            poses[parse_gt_cmc_pose_topic(topic)] = pose_to_matrix(msg.pose)
            continue
        name, kind = parse_cmc_topic(topic) or ("", "")
        if kind == "camera_info":
            models.setdefault(name, camera_info_to_model(msg))
        elif kind == "agent_keypoints" and args.recorded:
            f = frame_from_msg(msg)
            frames[name][f.stamp_ns] = f
        elif kind.startswith("image") and not args.recorded:
            source = sources.setdefault(name, PoseKeypointSource(name, params, 1, PeopleParams()))
            source.push(stamp_to_ns(msg.header.stamp), decode_color(msg))
    for name, source in sources.items():
        for f in source.flush(None):
            frames[name][f.stamp_ns] = f
    names = sorted(frames)
    P = {n: models[n].K @ np.linalg.inv(poses[n])[:3] for n in names}  # ideal pinhole projections
    res = collections.defaultdict(list)  # camera -> residuals [px]
    per_id = collections.defaultdict(list)
    for stamp in sorted(set().union(*(frames[n] for n in names))):
        obs = collections.defaultdict(dict)  # id -> camera -> raw uv
        for n in names:
            f = frames[n].get(stamp)
            if f is not None:
                for k, uv, c in zip(f.ids, f.uv, f.confidence):
                    if c >= params.min_keypoint_score:
                        obs[int(k)][n] = uv
        for k, seen in obs.items():
            if len(seen) < 3:
                continue
            rows = []
            for n, uv in seen.items():
                x = models[n].undistort_pixels(uv)[0]
                rows += [x[0] * P[n][2] - P[n][0], x[1] * P[n][2] - P[n][1]]
            X = np.linalg.svd(np.array(rows))[2][-1]
            X = X[:3] / X[3]
            for n, uv in seen.items():
                got, ok = models[n].project_world(poses[n], X[None])
                if ok[0]:
                    e = float(np.hypot(*(got[0] - uv)))
                    res[n].append(e)
                    per_id[k].append(e)
    # Reference-free: the frame-to-frame jitter. The person moves little between frames (60 fps), so
    # the second difference of a keypoint's track is its noise: sigma ~ |x0 - 2 x1 + x2| / sqrt(6).
    jitter = collections.defaultdict(list)
    for n in names:
        stamps = sorted(frames[n])
        period = np.median(np.diff(stamps)) if len(stamps) > 1 else 0
        for s0, s1, s2 in zip(stamps, stamps[1:], stamps[2:]):
            if abs(s2 - s0 - 2 * period) > 0.5 * period:
                continue
            at = [
                {int(k): uv for k, uv, c in zip(f.ids, f.uv, f.confidence) if c >= params.min_keypoint_score}
                for f in (frames[n][s0], frames[n][s1], frames[n][s2])
            ]
            for k in set(at[0]) & set(at[1]) & set(at[2]):
                jitter[n].append(float(np.hypot(*(at[0][k] - 2 * at[1][k] + at[2][k]))) / np.sqrt(6))
    what = "recorded keypoints" if args.recorded else f"pose model {changes or 'defaults'}"
    print(f"{args.bag}: {what}; residual of each keypoint to its reference-calibration triangulation (>= 3 views)")
    print("and (jitter) each keypoint's noise from its track's second difference over 3 consecutive frames")
    print("| camera | keypoints | residual median px | p75 px | p90 px | jitter median px |")
    print("|---|---|---|---|---|---|")
    for n in names + ["all"]:
        e = np.array(sum(res.values(), []) if n == "all" else res[n])
        j = np.array(sum(jitter.values(), []) if n == "all" else jitter[n])
        print(
            f"| {n} | {len(e)} | {np.median(e):.1f} | {np.percentile(e, 75):.1f} | {np.percentile(e, 90):.1f} | "
            f"{np.median(j):.2f} |"
        )
    print("per id, median px: " + ", ".join(f"{k}: {np.median(v):.1f}" for k, v in sorted(per_id.items())))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what")
    sub.add_parser("photos", help="hand-marked real photographs, and speed")
    s = sub.add_parser("sim", help="a simulated recording against its ground truth")
    s.add_argument("bag")
    s.add_argument("--preset", required=True)
    s.add_argument("--seed", type=int, required=True)
    s.add_argument("--json", help="write the numbers here too")
    s.add_argument("--model-labels", action="store_true", help="the model's own left/right (lr_resolve off)")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a PoseModelParams field")
    m = sub.add_parser("multiview", help="a real multi-camera recording against its reference calibration")
    m.add_argument("bag")
    m.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a PoseModelParams field")
    m.add_argument("--recorded", action="store_true", help="the recording's keypoints, not the pose model's")
    a = ap.parse_args()
    {"sim": sim, "multiview": multiview}.get(a.what, lambda _: photos())(a)
