"""Bystanders in the simulator (issue #46): other people walk through the rooms for the
whole walk, show in the CMC and ego images where they are in view, are recorded on
/gt/bystanders/ only, and change nothing of the agent's recording."""

from collections import defaultdict
from dataclasses import replace

import numpy as np
import pytest
import shapely
import yaml

from yowo_common.geometry import inv_se3, transform_points
from yowo_common.ros.bag import read_messages
from yowo_common.rosconv import (
    decode_color,
    message_fields,
    points_to_array,
)
from yowo_common.topics import (
    GT_BYSTANDER_INFO,
    GT_BYSTANDER_KEYPOINTS,
)
from yowo_sim.body import SHIRT, TROUSERS, agent_joints_3d, agent_mesh
from yowo_sim.bystanders import BystanderSpec
from yowo_sim.capture import START_NS, agent_in_view, build_capture, generate
from yowo_sim.presets import get_preset
from yowo_sim.render import Renderer

TWO = BystanderSpec(count=2, crossing_share=0.5)


def _tiny(count: int):
    # Raw images: a bystander's pixels compare exactly (no JPEG); a low ego rate keeps it short.
    return get_preset("tiny", raw_images=True, ego_hz=5.0, bystanders=replace(TWO, count=count))


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """The same `tiny` recording without and with two bystanders."""
    root = tmp_path_factory.mktemp("bystanders")
    out = {}
    for count in (0, 2):
        generate(_tiny(count), 3, root / f"n{count}")
        msgs = defaultdict(list)
        for topic, t, msg in read_messages(root / f"n{count}"):
            msgs[topic].append((t, msg))
        out[count] = msgs
    return out


def _is_image(topic: str) -> bool:
    return "/image_raw" in topic


def test_the_agents_recording_is_the_same_with_bystanders(pair):
    without, with_ = pair[0], pair[2]
    assert not [t for t in without if t.startswith("/gt/bystanders")]
    assert set(with_) - set(without) == {GT_BYSTANDER_KEYPOINTS, GT_BYSTANDER_INFO}
    # Everything but the images: poses, keypoints (the agent's only), clocks, IMU.
    for topic, msgs in without.items():
        if not _is_image(topic):
            assert [(t, message_fields(m)) for t, m in msgs] == [(t, message_fields(m)) for t, m in with_[topic]], topic
        else:
            assert [t for t, _ in msgs] == [t for t, _ in with_[topic]], topic
    # The bystanders' ground truth: one message per CMC frame at its true stamp, two points each.
    cmc_stamps = sorted(
        t for topic, msgs in with_.items() if topic.startswith("/cmc/") and "info" in topic for t, _ in msgs
    )
    gt = with_[GT_BYSTANDER_KEYPOINTS]
    assert [t for t, _ in gt] == cmc_stamps
    assert all(len(m.poses) == 2 * TWO.count and m.header.frame_id == "map" for _, m in gt)


def test_the_walk_cameras_and_clocks_are_the_same_with_bystanders():
    preset = get_preset("small", cmc_clock_offset_s=0.5)
    a = build_capture(preset, 5)
    b = build_capture(replace(preset, bystanders=BystanderSpec(count=3)), 5)
    assert len(a.bystanders) == 0 and len(b.bystanders) == 3
    np.testing.assert_array_equal(a.walk.xy, b.walk.xy)
    np.testing.assert_array_equal(a.walk.head_yaw, b.walk.head_yaw)
    assert [c.T_world_cam.tolist() for c in a.cmcs] == [c.T_world_cam.tolist() for c in b.cmcs]
    assert a.clock_offsets_ns == b.clock_offsets_ns and a.clock_offsets_ns
    assert a.rng.random() == b.rng.random()  # the noise stream goes on alike


def _visible_midpoints(camera, T_world_cam, background_depth, gt_points) -> list:
    """Pixels of the bystanders' middles (half their height) that nothing of the scene hides."""
    out = []
    for head, ground in gt_points.reshape(-1, 2, 3):
        mid = 0.5 * (head + ground)
        uv, ok = camera.project_world(T_world_cam, mid[None])
        z = (np.linalg.inv(T_world_cam) @ [*mid, 1.0])[2]
        if not (ok[0] and camera.in_image(uv, margin=4).all() and z > 0.5):
            continue
        u, v = np.round(uv[0]).astype(int)
        if np.nanmin(background_depth[v - 3 : v + 4, u - 3 : u + 4]) > z + 0.3:
            out.append((u, v))
    return out


def _differs(a: np.ndarray, b: np.ndarray, u: int, v: int) -> bool:
    win = np.s_[v - 2 : v + 3, u - 2 : u + 3]
    return np.abs(a[win].astype(float) - b[win].astype(float)).mean() > 12.0


def test_the_images_show_the_bystanders_in_view(pair):
    without, with_ = pair[0], pair[2]
    setup = build_capture(_tiny(2), 3)
    renderer = Renderer(setup.scene)
    gt = {t: points_to_array([p.position for p in m.poses]) for t, m in with_[GT_BYSTANDER_KEYPOINTS]}
    cams = {c.name: c for c in setup.cmcs}
    seen = shown = 0
    for topic in with_:
        if not (topic.startswith("/cmc/") and _is_image(topic)):
            continue
        cmc = cams[topic.split("/")[2]]
        for (t, m2), (_, m0) in zip(with_[topic], without[topic]):
            img2, img0 = decode_color(m2), decode_color(m0)
            # What a bystander can hide behind: the scene and the agent.
            xy, heading, phase = setup.walk.state_at((t - START_NS) / 1e9)
            agent = agent_mesh(xy, heading, setup.walk.height_m, phase)
            background = renderer.render(cmc.camera, cmc.T_world_cam, agent).depth
            points = gt[t]
            near = [agent_in_view(cmc, {0: h, 1: g}) for h, g in points.reshape(-1, 2, 3)]
            if not any(near):
                # Nobody new in view: the very same frame (same noise) as without bystanders.
                np.testing.assert_array_equal(img2, img0)
            for u, v in _visible_midpoints(cmc.camera, cmc.T_world_cam, background, points):
                seen += 1
                shown += _differs(img2, img0, u, v)
    assert seen >= 20, seen
    assert shown >= 0.97 * seen, (shown, seen)


def _ego_only(**overrides):
    # Ego frames only, small and slow: the `small` walk has the bystanders in the ego's view.
    return get_preset(
        "small", cmc_images=False, raw_images=True, imu=False, ego_hz=2.0, ego_width=320, ego_height=240, **overrides
    )


def _ego_images(tmp_path, name, preset) -> dict:
    generate(preset, 1, tmp_path / name)
    return {
        t: decode_color(m) for topic, t, m in read_messages(tmp_path / name) if topic.startswith("/ego/color/image")
    }


def test_the_ego_camera_sees_the_bystanders_in_view(tmp_path):
    three = BystanderSpec(count=3)
    without = _ego_images(tmp_path, "n0", _ego_only())
    with_ = _ego_images(tmp_path, "n3", _ego_only(bystanders=three))
    unseen = _ego_images(tmp_path, "off", _ego_only(bystanders=three, bystanders_in_ego_view=False))
    assert all(np.array_equal(unseen[t], img) for t, img in without.items())  # the option's off
    setup = build_capture(_ego_only(bystanders=three), 1)
    renderer = Renderer(setup.scene)
    seen = shown = unchanged = 0
    for t, img0 in without.items():
        T = setup.walk.ego_pose_at((t - START_NS) / 1e9)
        points = np.array([k[i] for b in setup.bystanders for k in [b.keypoints((t - START_NS) / 1e9)] for i in (0, 1)])
        if (transform_points(inv_se3(T), points)[:, 2] < -0.3).all():
            # Everybody behind the camera: the very same frame (same noise) as without bystanders.
            np.testing.assert_array_equal(with_[t], img0)
            unchanged += 1
        background = renderer.render(setup.ego_camera, T).depth
        for u, v in _visible_midpoints(setup.ego_camera, T, background, points):
            seen += 1
            shown += _differs(with_[t], img0, u, v)
    assert seen >= 3 and unchanged >= 3, (seen, unchanged)
    assert shown == seen, (shown, seen)


@pytest.fixture(scope="module")
def small_three():
    return build_capture(get_preset("small", bystanders=BystanderSpec(count=3, crossing_share=0.4)), 1)


def test_each_bystander_has_its_own_height_and_clothes(small_three, pair):
    people = small_three.bystanders
    spec = small_three.preset.bystanders
    heights = [b.height_m for b in people]
    assert all(spec.height_m[0] <= h <= spec.height_m[1] for h in heights)
    assert len(set(np.round(heights, 3))) == len(people)
    assert len({b.clothing.shirt for b in people}) == len(people)
    for b in people:
        for own in (b.clothing.shirt, b.clothing.trousers):
            assert min(np.linalg.norm(np.subtract(own, c)) for c in (SHIRT, TROUSERS)) > 60.0, own
        colours = {tuple(c) for c in b.mesh(3.0).colors.tolist()}
        assert b.clothing.shirt in colours and SHIRT not in colours and TROUSERS not in colours
    assert {tuple(c) for c in agent_mesh((0, 0), 0.0, 1.75, 0.0).colors.tolist()} >= {SHIRT, TROUSERS}
    # The recorded ground truth: head tops at each one's height, ground points on the floor.
    ((_, msg),) = pair[2][GT_BYSTANDER_INFO]
    info = yaml.safe_load(msg.data)["bystanders"]
    for _, m in pair[2][GT_BYSTANDER_KEYPOINTS]:
        p = points_to_array([q.position for q in m.poses]).reshape(-1, 2, 3)
        np.testing.assert_allclose(p[:, 0, 2], [b["height_m"] for b in info], atol=1e-9)
        np.testing.assert_allclose(p[:, 1, 2], 0.0, atol=1e-9)
        np.testing.assert_allclose(p[:, 0, :2], p[:, 1, :2], atol=1e-9)


def test_bystanders_walk_in_free_space_for_the_whole_walk(small_three):
    free = small_three.scene.free_space_polygon()
    agent = small_three.walk
    for b in small_three.bystanders:
        # Somewhere for the whole walk: its walk lasts about as long (then it stands).
        assert b.walk.duration_s >= agent.duration_s - 1.0
        xy = np.array([b.walk.state_at(t)[0] for t in np.arange(0.0, agent.duration_s, 0.05)])
        # As the agent's walk: rounded corners cut into the body's clearance by a little.
        assert shapely.distance(free, shapely.points(xy)).max() < 0.16
        # It walks (a crossing one may first wait for the agent).
        assert np.linalg.norm(np.diff(xy, axis=0), axis=1).sum() > 3.0
        step = np.linalg.norm(np.diff(b.walk.xy, axis=0), axis=1) * 100.0
        assert step.max() <= small_three.preset.bystanders.speed_mps[1] * 1.05
        assert (step < 1e-9).sum() > 100  # it stops now and then


def test_some_bystanders_pass_close_by_the_agent(small_three):
    agent = small_three.walk
    crossing = [b for b in small_three.bystanders if b.crosses_at_s is not None]
    assert len(crossing) == 2  # 40 % of 3, rounded up
    for b in crossing:
        t = b.crosses_at_s
        gap = np.linalg.norm(b.walk.state_at(t)[0] - agent.state_at(t)[0])
        assert 0.3 < gap < 1.0, gap
    lonely = build_capture(get_preset("small", bystanders=BystanderSpec(count=2, crossing_share=0.0)), 1)
    assert all(b.crosses_at_s is None for b in lonely.bystanders)


def test_the_pose_model_finds_the_agent_and_a_bystander(small_three):
    """A real pose model (never mocked) in a CMC frame that shows the agent and a bystander
    in full, apart: two persons."""
    from yowo_cmc.params import PoseModelParams
    from yowo_cmc.pose_model import PoseDetector

    setup = small_three
    renderer = Renderer(setup.scene)
    backgrounds = {c.name: renderer.render(c.camera, c.T_world_cam).depth for c in setup.cmcs}

    def in_full(cmc, joints) -> bool:
        uv, ok = cmc.camera.project_world(cmc.T_world_cam, joints)
        if not (ok.all() and cmc.camera.in_image(uv, margin=15).all()):
            return False
        z = (np.linalg.inv(cmc.T_world_cam) @ np.column_stack([joints, np.ones(len(joints))]).T)[2]
        px = np.round(uv).astype(int)
        return bool((backgrounds[cmc.name][px[:, 1], px[:, 0]] > z - 0.05).all())  # nothing in front

    walk = setup.walk
    for t in np.arange(0.0, walk.duration_s, 0.25):
        xy, heading, phase = walk.state_at(t)
        agent = agent_joints_3d(xy, heading, walk.height_m, phase)
        for cmc in setup.cmcs:
            if not in_full(cmc, agent):
                continue
            for b in setup.bystanders:
                bxy, bheading, bphase = b.walk.state_at(t)
                if np.linalg.norm(bxy - xy) > 1.2 and in_full(cmc, agent_joints_3d(bxy, bheading, b.height_m, bphase)):
                    people = [agent_mesh(xy, heading, walk.height_m, phase), b.mesh(t)]
                    frame = renderer.render(cmc.camera, cmc.T_world_cam, people)
                    found = PoseDetector(PoseModelParams()).detect(frame.rgb)
                    assert len(found) >= 2, (t, cmc.name, len(found))
                    return
    pytest.fail("no CMC frame shows the agent and a bystander in full")
