"""Scene builder, agent body and renderer: geometry and pixel conventions."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import shapely

from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at
from yowo_sim.body import GROUND, HEAD_TOP, LEFT_FOOT, PELVIS, RIGHT_FOOT, agent_keypoints_3d, agent_mesh
from yowo_sim.capture import place_cmcs
from yowo_sim.presets import PRESETS
from yowo_sim.render import Renderer
from yowo_sim.scene import LIGHT_RANGE, WALL_THICKNESS, Light, Scene, SceneSpec, build_scene

PINHOLE = CameraModel(640, 480, [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]])
DISTORTED = CameraModel(640, 480, PINHOLE.K, [-0.2, 0.05, 0.0, 0.0, 0.0])
# Camera at (0, 0, 1.5) looking along +x: image right is world -y, image down is world -z.
T_WORLD_CAM = look_at((0.0, 0.0, 1.5), (5.0, 0.0, 1.5))


def _quads_scene(quads: list[np.ndarray], texture: np.ndarray, uvs: list[np.ndarray] | None = None) -> Scene:
    """Scene of textured quads (corners in order), lit by ambient light 1 so the
    rendered colour is the texture colour."""
    vertices, triangles, tri_uvs = [], [], []
    for q, quad in enumerate(quads):
        uv = uvs[q] if uvs is not None else np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
        for tri in ((0, 1, 2), (0, 2, 3)):
            triangles.append([4 * q + i for i in tri])
            tri_uvs.append(uv[list(tri)])
        vertices.extend(quad)
    n = len(triangles)
    return Scene(
        vertices=np.array(vertices, np.float32),
        triangles=np.array(triangles, np.int32),
        triangle_uvs=np.array(tri_uvs, np.float32),
        triangle_texture=np.zeros(n, np.int32),
        textures=[texture],
        ambient=1.0,
    )


def _wall_x(x: float, y0: float, y1: float, z0: float = -10.0, z1: float = 10.0) -> np.ndarray:
    return np.array([[x, y0, z1], [x, y1, z1], [x, y1, z0], [x, y0, z0]], float)


def _grey(value: int) -> np.ndarray:
    return np.full((16, 16, 3), value, np.uint8)


@pytest.mark.parametrize("camera", [PINHOLE, DISTORTED], ids=["pinhole", "plumb_bob"])
def test_fronto_parallel_plane_has_exact_z_depth(camera):
    renderer = Renderer(_quads_scene([_wall_x(4.2, -50, 50, -50, 50)], _grey(128)))
    frame = renderer.render(camera, T_WORLD_CAM)
    assert np.isfinite(frame.depth).all()
    np.testing.assert_allclose(frame.depth, 4.2, atol=1e-4)
    assert (frame.rgb == 128).all()
    assert not frame.agent_mask.any()


def test_tilted_plane_z_depth_matches_ray_plane_intersection():
    # Plane through (4, 0, 1.5) with a normal tilted away from the optical axis.
    normal = np.array([1.0, 0.4, -0.3])
    normal /= np.linalg.norm(normal)
    p0 = np.array([4.0, 0.0, 1.5])
    a = np.cross(normal, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    quad = np.array([p0 + 40 * (sa * a + sb * b) for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    frame = Renderer(_quads_scene([quad], _grey(90))).render(DISTORTED, T_WORLD_CAM)
    u, v = np.meshgrid(np.arange(640.0), np.arange(480.0))
    bearings = DISTORTED.bearings(np.column_stack([u.ravel(), v.ravel()]))
    rays_world = bearings / bearings[:, 2:3] @ T_WORLD_CAM[:3, :3].T  # unit z in the camera frame
    z_depth = (normal @ (p0 - T_WORLD_CAM[:3, 3])) / (rays_world @ normal)
    np.testing.assert_allclose(frame.depth.ravel(), z_depth, atol=1e-4)


@pytest.mark.parametrize("camera", [PINHOLE, DISTORTED], ids=["pinhole", "plumb_bob"])
def test_occluding_edge_lies_where_camera_model_projects_it(camera):
    """A vertical edge at x = 3 in front of a wall at x = 6: every pixel whose
    centre is left of the projected edge sees the near plane, every pixel right
    of it the wall. A half-pixel error in the ray grid shifts the boundary."""
    # Choose the edge so that it projects to u = 100.25 (pinhole) near the image
    # border, where the distortion bends it.
    u_edge = 100.25
    y_edge = (PINHOLE.K[0, 2] - u_edge) * 3.0 / PINHOLE.K[0, 0]  # optical x is world -y
    near = _wall_x(3.0, y_edge, 20.0)
    scene = _quads_scene([near, _wall_x(6.0, -50, 50)], _grey(200))
    frame = Renderer(scene).render(camera, T_WORLD_CAM)
    # Projected edge: sample the 3D edge densely and interpolate u at each row.
    edge = np.column_stack([np.full(4001, 3.0), np.full(4001, y_edge), np.linspace(-2.0, 5.0, 4001)])
    uv, in_front = camera.project_world(T_WORLD_CAM, edge)
    assert in_front.all()
    order = np.argsort(uv[:, 1])
    rows = np.arange(480)
    u_at_row = np.interp(rows, uv[order, 1], uv[order, 0])
    cols = np.arange(640)[None, :]
    near_px = cols < u_at_row[:, None] - 0.02
    far_px = cols > u_at_row[:, None] + 0.02
    np.testing.assert_allclose(frame.depth[near_px], 3.0, atol=1e-4)
    assert np.all(frame.depth[far_px] > 5.9)
    if camera is PINHOLE:
        assert np.allclose(u_at_row, u_edge)
    else:
        assert np.ptp(u_at_row) > 5.0  # the edge really is curved in this image


@pytest.mark.parametrize("camera", [PINHOLE, DISTORTED], ids=["pinhole", "plumb_bob"])
def test_textured_marker_corners_project_to_their_pixels(camera):
    """Chessboard texture on a wall: detected inner corners sit (sub-pixel) where
    CameraModel.project puts the corresponding 3D points."""
    squares, sq_px = (8, 6), 64
    board = np.kron((np.indices(squares[::-1]).sum(axis=0) % 2), np.ones((sq_px, sq_px))).astype(np.uint8)
    texture = np.repeat(np.pad(board * 200 + 30, sq_px, constant_values=230)[..., None], 3, axis=2)
    size_m = 0.25 * np.array([squares[0] + 2, squares[1] + 2])  # 0.25 m squares, one square of margin
    # Board on the wall x = 3, centred in front of the camera, texture top-left at (y = +w/2, z = 1.5 + h/2).
    top_left = np.array([3.0, size_m[0] / 2, 1.5 + size_m[1] / 2])
    right, down = np.array([0.0, -1.0, 0.0]), np.array([0.0, 0.0, -1.0])
    quad = np.array(
        [
            top_left,
            top_left + size_m[0] * right,
            top_left + size_m[0] * right + size_m[1] * down,
            top_left + size_m[1] * down,
        ]
    )
    frame = Renderer(_quads_scene([quad], texture)).render(camera, T_WORLD_CAM)
    grey = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCornersSB(grey, (squares[0] - 1, squares[1] - 1), flags=cv2.CALIB_CB_ACCURACY)
    assert found
    i, j = np.meshgrid(np.arange(1, squares[0]), np.arange(1, squares[1]))
    points = top_left + (0.25 * (i.ravel() + 1))[:, None] * right + (0.25 * (j.ravel() + 1))[:, None] * down
    expected, _ = camera.project_world(T_WORLD_CAM, points)
    detected = corners.reshape(-1, 2)
    # Detection order may start at either end of the board.
    err = min(np.abs(detected - expected).max(), np.abs(detected[::-1] - expected).max())
    assert err < 0.5


def test_two_rooms_floor_polygon_area():
    scene = build_scene(SceneSpec(layout="two_rooms", seed=3))
    assert len(scene.floor_polygons) == 1 and len(scene.doors) == 1
    x, y = scene.floor_polygons[0].T
    signed_area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    expected = sum(r.area for r in scene.rooms) + scene.doors[0].width * WALL_THICKNESS
    assert signed_area > 0  # counter-clockwise
    assert abs(signed_area - expected) < 0.01 * expected
    assert 2 * 25.0 < expected < 2 * 35.0


def test_build_scene_is_deterministic_per_seed():
    spec = SceneSpec(layout="office", texture="rich", seed=11)
    a, b = build_scene(spec), build_scene(spec)
    for name in ("vertices", "triangles", "triangle_uvs", "triangle_texture", "triangle_room"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert len(a.textures) == len(b.textures)
    assert all(np.array_equal(ta, tb) for ta, tb in zip(a.textures, b.textures))
    c = build_scene(SceneSpec(layout="office", texture="rich", seed=12))
    assert c.vertices.shape != a.vertices.shape or not np.array_equal(c.vertices, a.vertices)
    # The geometry of a seed does not depend on the texture mode.
    poor = build_scene(SceneSpec(layout="office", texture="poor", seed=11))
    assert [f.bounds for f in poor.furniture] == [f.bounds for f in a.furniture]


@pytest.mark.parametrize("layout", ["room_4x4", "office", "floor_40x20"])
def test_layout_is_closed_walkable_and_lit(layout):
    scene = build_scene(SceneSpec(layout=layout, seed=5))
    floor = scene.floor_geometry()
    free = scene.free_space_polygon(margin=0.3)
    # One walkable piece reaching every room, clear of furniture.
    assert free.geom_type == "Polygon"
    assert all(free.intersects(room.polygon()) for room in scene.rooms)
    assert all(not free.intersects(f.polygon()) for f in scene.furniture)
    assert floor.contains(free)
    assert len(scene.furniture) > 0 and len(scene.lights) >= len(scene.rooms)
    walls = scene.wall_segments()
    assert len(walls) == 4 * len(scene.rooms)
    for w in walls:  # the inward normal points into the room
        mid = 0.5 * (w.start + w.end) + 0.1 * w.normal
        assert scene.rooms[w.room].polygon().contains(shapely.Point(*mid))
    assert (scene.vertices[:, 2] >= -0.01).all() and (scene.vertices[:, 2] <= scene.spec.ceiling_height + 0.01).all()


def test_no_ray_escapes_a_room():
    """Closed rooms: cameras anywhere inside see a surface at every pixel."""
    scene = build_scene(SceneSpec(layout="office", seed=2, num_furniture=0))
    renderer = Renderer(scene)
    for room in scene.rooms:
        x0, y0, x1, y1 = room.bounds
        eye = (x0 + 0.3, y0 + 0.3, 2.5)
        for target in ((x1, y1, 0.5), (x0 + 0.31, y0 + 0.31, 0.0), (x1, y0, 2.7)):
            frame = renderer.render(PINHOLE, look_at(eye, target))
            assert np.isfinite(frame.depth).all()


@pytest.mark.parametrize("phase", [0.0, 0.7, np.pi / 2, 2.5, np.pi, 4.0])
def test_agent_keypoints_match_body_mesh(phase):
    xy, heading, height = (1.3, -2.0), 0.8, 1.72
    mesh = agent_mesh(xy, heading, height, phase)
    kp = agent_keypoints_3d(xy, heading, height, phase)
    top = mesh.vertices[np.argmax(mesh.vertices[:, 2])]
    np.testing.assert_allclose(kp[HEAD_TOP], [*xy, height], atol=1e-6)
    np.testing.assert_allclose(top, kp[HEAD_TOP], atol=1e-5)  # head top is the highest mesh point
    np.testing.assert_allclose(kp[GROUND], [*xy, 0.0])
    assert abs(mesh.vertices[:, 2].min()) < 1e-5  # a foot stands on the floor
    feet_z = sorted([kp[LEFT_FOOT][2], kp[RIGHT_FOOT][2]])
    assert feet_z[0] == pytest.approx(0.0, abs=1e-9) and feet_z[1] < 0.1 * height
    assert 0.4 * height < kp[PELVIS][2] < 0.6 * height
    assert mesh.colors.shape == (len(mesh.triangles), 3) and mesh.colors.dtype == np.uint8


def test_agent_is_composited_by_depth_and_keypoints_project_onto_it():
    scene = build_scene(SceneSpec(layout="room_4x4", seed=1, num_furniture=0))
    renderer = Renderer(scene)
    T = look_at((0.2, 0.2, 2.6), (2.5, 2.5, 0.8))
    xy, heading, height, phase = (2.2, 2.0), 2.0, 1.75, 0.9
    plain = renderer.render(PINHOLE, T)
    frame = renderer.render(PINHOLE, T, agent_mesh(xy, heading, height, phase))
    assert frame.agent_mask.sum() > 2000
    assert np.all(frame.depth[frame.agent_mask] < plain.depth[frame.agent_mask])
    np.testing.assert_array_equal(frame.depth[~frame.agent_mask], plain.depth[~frame.agent_mask])
    kp = agent_keypoints_3d(xy, heading, height, phase)
    uv, _ = PINHOLE.project_world(T, np.array([kp[HEAD_TOP], kp[PELVIS]]))
    for u, v in np.round(uv).astype(int):
        assert frame.agent_mask[v - 2 : v + 3, u - 2 : u + 3].any()
    # The head top is the mask's point nearest the image top along its column.
    rows = np.flatnonzero(frame.agent_mask[:, int(round(uv[0, 0]))])
    assert abs(rows.min() - uv[0, 1]) < 2.0


def test_rich_texture_has_many_more_features_than_poor():
    orb = cv2.ORB_create(nfeatures=5000)
    sift = cv2.SIFT_create()
    T = look_at((2.0, 2.0, 1.5), (2.0, 4.0, 1.4))  # facing a wall 2 m away
    counts = {}
    for mode in ("rich", "poor"):
        scene = build_scene(SceneSpec(layout="room_4x4", texture=mode, seed=4, num_furniture=0))
        grey = cv2.cvtColor(Renderer(scene).render(PINHOLE, T).rgb, cv2.COLOR_RGB2GRAY)
        counts[mode] = (len(orb.detect(grey, None)), len(sift.detect(grey, None)))
    assert counts["rich"][0] > 500 and counts["rich"][0] > 10 * max(counts["poor"][0], 1)
    assert counts["rich"][1] > 200 and counts["rich"][1] > 10 * max(counts["poor"][1], 1)


def test_baked_lighting_matches_point_light_model():
    """Floor lit by one lamp: every pixel is albedo * (ambient + I cos / (1 + d^2 / R0^2) * window)."""
    floor = np.array([[-5.0, -5.0, 0.0], [5.0, -5.0, 0.0], [5.0, 5.0, 0.0], [-5.0, 5.0, 0.0]])
    scene = _quads_scene([floor], _grey(100))
    scene.ambient = 0.2
    scene.triangle_room[:] = 0
    lamp = np.array([0.3, -0.2, 2.0])
    scene.lights = [Light(lamp, 1.0, 0)]
    T = look_at((1.5, 1.0, 3.0), (0.0, 0.0, 0.0))
    frame = Renderer(scene).render(PINHOLE, T)
    u, v = np.meshgrid(np.arange(640.0), np.arange(480.0))
    bearings = PINHOLE.bearings(np.column_stack([u.ravel(), v.ravel()]))
    points = T[:3, 3] + (frame.depth.reshape(-1, 1) * bearings / bearings[:, 2:3]) @ T[:3, :3].T
    valid = np.isfinite(points).all(axis=1) & (np.abs(points[:, :2]) < 4.9).all(axis=1)
    delta = lamp - points[valid]
    d2 = (delta**2).sum(axis=1)
    window = np.clip(1.0 - (d2 / LIGHT_RANGE**2) ** 2, 0.0, 1.0)
    shade = 0.2 + delta[:, 2] / np.sqrt(d2) * 2.5**2 / (2.5**2 + d2) * window
    err = np.abs(frame.rgb.reshape(-1, 3)[valid, 0] - 100.0 * shade)
    assert valid.sum() > 100000
    assert err.max() < 2.0 and np.mean(err) < 0.5


def test_light_intensity_scales_the_image():
    T = look_at((0.5, 0.5, 1.6), (3.5, 3.0, 1.0))
    means = []
    for li in (0.5, 1.0):
        scene = build_scene(SceneSpec(layout="room_4x4", texture="poor", light_intensity=li, seed=1))
        means.append(Renderer(scene).render(PINHOLE, T).rgb.astype(float).mean())
    assert means[0] / means[1] == pytest.approx(0.5, abs=0.02)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_places_its_cameras_in_its_rooms(name):
    preset = PRESETS[name]
    scene = build_scene(preset.scene)
    cmcs = place_cmcs(scene, preset, np.random.default_rng(0))
    assert len(cmcs) == sum(preset.cmcs_per_room)
    rooms = {r.name: r.bounds for r in scene.rooms}
    for c in cmcs:
        x0, y0, x1, y1 = rooms[c.room]
        x, y = c.T_world_cam[:2, 3]
        assert x0 <= x <= x1 and y0 <= y <= y1, c.name
    if name == "floor50":
        assert len(cmcs) == 50
