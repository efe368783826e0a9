"""report.html of a run: a top view (layout, ego path, camera frustums), the
per-camera table with uncertainty and verdict, and the metrics when ground truth
was available. One self-contained file (the figure is embedded)."""
from __future__ import annotations

import base64
import html
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from yowo_fusion.pipeline import RegisteredCmc  # noqa: E402

from .results import pose_sigma  # noqa: E402

_COLOURS = {"ok": "tab:green", "weak": "tab:orange", "failed": "tab:red"}


def top_view_png(cameras: list[RegisteredCmc], ego_xy: np.ndarray | None, floors: list[np.ndarray],
                 gt_cameras: dict[str, np.ndarray] | None = None) -> bytes:
    fig, ax = plt.subplots(figsize=(9, 6))
    for poly in floors:
        ax.fill(*np.vstack([poly, poly[:1]]).T, color="0.9", zorder=0)
        ax.plot(*np.vstack([poly, poly[:1]]).T, color="0.5", lw=1)
    if ego_xy is not None and len(ego_xy):
        ax.plot(*ego_xy.T, color="tab:blue", lw=1, label="ego path")
    for c in cameras:
        if c.T_world_cam is None:
            continue
        C, z = c.T_world_cam[:3, 3], c.T_world_cam[:3, 2]
        col = _COLOURS.get(c.status, "k")
        ax.plot(C[0], C[1], "^", color=col, ms=8)
        d = z[:2] / max(np.linalg.norm(z[:2]), 1e-9) * 0.8
        ax.annotate("", xy=C[:2] + d, xytext=C[:2], arrowprops=dict(arrowstyle="->", color=col))
        ax.annotate(c.name, C[:2], fontsize=7, xytext=(4, 4), textcoords="offset points")
        if gt_cameras and c.name in gt_cameras:
            G = gt_cameras[c.name][:3, 3]
            ax.plot(G[0], G[1], "x", color="k", ms=6)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("top view (map frame): triangles = registered CMCs, x = ground truth")
    if ego_xy is not None:
        ax.legend(loc="best", fontsize=8)
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _camera_rows(cameras: list[RegisteredCmc]) -> str:
    rows = []
    for c in cameras:
        if c.T_world_cam is not None:
            pos = ", ".join(f"{v:.3f}" for v in c.T_world_cam[:3, 3])
            sig = pose_sigma(c.covariance)
            unc = "unknown" if sig is None else \
                f"{np.linalg.norm(sig[:3]) * 100:.1f} cm / {np.degrees(np.linalg.norm(sig[3:])):.2f}&deg;"
        else:
            pos = unc = "-"
        cells = [c.name, c.group or "-", c.method, f'<b style="color:{_COLOURS.get(c.status, "k")}">{c.status}</b>',
                 pos, unc, f"{c.rmse_px:.2f}", str(c.num_agent), str(c.num_scene), html.escape(c.reason)]
        rows.append("<tr>" + "".join(f"<td>{x}</td>" for x in cells) + "</tr>")
    return "\n".join(rows)


def _metrics_html(metrics: dict) -> str:
    parts = []
    for key, title in (("registration", "CMC registration (world frame, no alignment)"),
                       ("relative", "CMC relative pose (KU-aligned per group)")):
        if key in metrics:
            s = metrics[key]["summary"]
            parts.append(f"<h3>{title}</h3><table><tr><th></th><th>avg</th><th>min</th><th>max</th></tr>"
                         f"<tr><td>eps_pos [m]</td>" + "".join(f"<td>{s[f'pos_{k}']:.4f}</td>" for k in ("avg", "min", "max"))
                         + "</tr><tr><td>eps_rot [deg]</td>"
                         + "".join(f"<td>{s[f'rot_{k}']:.3f}</td>" for k in ("avg", "min", "max")) + "</tr></table>")
    if "ego" in metrics:
        parts.append(f"<p>ego ATE RMSE: {metrics['ego']['ate_rmse_m']:.4f} m ({metrics['ego']['matched']} poses)</p>")
    if "layout" in metrics:
        parts.append(f"<p>layout IoU: {metrics['layout']['iou']:.3f}</p>")
    return "\n".join(parts)


def write_report(path: Path, title: str, cameras: list[RegisteredCmc], ego_xy, floors, metrics: dict | None = None,
                 gt_cameras=None, notes: list[str] | None = None) -> None:
    png = base64.b64encode(top_view_png(cameras, ego_xy, floors, gt_cameras)).decode()
    doc = f"""<!doctype html><html><head><meta charset="utf-8"><title>YOWO report: {html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:2em}} table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:3px 8px;font-size:13px}}</style></head><body>
<h1>YOWO report</h1><p>{html.escape(title)}</p>
<img src="data:image/png;base64,{png}" alt="top view">
<h2>Cameras</h2><table><tr><th>name</th><th>group</th><th>method</th><th>verdict</th><th>position [m]</th>
<th>1-sigma pos / rot</th><th>RMSE [px]</th><th>agent obs</th><th>scene obs</th><th>reason</th></tr>
{_camera_rows(cameras)}</table>
{"<h2>Metrics against ground truth</h2>" + _metrics_html(metrics) if metrics else ""}
{"<h2>Notes</h2><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>" if notes else ""}
</body></html>"""
    Path(path).write_text(doc)
