"""The report's geometry (each camera's view of the floor, walls, ellipse scale) and the
page as a browser shows it: headless Chromium renders report.html to a screenshot."""

import shutil
import subprocess

import numpy as np
from geometry_msgs.msg import Point

from yowo_bringup.report import _COLOURS, _ellipse_scale, floor_footprint, wall_segments, write_report
from yowo_common.camera import CameraModel
from yowo_common.geometry import look_at
from yowo_fusion.records import AgentFit, RegisteredCmc, unregistered
from yowo_msgs.msg import Plane


def camera(name, eye, target, status="ok", sigma_m=0.01):
    cov = np.diag([sigma_m**2, (2 * sigma_m) ** 2, sigma_m**2, 1e-6, 1e-6, 1e-6])
    cam = CameraModel.from_fov(640, 480, 90.0)
    return RegisteredCmc(
        name=name,
        group="g0",
        method="group_sfm",
        status=status,
        reason="",
        T_world_cam=look_at(eye, target),
        covariance=cov,
        camera=cam,
        rmse_px=1.2,
        num_agent=500,
        num_scene=40,
    )


def test_a_camera_looking_straight_down_sees_a_rectangle_of_the_floor():
    # 90 deg horizontal field of view from 3 m: the floor from x - 3 to x + 3 (+-2.25 m across).
    c = RegisteredCmc(
        name="down",
        group="g0",
        method="group_sfm",
        status="ok",
        reason="",
        T_world_cam=np.diag([1.0, -1.0, -1.0, 1.0]) @ np.eye(4),
        covariance=None,
        camera=CameraModel.from_fov(640, 480, 90.0),
        rmse_px=1.0,
        num_agent=1,
        num_scene=1,
    )
    c.T_world_cam[:3, 3] = (1.0, 2.0, 3.0)
    foot = floor_footprint(c)
    assert np.allclose(foot[:, 2], 0.0)
    assert np.allclose(np.sort(np.unique(np.round(foot[:, 0], 6))), [1.0 - 3.0, 1.0 + 3.0], atol=0.02)
    assert np.allclose(np.sort(np.unique(np.round(foot[:, 1], 6))), [2.0 - 2.25, 2.0 + 2.25], atol=0.02)


def test_a_corner_ray_above_the_horizon_stops_at_the_drawing_range():
    c = camera("level", (0.0, 0.0, 2.5), (5.0, 0.0, 2.5))  # looking along x, horizontally
    foot = floor_footprint(c, max_range_m=8.0)
    up = foot[:, 2] > 0
    assert up.sum() == 2 and np.allclose(np.linalg.norm(foot[up] - c.T_world_cam[:3, 3], axis=1), 8.0)


def test_walls_are_the_extent_of_their_outline_and_the_ellipses_are_enlarged_to_be_seen():
    wall = Plane(
        kind=Plane.KIND_WALL,
        coefficients=[0.0, 1.0, 0.0, -4.0],
        boundary=[Point(x=x, y=4.0, z=z) for x, z in ((0.5, 0), (3.0, 0), (3.0, 2.5), (1.0, 2.5))],
    )
    floor = Plane(kind=Plane.KIND_FLOOR, coefficients=[0.0, 0.0, 1.0, 0.0], boundary=[Point(x=0.0, y=0.0)])
    (seg,) = wall_segments([wall, floor])
    assert np.allclose(sorted(seg[:, 0]), [0.5, 3.0]) and np.allclose(seg[:, 1], 4.0)
    # Largest sigma 2 cm: 3-sigma ellipse 12 cm across, drawn x 2 (1-2-5 steps) to be ~0.4 m.
    assert _ellipse_scale([camera("a", (0, 0, 3), (1, 1, 0))]) == 2.0
    assert _ellipse_scale([camera("a", (0, 0, 3), (1, 1, 0), sigma_m=0.0005)]) == 50.0


def test_report_renders_in_headless_chromium(tmp_path):
    assert shutil.which("chromium"), "chromium not found: `make setup` installs it (apt)"
    floor = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0]])
    cams = [
        camera("c1", (0.3, 0.3, 3.0), (3.0, 2.0, 0.0)),
        camera("c2", (5.7, 3.7, 3.0), (3.0, 2.0, 0.0), "weak"),
        unregistered("c3", "never saw the agent"),
    ]
    walls = [np.array([[0.0, 4.0], [6.0, 4.0]]), np.array([[6.0, 0.0], [6.0, 4.0]])]
    rng = np.random.default_rng(1)
    obs = rng.uniform([100, 100], [540, 380], (800, 2))
    fits = [
        (
            AgentFit(
                name=n,
                keypoint_ids=rng.integers(0, 20, 800),
                observed_uv=obs,
                reprojected_uv=obs + rng.normal(0, 1.5, obs.shape),
            ),
            (640, 480),
            np.full((480, 640, 3), 200, np.uint8) if n == "c1" else None,
        )
        for n in ("c1", "c2")
    ]
    ego = np.column_stack([np.linspace(1, 5, 50), 2 + np.sin(np.linspace(0, 3, 50))])
    write_report(tmp_path / "report.html", "synthetic", cams, ego, [floor], walls=walls, fits=fits)
    shot = tmp_path / "shot.png"
    subprocess.run(
        [
            "chromium",
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--window-size=1250,2400",
            f"--screenshot={shot}",
            (tmp_path / "report.html").as_uri(),
        ],
        capture_output=True,
        timeout=120,
        check=True,
    )
    import cv2

    img = cv2.imread(str(shot))[:, :, ::-1].astype(int)
    assert img.shape[:2] == (2400, 1250)

    def pixels(hex_colour, tol=12):
        rgb = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)])
        return int((np.abs(img - rgb).max(axis=2) <= tol).sum())

    # What the browser shows: both registered cameras (verdict colours: markers, rays, ellipses,
    # the verdict cells), the walls' dark grey, the panels' red reprojections and blue observations.
    assert pixels(_COLOURS["ok"]) > 100 and pixels(_COLOURS["weak"]) > 100
    assert pixels("#404040", tol=6) > 300
    assert pixels("#d62728", tol=30) > 300 and pixels("#1f77b4", tol=30) > 300


def test_the_walks_weak_places_are_listed_and_numbered_as_drawn(tmp_path):
    cams = [camera("cam00", [0.5, 0.5, 2.8], [3, 2, 0])]
    ego = np.column_stack([np.linspace(0, 6, 50), np.full(50, 2.0)])
    place = {
        "kind": "walked once",
        "start_s": 12.0,
        "end_s": 20.5,
        "x_m": 4.5,
        "y_m": 2.0,
        "extent_m": 3.2,
        "why": "walked once (3.4 m of path), never returned to",
        "group": "",
    }
    write_report(tmp_path / "with.html", "synthetic", cams, ego, [], weak_places=[place])
    page = (tmp_path / "with.html").read_text()
    assert "Weak places of the walk" in page
    assert "<td>W1</td><td>walked once</td><td>12.0-20.5 s</td><td>(4.5, 2.0) m</td>" in page
    write_report(tmp_path / "none.html", "synthetic", cams, ego, [], weak_places=[])
    assert "None found" in (tmp_path / "none.html").read_text()
    write_report(tmp_path / "cmc_only.html", "synthetic", cams, None, [])  # no fusion: no section
    assert "Weak places" not in (tmp_path / "cmc_only.html").read_text()
