"""Two people cross in one ceiling camera's rendered view and the real pose model finds them:
no person track takes in the other person (issue #46)."""

import numpy as np

from yowo_cmc.config import CmcParams
from yowo_cmc.pose_source import PoseKeypointSource
from yowo_common.geometry import inv_se3, transform_points
from yowo_sim.body import agent_keypoints_3d, agent_mesh
from yowo_sim.bystanders import SHIRTS, Clothing
from yowo_sim.capture import build_capture
from yowo_sim.presets import get_preset
from yowo_sim.render import Renderer

HZ, SPEED, STRIDE = 10.0, 1.2, 1.4  # images per second, walking speed [m/s], stride length [m]


def test_people_crossing_in_one_view_keep_their_own_tracks():
    setup = build_capture(get_preset("small"), 0)
    cam = setup.cmcs[0]
    renderer = Renderer(setup.scene)
    params = CmcParams()
    source = PoseKeypointSource(cam.name, params.pose, 1, params.people)
    other = Clothing(shirt=SHIRTS[1], trousers=(130, 110, 80))
    # Both walk along the camera's view through its target, in opposite directions, 0.45 m
    # apart sideways: they pass each other at its centre after 2 s.
    centre = np.asarray(cam.target_xy, float)
    forward = np.array([1.0, 0.0])
    side = np.array([0.0, 0.45])
    people = {}  # stamp -> true ground points (walker, other) in the image
    T_cam_world = inv_se3(cam.T_world_cam)
    for i in range(int(4 * HZ)):
        t = i / HZ
        a = centre + forward * SPEED * (t - 2.0)
        b = centre + side - forward * SPEED * (t - 2.0)
        phase = 2 * np.pi * SPEED * t / STRIDE
        meshes = [agent_mesh(a, 0.0, 1.75, phase), agent_mesh(b, np.pi, 1.65, phase + 1.0, other)]
        rgb = renderer.render(cam.camera, cam.T_world_cam, meshes).rgb
        stamp = int(1e9 + t * 1e9)
        source.push(stamp, rgb)
        grounds = [agent_keypoints_3d(a, 0.0, 1.75, phase)[1], agent_keypoints_3d(b, np.pi, 1.65, phase + 1.0)[1]]
        people[stamp] = cam.camera.project(transform_points(T_cam_world, np.array(grounds)))[0]
    tracks = [t for t in source.tracker.tracks if len(t.stamps_ns) >= 5]
    assert len(tracks) >= 2, "the model did not find both people"
    seen = set()
    for track in tracks:
        who = set()
        for stamp, pose, crowded in zip(track.stamps_ns, track.poses, track.crowded):
            if crowded:
                continue  # overlapping: which person the model drew is not well defined
            foot = np.array([(pose.box[0] + pose.box[2]) / 2, pose.box[3]])
            who.add(int(np.argmin(np.linalg.norm(people[stamp] - foot, axis=1))))
        assert len(who) == 1, f"track {track.track_id} holds both people"
        seen |= who
    assert seen == {0, 1}
    assert any(any(t.crowded) for t in tracks), "the two never overlapped in the image: no crossing tested"
