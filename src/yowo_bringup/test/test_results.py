"""cameras.yaml: a covariance the fusion could not compute (NaN) is written as unknown,
not as NaN sigmas; a real one gives its standard deviations."""

import numpy as np
import yaml

from yowo_bringup.results import write_cameras_yaml
from yowo_common.camera import CameraModel
from yowo_fusion.records import RegisteredCmc


def _camera(name: str, covariance: np.ndarray) -> RegisteredCmc:
    return RegisteredCmc(
        name=name,
        group="g0",
        method="group_sfm",
        status="weak",
        reason="covariance unavailable",
        T_world_cam=np.eye(4),
        covariance=covariance,
        camera=CameraModel(640, 480, np.diag([500.0, 500.0, 1.0])),
        rmse_px=0.5,
        num_agent=100,
        num_scene=10,
    )


def test_unknown_covariance_is_written_as_unknown(tmp_path):
    known = np.diag([1e-4, 4e-4, 9e-4, 1e-6, 1e-6, 1e-6])
    write_cameras_yaml(tmp_path / "cameras.yaml", [_camera("a", known), _camera("b", np.full((6, 6), np.nan))])
    a, b = yaml.safe_load((tmp_path / "cameras.yaml").read_text())["cameras"]
    np.testing.assert_allclose(a["sigma"]["position_m"], [0.01, 0.02, 0.03])
    assert b["covariance"] is None and b["sigma"].startswith("unknown")
    assert "T_world_camera" in b  # the pose itself is still reported


def test_ground_truth_agent_in_the_map_frame_projects_onto_the_detections(tmp_path):
    """read_ground_truth moves the cameras into YOWO's map frame (the first ego pose);
    T_map_sim takes the simulator's other ground truth (the agent) there too. The
    Cramer-Rao bound had mixed the two frames (agent points behind the cameras)."""
    from dataclasses import replace

    from yowo_common.geometry import transform_points
    from yowo_common.ros.bag import read_messages
    from yowo_common.rosconv import camera_info_to_model, points_to_array, stamp_to_ns
    from yowo_common.topics import GT_AGENT_KEYPOINTS
    from yowo_eval.ground_truth import read_ground_truth
    from yowo_sim.capture import generate
    from yowo_sim.presets import get_preset

    bag = tmp_path / "tiny"
    generate(replace(get_preset("tiny"), cmc_images=False), 0, bag)
    truth = read_ground_truth(bag)
    assert not np.allclose(truth.T_map_sim, np.eye(4))  # else this test would show nothing
    agent, info, detections = {}, {}, []
    for topic, _, msg in read_messages(bag):
        if topic == GT_AGENT_KEYPOINTS:
            agent[stamp_to_ns(msg.header.stamp)] = transform_points(
                truth.T_map_sim, points_to_array([p.position for p in msg.poses])
            )
        elif topic.startswith("/cmc/") and topic.endswith("/camera_info"):
            info.setdefault(topic.split("/")[2], camera_info_to_model(msg))
        elif topic.endswith("/agent_keypoints"):
            detections.append(msg)
    errors = [
        np.linalg.norm(
            info[m.camera_name].project_world(truth.cameras[m.camera_name], P[k.id][None])[0][0] - [k.x, k.y]
        )
        for m in detections
        if (P := agent.get(stamp_to_ns(m.header.stamp))) is not None
        for k in m.keypoints
        if k.id in (0, 1)
    ]
    assert len(errors) > 100 and np.median(errors) < 2.5  # head top 1 px, ground point 1.5 px noise
