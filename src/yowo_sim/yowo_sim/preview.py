"""A picture of a capture: one ego frame, one CMC frame with the agent, and the
top view of the floor plan with the walk and every CMC's frustum footprint."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from shapely.geometry import Polygon  # noqa: E402

from yowo_common.camera import CameraModel  # noqa: E402

from .body import agent_keypoints_3d, agent_mesh  # noqa: E402
from .capture import CaptureSetup  # noqa: E402
from .render import Renderer  # noqa: E402


def floor_footprint(camera: CameraModel, T_world_cam: np.ndarray, max_range_m: float = 12.0) -> np.ndarray:
    """Where the image border's rays meet the floor (z = 0), clipped to a range: (N, 2);
    walls are not considered (the caller clips to the camera's room)."""
    w, h = camera.width, camera.height
    border = np.vstack(
        [
            np.column_stack([np.linspace(0, w - 1, 20), np.zeros(20)]),
            np.column_stack([np.full(20, w - 1), np.linspace(0, h - 1, 20)]),
            np.column_stack([np.linspace(w - 1, 0, 20), np.full(20, h - 1)]),
            np.column_stack([np.zeros(20), np.linspace(h - 1, 0, 20)]),
        ]
    )
    rays = camera.bearings(border) @ T_world_cam[:3, :3].T
    C = T_world_cam[:3, 3]
    t = np.where(rays[:, 2] < -1e-6, -C[2] / np.minimum(rays[:, 2], -1e-6), np.inf)
    t = np.minimum(t, max_range_m)
    return (C + rays * t[:, None])[:, :2]


def render_preview(setup: CaptureSetup, path) -> None:
    scene, walk = setup.scene, setup.walk
    renderer = Renderer(scene)
    t_ego = walk.duration_s * 0.3
    others = [b.mesh(t_ego) for b in setup.bystanders] if setup.preset.bystanders_in_ego_view else []
    ego_rgb = renderer.render(setup.ego_camera, walk.ego_pose_at(t_ego), others)[0]
    # A CMC frame with the agent in view: the first camera and time that show it.
    cmc_rgb, cmc_title = None, ""
    for t in np.linspace(0, walk.duration_s, 200):
        xy, heading, phase = walk.state_at(t)
        for cmc in setup.cmcs:
            kps = agent_keypoints_3d(xy, heading, walk.height_m, phase)
            uv, ok = cmc.camera.project_world(cmc.T_world_cam, np.array([kps[0], kps[1]]))
            if ok.all() and cmc.camera.in_image(uv, margin=20).all():
                people = [agent_mesh(xy, heading, walk.height_m, phase)] + [b.mesh(t) for b in setup.bystanders]
                frame = renderer.render(cmc.camera, cmc.T_world_cam, people)
                if frame.agent_mask.mean() > 0.01:  # visible, not behind a wall
                    cmc_rgb, cmc_title = frame.rgb, f"CMC {cmc.name} at t = {t:.1f} s"
                    break
        if cmc_rgb is not None:
            break
    fig = plt.figure(figsize=(15, 5.2))
    ax = fig.add_subplot(1, 3, 1)
    ax.imshow(ego_rgb)
    ax.set_title(f"ego RGB at t = {t_ego:.1f} s")
    ax.axis("off")
    ax = fig.add_subplot(1, 3, 2)
    if cmc_rgb is not None:
        ax.imshow(cmc_rgb)
    ax.set_title(cmc_title or "no CMC sees the agent")
    ax.axis("off")
    ax = fig.add_subplot(1, 3, 3)
    for poly in scene.floor_polygons:
        ax.fill(*np.vstack([poly, poly[:1]]).T, color="0.92", zorder=0)
    for seg in scene.wall_segments():
        ax.plot(*np.array([seg.start, seg.end]).T, color="0.3", lw=1.5)
    for f in scene.furniture:
        x0, y0, x1, y1 = f.bounds
        ax.fill([x0, x1, x1, x0], [y0, y0, y1, y1], color="tan", alpha=0.7)
    ax.plot(*walk.xy.T, color="tab:blue", lw=1, label="agent walk")
    for i, b in enumerate(setup.bystanders):
        ax.plot(*b.walk.xy.T, color=np.array(b.clothing.shirt) / 255, lw=0.7, ls="--", label=f"bystander {i}")
    colors = plt.cm.tab10(np.linspace(0, 1, max(len(setup.cmcs), 2)))
    for cmc, col in zip(setup.cmcs, colors):
        room = next(r for r in scene.rooms if r.name == cmc.room)
        seen = Polygon(floor_footprint(cmc.camera, cmc.T_world_cam)).buffer(0).intersection(room.polygon())
        for part in getattr(seen, "geoms", [seen]):
            if not part.is_empty:
                ax.fill(*np.asarray(part.exterior.coords).T, color=col, alpha=0.15)
        C = cmc.T_world_cam[:3, 3]
        ax.plot(C[0], C[1], "^", color=col, ms=8)
        ax.annotate(cmc.name, C[:2], fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_title(f"top view: {len(setup.cmcs)} CMCs, {walk.duration_s:.0f} s walk")
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
