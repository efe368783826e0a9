"""Isolated-CMC registration from the agent track: a straight walk puts every agent
point in one vertical plane, where PnP has a mirrored solution under the agent."""

import numpy as np

from yowo_cmc.keypoint_tracks import CameraTracks, KeypointTrack
from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at
from yowo_fusion.isolated import register_by_agent
from yowo_fusion.records import AgentTrack


def test_straight_walk_registers_the_ceiling_camera_not_its_mirror_image():
    rng = np.random.default_rng(0)
    camera = CameraModel.from_fov(640, 480, 80.0)
    T_world_cam = look_at(np.array([0.5, -1.0, 2.6]), np.array([0.0, 1.5, 0.8]))
    stamps = np.arange(120, dtype=np.int64) * 100_000_000
    x = np.linspace(-2.0, 2.0, len(stamps))
    walk = {
        0: np.column_stack([x, np.full_like(x, 1.5), 1.7 + 0.02 * np.sin(6 * x)]),  # head top, a little bob
        1: np.column_stack([x, np.full_like(x, 1.5), np.zeros_like(x)]),
    }  # ground point
    tracks = {}
    for kp, P in walk.items():
        uv, _ = camera.project_world(T_world_cam, P)
        tracks[kp] = KeypointTrack(stamps, uv + rng.normal(0, 1.0, uv.shape), np.full(len(stamps), 0.9))
    agent = AgentTrack(np.concatenate([stamps, stamps]), np.repeat([0, 1], len(stamps)), np.vstack([walk[0], walk[1]]))
    result, why = register_by_agent(CameraTracks("cam", camera, tracks), agent)
    assert result is not None, why
    assert np.linalg.norm(result.T_world_cam[:3, 3] - T_world_cam[:3, 3]) < 0.05
    cos = (np.trace(result.T_world_cam[:3, :3].T @ T_world_cam[:3, :3]) - 1) / 2
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 1.0


def test_of_two_planar_solutions_the_one_above_the_agent_wins():
    import cv2

    from yowo_fusion.isolated import IsolatedParams, _score

    camera = CameraModel.from_fov(640, 480, 80.0)
    T_world_cam = look_at(np.array([0.5, -1.0, 2.6]), np.array([0.0, 1.5, 0.8]))
    x = np.linspace(-2.0, 2.0, 40)
    P = np.vstack([np.column_stack([x, np.full_like(x, 1.5), np.full_like(x, z)]) for z in (1.7, 0.0)])
    uv, _ = camera.project_world(T_world_cam, P)
    uv = uv + np.random.default_rng(1).normal(0, 1.0, uv.shape)
    _, rvecs, tvecs, _ = cv2.solvePnPGeneric(P, uv, camera.K, None, flags=cv2.SOLVEPNP_IPPE)  # coplanar: 2 poses
    scores = [_score(P, uv, camera, rv, tv, IsolatedParams()) for rv, tv in zip(rvecs, tvecs)]
    assert len(scores) == 2 and sorted(s[0][0] for s in scores) == [False, True]  # one of them is under the agent
    (_, T, _) = max(scores, key=lambda s: s[0])
    assert np.linalg.norm(T[:3, 3] - T_world_cam[:3, 3]) < 0.05


def test_an_agent_standing_still_in_view_is_a_reason_not_a_crash():
    camera = CameraModel.from_fov(640, 480, 80.0)
    T_world_cam = look_at(np.array([0.5, -1.0, 2.6]), np.array([0.0, 1.5, 0.8]))
    stamps = np.arange(60, dtype=np.int64) * 100_000_000
    head = np.tile([[0.2, 1.4, 1.7]], (len(stamps), 1))  # only the head top is seen, never moving
    uv, _ = camera.project_world(T_world_cam, head)
    tracks = {0: KeypointTrack(stamps, uv, np.full(len(stamps), 0.9))}
    agent = AgentTrack(stamps, np.zeros(len(stamps), np.int64), head)
    result, why = register_by_agent(CameraTracks("cam", camera, tracks), agent)
    assert result is None and "stood still" in why
