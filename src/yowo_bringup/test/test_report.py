"""The report's geometry (each camera's view of the floor, walls, ellipse scale) and the
pages as a browser shows them: headless Chromium renders report.html and the guidance's
floor-plan page guidance.html to screenshots."""

import shutil
import subprocess

import numpy as np
from geometry_msgs.msg import Point

from yowo_bringup.report import (
    _COLOURS,
    AREA_COLOUR,
    SECOND_WALK_COLOUR,
    WALK_COLOUR,
    _ellipse_scale,
    floor_footprint,
    wall_segments,
    write_guidance_page,
    write_report,
)
from yowo_bringup.second_walk import CameraVerdict, plan_second_walk
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


def screenshot(page, size: tuple[int, int]) -> np.ndarray:
    """(height, width, 3) RGB of the page as headless Chromium renders it."""
    assert shutil.which("chromium"), "chromium not found: `make setup` installs it (apt)"
    shot = page.with_suffix(".png")
    subprocess.run(
        [
            "chromium",
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--window-size={size[0]},{size[1]}",
            f"--screenshot={shot}",
            page.as_uri(),
        ],
        capture_output=True,
        timeout=120,
        check=True,
    )
    import cv2

    img = cv2.imread(str(shot))[:, :, ::-1].astype(int)
    assert img.shape[:2] == (size[1], size[0])
    return img


def colour_pixels(img: np.ndarray, hex_colour: str, tol: int = 12) -> int:
    rgb = np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)])
    return int((np.abs(img - rgb).max(axis=2) <= tol).sum())


def test_report_renders_in_headless_chromium(tmp_path):
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
    img = screenshot(tmp_path / "report.html", (1250, 2400))

    def pixels(hex_colour, tol=12):
        return colour_pixels(img, hex_colour, tol)

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


def guidance_scene(with_second_walk: bool):
    """Two rooms joined by a doorway, the first walk in the left one; cam00 over the right one
    never saw the walker in two of its image's corners, cam01 over the left one is ok."""
    rooms = [
        np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]),
        np.array([[4.0, 1.5], [5.0, 1.5], [5.0, 2.5], [4.0, 2.5]]),
        np.array([[5.0, 0.0], [9.0, 0.0], [9.0, 4.0], [5.0, 4.0]]),
    ]
    walls = [np.array([[0.0, 4.0], [9.0, 4.0]]), np.array([[0.0, 0.0], [9.0, 0.0]])]
    cams = [camera("cam00", (7.0, 0.2, 3.0), (7.0, 2.5, 0.0)), camera("cam01", (2.0, 0.2, 3.0), (2.0, 2.5, 0.0))]
    missing = ("top-left corner", "bottom-right corner") if with_second_walk else ()
    verdicts = [
        CameraVerdict(
            name="cam00",
            verdict="needs more" if with_second_walk else "ok",
            reasons=("agent never seen in the image's left or right third",) if with_second_walk else (),
            regions_missing=missing,
            observations=900,
            covisible={"cam01": 80},
            in_group=True,
        ),
        CameraVerdict(name="cam01", verdict="ok", observations=900, covisible={"cam00": 80}, in_group=True),
    ]
    ego = np.column_stack([np.linspace(0.5, 3.5, 60), 2 + 0.8 * np.sin(np.linspace(0, 6, 60))])
    walk = plan_second_walk(cameras=cams, verdicts=verdicts, floors=rooms, ego_xy=ego, weak_places=[])
    return cams, verdicts, walk, ego, rooms, walls


def test_the_guidance_page_draws_the_walk_the_areas_and_the_numbered_second_walk_in_chromium(tmp_path):
    cams, verdicts, walk, ego, rooms, walls = guidance_scene(with_second_walk=True)
    assert len(walk.waypoints) == 2
    write_guidance_page(tmp_path / "guidance.html", "synthetic", cams, verdicts, walk, ego, rooms, walls)
    page = (tmp_path / "guidance.html").read_text()
    assert "1 of 2 cameras need more: cam00." in page
    assert "never saw the walker in its image&#x27;s top-left corner" in page and "(waypoint " in page
    img = screenshot(tmp_path / "guidance.html", (1250, 1100))
    # What the browser shows: the first walk (blue), the floor cam00 needs the walker in (olive
    # outlines), the second walk (pink line and numbered circles), cam00's verdict colour.
    walked = colour_pixels(img, WALK_COLOUR, 20)
    areas = colour_pixels(img, AREA_COLOUR, 20)
    second = colour_pixels(img, SECOND_WALK_COLOUR, 20)
    assert walked > 800 and areas > 300 and second > 800
    assert colour_pixels(img, _COLOURS["failed"]) > 50  # cam00's triangle and its verdict, red
    # The same page with nothing to do has no areas and no second walk.
    cams, verdicts, walk, ego, rooms, walls = guidance_scene(with_second_walk=False)
    write_guidance_page(tmp_path / "ok.html", "synthetic", cams, verdicts, walk, ego, rooms, walls)
    img = screenshot(tmp_path / "ok.html", (1250, 1100))
    assert colour_pixels(img, AREA_COLOUR, 20) < 20 and colour_pixels(img, SECOND_WALK_COLOUR, 20) < 20
    assert abs(colour_pixels(img, WALK_COLOUR, 20) - walked) < 0.2 * walked
    assert "All 2 cameras are ok." in (tmp_path / "ok.html").read_text()


def test_the_report_links_the_guidance_page_when_there_is_one(tmp_path):
    cams = [camera("cam00", [0.5, 0.5, 2.8], [3, 2, 0])]
    write_report(tmp_path / "with.html", "synthetic", cams, None, [], guidance_page="guidance.html")
    assert '<a href="guidance.html">Guidance after the walk</a>' in (tmp_path / "with.html").read_text()
    write_report(tmp_path / "without.html", "synthetic", cams, None, [])
    assert "guidance.html" not in (tmp_path / "without.html").read_text()
