"""cameras.yaml: a covariance the fusion could not compute (NaN) is written as unknown,
not as NaN sigmas; a real one gives its standard deviations."""
import numpy as np
import yaml

from yowo_bringup.results import write_cameras_yaml
from yowo_fusion.pipeline import RegisteredCmc


def _camera(name: str, covariance: np.ndarray) -> RegisteredCmc:
    return RegisteredCmc(name, "g0", "group_sfm", "weak", "covariance unavailable", np.eye(4), covariance,
                         np.diag([500.0, 500.0, 1.0]), 0.5, 100, 10)


def test_unknown_covariance_is_written_as_unknown(tmp_path):
    known = np.diag([1e-4, 4e-4, 9e-4, 1e-6, 1e-6, 1e-6])
    write_cameras_yaml(tmp_path / "cameras.yaml", [_camera("a", known), _camera("b", np.full((6, 6), np.nan))])
    a, b = yaml.safe_load((tmp_path / "cameras.yaml").read_text())["cameras"]
    np.testing.assert_allclose(a["sigma"]["position_m"], [0.01, 0.02, 0.03])
    assert b["covariance"] is None and b["sigma"].startswith("unknown")
    assert "T_world_camera" in b   # the pose itself is still reported
