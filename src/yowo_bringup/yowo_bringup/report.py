"""report.html of a run: a top view (floor, walls, ego path, each camera's view of the
floor and its position uncertainty), the per-camera table with uncertainty and
verdict, a panel per grouped camera (as kalibr's report gives each target: the
observed agent keypoints and the reprojected fused track over the camera's
background, the residual histogram, where in the image the agent was seen), and the
metrics when ground truth was available. One self-contained file (figures embedded)."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from yowo_fusion.records import AgentFit, RegisteredCmc  # noqa: E402

from .results import pose_sigma  # noqa: E402

# Verdict colours as CSS hex (matplotlib takes them too): tab:green, tab:orange, tab:red.
_COLOURS = {"ok": "#2ca02c", "weak": "#ff7f0e", "failed": "#d62728"}
_UNKNOWN = "#000000"
FRUSTUM_RANGE_M = 8.0  # how far a corner ray that never meets the floor is drawn


def floor_footprint(c: RegisteredCmc, floor_z: float = 0.0, max_range_m: float = FRUSTUM_RANGE_M) -> np.ndarray:
    """(4, 3) where the rays through the image corners meet the floor (a corner ray that
    points above the horizon ends at max_range_m): the camera's view on the floor."""
    cam, T = c.camera, c.T_world_cam
    corners = np.array([[0, 0], [cam.width - 1, 0], [cam.width - 1, cam.height - 1], [0, cam.height - 1]], float)
    rays = cam.bearings(corners) @ T[:3, :3].T
    C = T[:3, 3]
    down = rays[:, 2] < -1e-6
    t = np.where(down, (floor_z - C[2]) / np.where(down, rays[:, 2], -1.0), max_range_m)
    return C + rays * np.minimum(t, max_range_m)[:, None]


def wall_segments(planes) -> list[np.ndarray]:
    """(2, 2) top-view segment of each wall (yowo_msgs/Plane KIND_WALL): the extent of its
    outline along the wall."""
    out = []
    for pl in planes:
        if pl.kind != 2 or not pl.boundary:  # Plane.KIND_WALL
            continue
        xy = np.array([[q.x, q.y] for q in pl.boundary])
        n = np.array(pl.coefficients[:2], float)
        along = np.array([-n[1], n[0]]) / max(np.linalg.norm(n), 1e-9)
        s = xy @ along
        out.append(xy[[np.argmin(s), np.argmax(s)]])
    return out


def _ellipse_scale(cameras: list[RegisteredCmc]) -> float:
    """Position ellipses are drawn enlarged (centimetre sigmas are invisible on a room
    plan): a 1-2-5 factor that makes the largest 3-sigma ellipse about 0.4 m across."""
    sig = [pose_sigma(c.covariance) for c in cameras if c.T_world_cam is not None]
    largest = max((float(s[:2].max()) for s in sig if s is not None), default=0.0)
    if largest <= 0:
        return 1.0
    wanted = max(0.4 / (6 * largest), 1.0)
    decade = 10 ** np.floor(np.log10(wanted))
    return float(max(m * decade for m in (1, 2, 5) if m * decade <= wanted))


def top_view_png(
    cameras: list[RegisteredCmc],
    ego_xy: np.ndarray | None,
    floors: list[np.ndarray],
    gt_cameras: dict[str, np.ndarray] | None = None,
    walls: list[np.ndarray] | None = None,
    weak_places: list[dict] | None = None,
) -> bytes:
    from matplotlib.patches import Circle, Ellipse, Polygon
    from matplotlib.path import Path as MplPath

    fig, ax = plt.subplots(figsize=(10, 7))
    floor_patches = []
    for poly in floors:
        floor_patches.append(
            ax.add_patch(Polygon(poly, closed=True, facecolor="0.92", edgecolor="0.6", lw=1, zorder=0))
        )
    # The views are drawn on the floor only (a corner ray near the horizon meets the floor
    # plane far beyond the walls).
    clip = (
        MplPath.make_compound_path(*[q.get_path().transformed(q.get_patch_transform()) for q in floor_patches])
        if floor_patches
        else None
    )
    for i, seg in enumerate(walls or []):
        ax.plot(*seg.T, color="0.25", lw=3, solid_capstyle="butt", label="walls" if i == 0 else None)
    if ego_xy is not None and len(ego_xy):
        ax.plot(*ego_xy.T, color="#1f77b4", lw=1, label="ego path")
    scale = _ellipse_scale(cameras)
    extent = [np.asarray(q) for q in [*floors, *(walls or [])]]
    for c in cameras:
        if c.T_world_cam is None:
            continue
        C, col = c.T_world_cam[:3, 3], _COLOURS.get(c.status, _UNKNOWN)
        extent.append(C[None, :2])
        if c.camera is not None:
            foot = floor_footprint(c)
            artists = [ax.add_patch(Polygon(foot[:, :2], closed=True, facecolor=col, alpha=0.1, edgecolor=col, lw=0.8))]
            artists += [ax.plot([C[0], q[0]], [C[1], q[1]], color=col, lw=0.6, alpha=0.7)[0] for q in foot]
            if clip is not None:
                for a in artists:
                    a.set_clip_path(clip, ax.transData)
        ax.plot(C[0], C[1], "^", color=col, ms=8)
        sig = pose_sigma(c.covariance)
        if sig is not None:
            w, V = np.linalg.eigh(np.asarray(c.covariance)[:2, :2])
            ax.add_patch(
                Ellipse(
                    C[:2],
                    *(2 * 3 * scale * np.sqrt(np.clip(w, 0, None))),
                    angle=np.degrees(np.arctan2(V[1, 0], V[0, 0])),
                    fill=False,
                    color=col,
                    lw=1.2,
                )
            )
        ax.annotate(c.name, C[:2], fontsize=7, xytext=(4, 4), textcoords="offset points")
        if gt_cameras and c.name in gt_cameras:
            G = gt_cameras[c.name][:3, 3]
            ax.plot(G[0], G[1], "x", color="k", ms=6)
    for i, w in enumerate(weak_places or []):
        # A circle over the place (at least half a metre across), numbered as in the table.
        col = _WEAK_COLOURS.get(w["kind"], _UNKNOWN)
        ax.add_patch(Circle((w["x_m"], w["y_m"]), max(w["extent_m"] / 2, 0.25), fill=False, ls="--", color=col, lw=1.5))
        ax.annotate(f"W{i + 1}", (w["x_m"], w["y_m"]), color=col, fontsize=8, ha="center", va="center")
    if ego_xy is not None and len(ego_xy):
        extent.append(ego_xy)
    pts = np.vstack(extent) if extent else np.zeros((1, 2))  # nothing to draw: an empty metre around 0
    lo, hi = pts.min(axis=0) - 0.5, pts.max(axis=0) + 0.5
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(
        "top view (map frame): triangles = registered CMCs with their view of the floor, "
        f"ellipses = 3-sigma position x {scale:g}" + (", x = ground truth" if gt_cameras else ""),
        fontsize=9,
    )
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=8)
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _camera_table(cameras: list[RegisteredCmc]) -> str:
    return (
        "<table><tr><th>name</th><th>group</th><th>method</th><th>verdict</th><th>position [m]</th>"
        "<th>1-sigma pos / rot</th><th>RMSE [px]</th><th>agent obs</th><th>scene obs</th><th>reason</th></tr>"
        f"{_camera_rows(cameras)}</table>"
    )


def _camera_rows(cameras: list[RegisteredCmc]) -> str:
    rows = []
    for c in cameras:
        if c.T_world_cam is not None:
            pos = ", ".join(f"{v:.3f}" for v in c.T_world_cam[:3, 3])
            sig = pose_sigma(c.covariance)
            unc = (
                "unknown"
                if sig is None
                else f"{np.linalg.norm(sig[:3]) * 100:.1f} cm / {np.degrees(np.linalg.norm(sig[3:])):.2f}&deg;"
            )
        else:
            pos = unc = "-"
        cells = [
            c.name,
            c.group or "-",
            c.method,
            f'<b style="color:{_COLOURS.get(c.status, _UNKNOWN)}">{c.status}</b>',
            pos,
            unc,
            f"{c.rmse_px:.2f}",
            str(c.num_agent),
            str(c.num_scene),
            html.escape(c.reason),
        ]
        rows.append("<tr>" + "".join(f"<td>{x}</td>" for x in cells) + "</tr>")
    return "\n".join(rows)


PANEL_POINTS = 3000  # observations drawn per panel (a random, seeded subset of more)


def agent_fit_png(fit: AgentFit, size: tuple[int, int], background: np.ndarray | None) -> bytes:
    """One camera's panel: observed (dots) and reprojected (crosses) agent keypoints over its
    background, the histogram of reprojection errors, the coverage of the image."""
    w, h = size
    err = np.linalg.norm(fit.observed_uv - fit.reprojected_uv, axis=1)
    ok = np.isfinite(err)
    pick = np.flatnonzero(ok)
    if len(pick) > PANEL_POINTS:
        pick = np.sort(np.random.default_rng(0).choice(pick, PANEL_POINTS, replace=False))
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), gridspec_kw={"width_ratios": [1.4, 1, 1.1]})
    ax = axes[0]
    if background is not None:
        ax.imshow(background, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    else:
        ax.add_patch(plt.Rectangle((-0.5, -0.5), w, h, color="0.85"))
    ax.plot(*fit.reprojected_uv[pick].T, "x", ms=3, color="#d62728", label="fused track, reprojected")
    ax.plot(*fit.observed_uv[pick].T, ".", ms=2, color="#1f77b4", label="observed")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_title(
        f"{fit.name}: agent keypoints" + ("" if background is not None else " (no image recorded)"), fontsize=9
    )
    ax.legend(loc="lower right", fontsize=7, markerscale=3)
    ax = axes[1]
    if ok.any():
        ax.hist(err[ok], bins=40, range=(0, max(float(np.percentile(err[ok], 99)), 1e-3)), color="#1f77b4")
        ax.axvline(float(np.sqrt(np.mean(err[ok] ** 2))), color="#d62728", lw=1, label="RMS")
        ax.legend(fontsize=7)
    ax.set_xlabel("reprojection error [px]")
    ax.set_ylabel("observations")
    ax.set_title(f"residuals ({int(ok.sum())} observations)", fontsize=9)
    ax = axes[2]
    cov = ax.hist2d(
        fit.observed_uv[ok, 0],
        fit.observed_uv[ok, 1],
        bins=(16, max(2, round(16 * h / w))),
        range=((0, w), (0, h)),
        cmap="viridis",
        cmin=1,
    )
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_title("where the agent was seen", fontsize=9)
    fig.colorbar(cov[3], ax=ax, label="observations")
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _panels_html(fits) -> str:
    parts = []
    for fit, size, background in fits:
        png = base64.b64encode(agent_fit_png(fit, size, background)).decode()
        parts.append(
            f'<div class="panel" id="panel-{html.escape(fit.name)}"><h3>{html.escape(fit.name)}</h3>'
            f'<img src="data:image/png;base64,{png}" alt="{html.escape(fit.name)} agent fit"></div>'
        )
    return "\n".join(parts)


def _metrics_html(metrics: dict) -> str:
    parts = []
    for key, title in (
        ("registration", "CMC registration (world frame, no alignment)"),
        ("relative", "CMC relative pose (KU-aligned per group)"),
    ):
        if key in metrics:
            s = metrics[key]["summary"]
            parts.append(
                f"<h3>{title}</h3><table><tr><th></th><th>avg</th><th>min</th><th>max</th></tr>"
                f"<tr><td>eps_pos [m]</td>"
                + "".join(f"<td>{s[f'pos_{k}']:.4f}</td>" for k in ("avg", "min", "max"))
                + "</tr><tr><td>eps_rot [deg]</td>"
                + "".join(f"<td>{s[f'rot_{k}']:.3f}</td>" for k in ("avg", "min", "max"))
                + "</tr></table>"
            )
    if "ego" in metrics:
        parts.append(f"<p>ego ATE RMSE: {metrics['ego']['ate_rmse_m']:.4f} m ({metrics['ego']['matched']} poses)</p>")
    if "layout" in metrics:
        parts.append(f"<p>layout IoU: {metrics['layout']['iou']:.3f}</p>")
    return "\n".join(parts)


_WEAK_COLOURS = {"weak tracking": "#d62728", "walked once": "#9467bd", "track misses the walk": "#ff7f0e"}


def _weak_places_html(places: list[dict]) -> str:
    if not places:
        return "<p>None found: every stretch was tracked well, walked more than once, and fits the groups' tracks.</p>"
    rows = "".join(
        f"<tr><td>W{i + 1}</td><td>{html.escape(w['kind'])}</td><td>{w['start_s']:.1f}-{w['end_s']:.1f} s</td>"
        f"<td>({w['x_m']:.1f}, {w['y_m']:.1f}) m</td><td>{html.escape(w['why'])}</td></tr>"
        for i, w in enumerate(places)
    )
    return (
        "<p>Where a second walk would help the map (dashed circles in the top view; also in weak_places.yaml).</p>"
        f"<table><tr><th></th><th>kind</th><th>when</th><th>where</th><th>why</th></tr>{rows}</table>"
    )


def _walkers_html(walkers: dict[str, dict]) -> str:
    """Per camera, each person its pose model tracked: tracks, time in view, agreement of its
    walking and standing with the head camera's, and the decision."""
    rows = []
    for name, w in sorted(walkers.items()):
        people = w.get("people") or [{}]
        for k, e in enumerate(people):
            agreement = "-" if e.get("agreement") is None else f"{e['agreement']:.2f} (&ge; {e['confidence']:.2f})"
            cells = [
                html.escape(name) if k == 0 else "",
                ", ".join(map(str, e.get("tracks", []))) or "-",
                f"{e['seconds']:.1f}" if "seconds" in e else "-",
                agreement,
                "<b>walker</b>" if e.get("walker") else "",
                html.escape(e.get("why") or w.get("reason", "")),
            ]
            rows.append("<tr>" + "".join(f"<td>{x}</td>" for x in cells) + "</tr>")
    return (
        "<table><tr><th>camera</th><th>tracks</th><th>seen [s]</th><th>agreement with the head camera</th>"
        "<th></th><th>why</th></tr>" + "".join(rows) + "</table>"
    )


def write_report(
    path: Path,
    title: str,
    cameras: list[RegisteredCmc],
    ego_xy,
    floors,
    metrics: dict | None = None,
    gt_cameras=None,
    notes: list[str] | None = None,
    walls: list[np.ndarray] | None = None,
    fits=(),
    no_cameras: str = "",
    walkers: dict[str, dict] | None = None,
    weak_places: list[dict] | None = None,
) -> None:
    """`fits`: (AgentFit, (width, height), background RGB or None) per grouped camera;
    `no_cameras`: why the run registered none (an ego-only run), shown instead of the table;
    `walkers`: per camera of the pose model, the person taken for the walker and the evidence;
    `weak_places`: the walk's weak places (None: the run has no fusion)."""
    png = base64.b64encode(top_view_png(cameras, ego_xy, floors, gt_cameras, walls, weak_places)).decode()
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>YOWO report: {html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px}}</style></head><body>
<h1>YOWO report</h1><p>{html.escape(title)}</p>
<img src="data:image/png;base64,{png}" alt="top view">
<h2>Cameras</h2>{f"<p>{html.escape(no_cameras)}</p>" if no_cameras else _camera_table(cameras)}
{"<h2>Per camera: the agent track in its view</h2>" + _panels_html(fits) if fits else ""}
{"<h2>Who is the walker</h2>" + _walkers_html(walkers) if walkers else ""}
{"<h2>Weak places of the walk</h2>" + _weak_places_html(weak_places) if weak_places is not None else ""}
{"<h2>Metrics against ground truth</h2>" + _metrics_html(metrics) if metrics else ""}
{"<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>" if notes else ""}
</body></html>"""
    Path(path).write_text(doc)
