"""The CMC stage on every camera's tracks: one camera whose data makes the group SfM fail
is left out with the error; the others are calibrated."""

import numpy as np
import pytest

from cmc_synthetic import ceiling_camera, loop_walk, observe
from yowo_cmc.config import CmcParams
from yowo_cmc.pipeline import calibrate_cmcs_apart


def test_a_camera_the_group_sfm_fails_on_is_left_out_and_the_others_calibrated():
    cams = {
        "c1": ceiling_camera(0.3, 0.3, (2.5, 2.5)),
        "c2": ceiling_camera(4.7, 0.3, (2.5, 2.5), z=3.3),
        "c3": ceiling_camera(2.5, 4.7, (2.5, 2.3)),
        "c4": ceiling_camera(4.7, 4.7, (2.5, 2.5)),
    }
    tracks = observe(cams, loop_walk((2.5, 2.5), (1.5, 1.2), 10.0), 12.0, sigma_px=0.5, seed=0)
    good = calibrate_cmcs_apart(tracks[:3])
    tracks[3].camera.K = tracks[3].camera.K.copy()
    tracks[3].camera.K[0, 0] = np.nan  # intrinsics no check caught
    grouping = calibrate_cmcs_apart(tracks)
    assert [sorted(g.names) for g in grouping.groups] == [["c1", "c2", "c3"]]
    assert grouping.ungrouped["c4"].startswith("the group SfM fails with this camera's data ("), grouping.ungrouped
    for n in ("c1", "c2", "c3"):
        np.testing.assert_allclose(grouping.groups[0].T_local_cam[n], good.groups[0].T_local_cam[n], atol=1e-9)
    # Beyond isolate_failure_max_cameras the failure is the stage's.
    with pytest.raises(np.linalg.LinAlgError):
        calibrate_cmcs_apart(tracks, CmcParams(isolate_failure_max_cameras=3))
