"""`yowo eval` on a results directory (yowo_eval.results_eval.evaluate)."""

import numpy as np
import pytest
import yaml

from yowo_bringup.results import pose_entry
from yowo_common.geometry import look_at
from yowo_eval import results_eval as yowo_eval
from yowo_eval.ground_truth import GroundTruth


def test_isolated_cameras_get_registration_errors_and_no_table_of_nan(tmp_path, monkeypatch):
    gt = {"cam00": look_at([0.0, 0.0, 3.0], [1.0, 1.0, 0.0]), "cam01": look_at([4.0, 0.0, 3.0], [3.0, 1.0, 0.0])}
    est = {n: T.copy() for n, T in gt.items()}
    est["cam01"][:3, 3] += [0.0, 0.1, 0.0]
    doc = {
        "frame": "map",
        "cameras": [{"name": n, "group": None, "T_world_camera": pose_entry(T)} for n, T in est.items()],
    }
    (tmp_path / "cameras.yaml").write_text(yaml.safe_dump(doc))
    monkeypatch.setattr(yowo_eval, "read_ground_truth", lambda bag: GroundTruth(cameras=gt, ego=None, floor=[]))
    m = yowo_eval.evaluate(tmp_path, "rec.mcap")
    assert m["registration"]["summary"]["pos_max"] == pytest.approx(0.1)
    assert "relative" not in m and "no group" in m["relative_note"]
    assert np.isfinite(m["registration"]["summary"]["pos_avg"])
