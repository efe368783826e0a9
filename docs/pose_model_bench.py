"""Measures the pose models of yowo_cmc.pose_model (docs/pose_model.md): joint
error against the hand-marked joints of src/yowo_cmc/test/test_pose_model.py, and
speed on 640x480 frames with one interpreter thread on one core.

    taskset -c 0 .venv/bin/python docs/pose_model_bench.py
"""
import importlib.util
import pathlib
import time

import cv2
import numpy as np

from yowo_cmc.pose_model import PoseDetector, PoseModelParams

ROOT = pathlib.Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("marks", ROOT / "src/yowo_cmc/test/test_pose_model.py")
marks = importlib.util.module_from_spec(spec)
spec.loader.exec_module(marks)

for model in ("movenet", "blazepose"):
    det = PoseDetector(PoseModelParams(model=model))
    errors = []
    for image, people in marks.MARKS.items():
        rgb = marks.photo(image)
        found = det.detect(rgb)
        for person in people:
            best = marks.match(found, person)
            nose = None if best is None else np.hypot(*(best.uv[2] - person["joints"]["nose"]))
            if nose is None or nose > 0.2 * person["height"]:   # the nearest is somebody else
                print(f"{model}: {image} {person['who']}: not found")
                continue
            for name, err in marks.joint_errors(det, best, person).items():
                errors.append(err / person["height"])
                print(f"{model}: {image:10s} {person['who']:8s} {name:15s} {err:5.1f} px "
                      f"({100 * err / person['height']:.1f} % of {person['height']} px)")
    e = np.array(errors) * 100
    print(f"{model}: {len(e)} joints, error median {np.median(e):.1f} %, max {e.max():.1f} % of person height")
    frame = cv2.resize(marks.photo("bus")[230:840], (640, 480), interpolation=cv2.INTER_AREA)
    for _ in range(5):
        det.detect(frame)
    n, t0 = 50, time.perf_counter()
    for _ in range(n):
        det.detect(frame)
    dt = (time.perf_counter() - t0) / n
    print(f"{model}: 640x480, 1 thread: {1000 * dt:.1f} ms per frame, {1 / dt:.1f} frames/s "
          f"({len(det.detect(frame))} persons)")
