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

from yowo_cmc.coverage import NEEDS_MORE, OK  # noqa: E402
from yowo_cmc.params import CoverageParams  # noqa: E402
from yowo_fusion.records import AgentFit, RegisteredCmc  # noqa: E402

from .results import pose_sigma  # noqa: E402
from .second_walk import (  # noqa: E402
    CLOSER,
    PAUSE,
    WALK_THROUGH,
    WITH_ANOTHER,
    CameraVerdict,
    SecondWalk,
    box_on_plane,
    plan_second_walk,
    write_second_walk_yaml,
)

# Verdict colours as CSS hex (matplotlib takes them too): tab:green, tab:orange, tab:red.
_COLOURS = {"ok": "#2ca02c", "weak": "#ff7f0e", "failed": "#d62728"}
_UNKNOWN = "#000000"
WALK_COLOUR = "#1f77b4"  # tab:blue, the first walk
FRUSTUM_RANGE_M = 8.0  # how far a corner ray that never meets the floor is drawn


def floor_footprint(c: RegisteredCmc, floor_z: float = 0.0, max_range_m: float = FRUSTUM_RANGE_M) -> np.ndarray:
    """(4, 3) where the rays through the image corners meet the floor (a corner ray that
    points above the horizon ends at max_range_m): the camera's view on the floor."""
    return box_on_plane(c, (0, 0, c.camera.width - 1, c.camera.height - 1), floor_z, max_range_m)


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


def _draw_plan(
    ax, floors: list[np.ndarray], walls: list[np.ndarray] | None, ego_xy: np.ndarray | None, walk_lw: float = 1.0
):
    """The floor polygons, the walls and the walk; returns the floor as a clip path for what is
    drawn on it (None: no floor)."""
    from matplotlib.patches import Polygon
    from matplotlib.path import Path as MplPath

    floor_patches = []
    for poly in floors:
        floor_patches.append(
            ax.add_patch(Polygon(poly, closed=True, facecolor="0.92", edgecolor="0.6", lw=1, zorder=0))
        )
    for i, seg in enumerate(walls or []):
        ax.plot(*seg.T, color="0.25", lw=3, solid_capstyle="butt", label="walls" if i == 0 else None)
    if ego_xy is not None and len(ego_xy):
        ax.plot(*ego_xy.T, color=WALK_COLOUR, lw=walk_lw, label="ego path")
    return (
        MplPath.make_compound_path(*[q.get_path().transformed(q.get_patch_transform()) for q in floor_patches])
        if floor_patches
        else None
    )


def _draw_view(ax, c: RegisteredCmc, col: str, clip) -> None:
    """A camera's view of the floor (on the floor only: a corner ray near the horizon meets the
    floor plane far beyond the walls) and its corner rays."""
    from matplotlib.patches import Polygon

    C, foot = c.T_world_cam[:3, 3], floor_footprint(c)
    artists = [ax.add_patch(Polygon(foot[:, :2], closed=True, facecolor=col, alpha=0.1, edgecolor=col, lw=0.8))]
    artists += [ax.plot([C[0], q[0]], [C[1], q[1]], color=col, lw=0.6, alpha=0.7)[0] for q in foot]
    if clip is not None:
        for a in artists:
            a.set_clip_path(clip, ax.transData)


def _draw_weak_places(ax, weak_places: list[dict] | None) -> None:
    """A dashed circle over each place (at least half a metre across), numbered as in the table."""
    from matplotlib.patches import Circle

    for i, w in enumerate(weak_places or []):
        col = _WEAK_COLOURS.get(w["kind"], _UNKNOWN)
        ax.add_patch(Circle((w["x_m"], w["y_m"]), max(w["extent_m"] / 2, 0.25), fill=False, ls="--", color=col, lw=1.5))
        ax.annotate(f"W{i + 1}", (w["x_m"], w["y_m"]), color=col, fontsize=8, ha="center", va="center")


def _finish_png(fig, ax, extent: list[np.ndarray], title: str) -> bytes:
    """Frame the drawing around everything in `extent` (half a metre around), title, legend, PNG."""
    pts = np.vstack(extent) if extent else np.zeros((1, 2))  # nothing to draw: an empty metre around 0
    lo, hi = pts.min(axis=0) - 0.5, pts.max(axis=0) + 0.5
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=8)
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def top_view_png(
    cameras: list[RegisteredCmc],
    ego_xy: np.ndarray | None,
    floors: list[np.ndarray],
    gt_cameras: dict[str, np.ndarray] | None = None,
    walls: list[np.ndarray] | None = None,
    weak_places: list[dict] | None = None,
) -> bytes:
    from matplotlib.patches import Ellipse

    fig, ax = plt.subplots(figsize=(10, 7))
    clip = _draw_plan(ax, floors, walls, ego_xy)
    scale = _ellipse_scale(cameras)
    extent = [np.asarray(q) for q in [*floors, *(walls or [])]]
    for c in cameras:
        if c.T_world_cam is None:
            continue
        C, col = c.T_world_cam[:3, 3], _COLOURS.get(c.status, _UNKNOWN)
        extent.append(C[None, :2])
        if c.camera is not None:
            _draw_view(ax, c, col, clip)
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
    _draw_weak_places(ax, weak_places)
    if ego_xy is not None and len(ego_xy):
        extent.append(ego_xy)
    title = (
        "top view (map frame): triangles = registered CMCs with their view of the floor, "
        f"ellipses = 3-sigma position x {scale:g}" + (", x = ground truth" if gt_cameras else "")
    )
    return _finish_png(fig, ax, extent, title)


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


AREA_COLOUR = "#bcbd22"  # tab:olive, the floor a camera needs the walker in
SECOND_WALK_COLOUR = "#e377c2"  # tab:pink, the suggested second walk
_GUIDANCE_COLOURS = {OK: _COLOURS["ok"], NEEDS_MORE: _COLOURS["failed"]}
_HATCHES = {WALK_THROUGH: "//", PAUSE: "..", CLOSER: "xx", WITH_ANOTHER: "\\\\"}


def _shape_patches(area):
    """Matplotlib patches of a shapely (multi)polygon's outer rings."""
    from matplotlib.patches import Polygon

    parts = getattr(area, "geoms", [area])
    return [
        Polygon(np.asarray(g.exterior.coords), closed=True)
        for g in parts
        if g.geom_type == "Polygon" and not g.is_empty
    ]


def floor_plan_png(
    cameras: list[RegisteredCmc],
    verdicts: list[CameraVerdict],
    walk: SecondWalk,
    ego_xy: np.ndarray | None,
    floors: list[np.ndarray],
    walls: list[np.ndarray] | None = None,
    weak_places: list[dict] | None = None,
) -> bytes:
    """The floor plan of the guidance: the walk, each camera by its verdict (the view of those
    that need more), the floor areas their needs ask for (hatched by kind), the weak places and
    the numbered second walk."""
    fig, ax = plt.subplots(figsize=(10, 7.5))
    _draw_plan(ax, floors, walls, ego_xy, walk_lw=2.0)
    verdict = {v.name: v.verdict for v in verdicts}
    extent = [np.asarray(q) for q in [*floors, *(walls or [])]]
    for c in cameras:
        if c.T_world_cam is None:
            continue
        C, col = c.T_world_cam[:3, 3], _GUIDANCE_COLOURS.get(verdict.get(c.name, ""), _UNKNOWN)
        extent.append(C[None, :2])
        trusted = c.name not in walk.unplaced
        ax.plot(C[0], C[1], "^", color=col, ms=9, mfc=col if trusted else "none")
        pose = "" if c.status == "ok" else f" (pose {c.status})"
        ax.annotate(
            f"{c.name}: {verdict.get(c.name, '?')}{pose}", C[:2], fontsize=8, xytext=(5, 5), textcoords="offset points"
        )
    label = "floor a camera needs you in"
    for need in (n for n in walk.needs if n.camera):
        for fill, edge in zip(_shape_patches(need.area), _shape_patches(need.area)):
            fill.set(facecolor=AREA_COLOUR, alpha=0.25, edgecolor="none", hatch=_HATCHES.get(need.kind))
            edge.set(fill=False, edgecolor=AREA_COLOUR, lw=1.5, label=label)
            ax.add_patch(fill)
            ax.add_patch(edge)
            label = None
        extent.append(np.asarray(need.area.envelope.exterior.coords)[:, :2])
    _draw_weak_places(ax, weak_places)
    if len(walk.route_xy):
        ax.plot(*walk.route_xy.T, color=SECOND_WALK_COLOUR, lw=2.5, label="suggested second walk")
        ax.plot(*walk.route_xy[0], "*", color=SECOND_WALK_COLOUR, ms=16, mec="k", label="its start")
        for k, w in enumerate(walk.waypoints):
            ax.annotate(
                str(k + 1),
                (w.x_m, w.y_m),
                ha="center",
                va="center",
                fontsize=8,
                fontweight="bold",
                bbox={"boxstyle": "circle,pad=0.25", "fc": "white", "ec": SECOND_WALK_COLOUR, "lw": 2},
            )
        extent.append(walk.route_xy)
    if ego_xy is not None and len(ego_xy):
        extent.append(ego_xy)
    title = (
        "floor plan (map frame): the walk (blue), cameras by their final guidance (hollow: pose not trusted),\n"
        "hatched = floor a camera needs you in, pink = the suggested second walk"
    )
    return _finish_png(fig, ax, extent, title)


def _needs_html(v: CameraVerdict, walk: SecondWalk, numbers: dict[int, int]) -> str:
    """What would improve a camera: its needs with their waypoints."""
    if v.verdict != NEEDS_MORE:
        return "-"
    items = [
        f"{html.escape(n.why)} (waypoint {numbers[id(n)]})"
        for n in walk.needs
        if n.camera == v.name and id(n) in numbers
    ]
    head = html.escape(walk.unplaced[v.name]) if v.name in walk.unplaced else ""
    return head + ("<ul>" + "".join(f"<li>{x}</li>" for x in items) + "</ul>" if items else "")


def write_guidance_page(
    path: Path,
    title: str,
    cameras: list[RegisteredCmc],
    verdicts: list[CameraVerdict],
    walk: SecondWalk,
    ego_xy,
    floors,
    walls: list[np.ndarray] | None = None,
    weak_places: list[dict] | None = None,
    walk_file: str = "second_walk.yaml",
) -> None:
    """guidance.html: the floor plan of the guidance after the walk, each camera's verdict and
    what would improve it, and the suggested second walk (also in `walk_file`)."""
    png = base64.b64encode(floor_plan_png(cameras, verdicts, walk, ego_xy, floors, walls, weak_places)).decode()
    numbers = {id(n): k + 1 for k, w in enumerate(walk.waypoints) for n in w.needs}
    needing = [v.name for v in verdicts if v.verdict == NEEDS_MORE]
    cams = "".join(
        f"<tr><td>{html.escape(v.name)}</td>"
        f'<td><b style="color:{_GUIDANCE_COLOURS.get(v.verdict, _UNKNOWN)}">{html.escape(v.verdict)}</b></td>'
        f"<td>{'<br>'.join(html.escape(r) for r in v.reasons) or '-'}</td><td>{_needs_html(v, walk, numbers)}</td></tr>"
        for v in verdicts
    )
    stops = "".join(
        f"<tr><td>{k + 1}</td><td>({w.x_m:.2f}, {w.y_m:.2f})</td><td>{w.pause_s:g}</td>"
        f"<td>{', '.join(w.cameras) or 'the map'}</td>"
        f"<td>{'<br>'.join(html.escape(f'{n.camera}: {n.why}' if n.camera else n.why) for n in w.needs)}</td></tr>"
        for k, w in enumerate(walk.waypoints)
    )
    start = (
        "" if walk.start_xy is None else f", from ({walk.start_xy[0]:.2f}, {walk.start_xy[1]:.2f}) on the first walk"
    )
    summary = (
        f"{len(needing)} of {len(verdicts)} cameras need more: {', '.join(needing)}."
        if needing
        else f"All {len(verdicts)} cameras are ok."
    )
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>YOWO guidance: {html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px;vertical-align:top}} ul{{margin:0;padding-left:1.2em}}</style>
</head><body>
<h1>Guidance after the walk</h1><p>{html.escape(title)} &middot; <a href="report.html">the report</a></p>
<p>{html.escape(summary)} The suggested second walk: {len(walk.waypoints)} waypoints, {walk.length_m:.1f} m{start}
(<a href="{html.escape(walk_file)}">{html.escape(walk_file)}</a>, waypoints in the map frame).</p>
<img src="data:image/png;base64,{png}" alt="floor plan with the suggested second walk">
<h2>Cameras: verdict and what would improve it</h2>
<table><tr><th>camera</th><th>verdict</th><th>what is missing</th><th>what would improve it</th></tr>{cams}</table>
<h2>The suggested second walk</h2>
<p>Walk the waypoints in their order, pausing where told; the path between them stays on the mapped floor where it can.
Combining a recording of only this walk with the first one in one run (<code>yowo run</code> with two recordings)
is not possible yet: record the whole walk again with these places in it.</p>
<table><tr><th>#</th><th>where [m]</th><th>pause [s]</th><th>for</th><th>why</th></tr>{stops}</table>
</body></html>"""
    Path(path).write_text(doc)


def write_guidance(
    out_dir: Path,
    title: str,
    cameras: list[RegisteredCmc],
    final_guidance,
    ego_xy,
    floors,
    walls: list[np.ndarray] | None,
    weak_places: list[dict] | None,
    coverage: CoverageParams,
    sightings: dict[str, np.ndarray] | None = None,
) -> list[Path]:
    """The guidance after the walk from the final walk guidance (yowo_msgs/WalkGuidance):
    second_walk.yaml and its floor-plan page guidance.html; the files written."""
    verdicts = [CameraVerdict.from_msg(c) for c in final_guidance.cameras]
    walk = plan_second_walk(
        cameras=cameras,
        verdicts=verdicts,
        floors=floors,
        ego_xy=ego_xy,
        weak_places=weak_places,
        sightings=sightings,
        coverage=coverage,
    )
    write_second_walk_yaml(out_dir / "second_walk.yaml", walk)
    write_guidance_page(out_dir / "guidance.html", title, cameras, verdicts, walk, ego_xy, floors, walls, weak_places)
    return [out_dir / "second_walk.yaml", out_dir / "guidance.html"]


def _guidance_link(page: str) -> str:
    if not page:
        return ""
    return (
        f'<p><b><a href="{html.escape(page)}">Guidance after the walk</a></b>: the floor plan with what each camera '
        "still needs and a suggested second walk.</p>"
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
    guidance_page: str = "",
) -> None:
    """`fits`: (AgentFit, (width, height), background RGB or None) per grouped camera;
    `no_cameras`: why the run registered none (an ego-only run), shown instead of the table;
    `walkers`: per camera of the pose model, the person taken for the walker and the evidence;
    `weak_places`: the walk's weak places (None: the run has no fusion); `guidance_page`: the
    guidance after the walk (write_guidance's page, beside the report; '' none)."""
    png = base64.b64encode(top_view_png(cameras, ego_xy, floors, gt_cameras, walls, weak_places)).decode()
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>YOWO report: {html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px}}</style></head><body>
<h1>YOWO report</h1><p>{html.escape(title)}</p>
{_guidance_link(guidance_page)}
<img src="data:image/png;base64,{png}" alt="top view">
<h2>Cameras</h2>{f"<p>{html.escape(no_cameras)}</p>" if no_cameras else _camera_table(cameras)}
{"<h2>Per camera: the agent track in its view</h2>" + _panels_html(fits) if fits else ""}
{"<h2>Who is the walker</h2>" + _walkers_html(walkers) if walkers else ""}
{"<h2>Weak places of the walk</h2>" + _weak_places_html(weak_places) if weak_places is not None else ""}
{"<h2>Metrics against ground truth</h2>" + _metrics_html(metrics) if metrics else ""}
{"<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>" if notes else ""}
</body></html>"""
    Path(path).write_text(doc)
