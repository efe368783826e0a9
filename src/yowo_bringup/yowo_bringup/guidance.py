"""The walk guidance (yowo_msgs/WalkGuidance on /yowo/guidance) for people: one line per camera
that needs more on the console of `yowo live`, printed when what it says changes; a page that
reloads itself with every camera's (guidance_live.html); and its account in the run log (how
often it came, what it said last). No ROS here: the run monitor collects the messages."""

from __future__ import annotations

import html
import re
import time
from pathlib import Path

import numpy as np

from yowo_common.rosconv import stamp_to_ns

NEEDS_MORE = "needs more"
REASONS_SHOWN = 2  # reasons on a camera's console line; the rest are counted
_NUMBER = re.compile(r"\d+(\.\d+)?")


def camera_line(cam, final: bool = False) -> str:
    """A camera's console line: its name, its verdict and what is missing."""
    head = f"guidance{' (end of walk)' if final else ''}: {cam.name}"
    if cam.verdict != NEEDS_MORE:
        return f"{head} ok"
    reasons = list(cam.reasons)
    more = f" (+{len(reasons) - REASONS_SHOWN} more)" if len(reasons) > REASONS_SHOWN else ""
    return f"{head} needs more: {'; '.join(reasons[:REASONS_SHOWN])}{more}"


def _gist(cam) -> tuple:
    """What a camera's guidance says, its counts left out: a count that grows is no news."""
    return cam.verdict, tuple(_NUMBER.sub("#", r) for r in cam.reasons)


class GuidanceLines:
    """Prints each camera's guidance line when its gist changes: a camera that needs more when
    first heard of, one whose reasons change, one that became ok, each at most every `period_s`;
    the final guidance (the walk is over) for every camera at once."""

    def __init__(self, log=print, period_s: float = 5.0, clock=time.monotonic):
        self.log, self.period_s, self.clock = log, period_s, clock
        self._said: dict[str, tuple] = {}  # camera -> the gist last printed
        self._at: dict[str, float] = {}  # camera -> when

    def __call__(self, msg) -> None:
        now = self.clock()
        for cam in msg.cameras:
            gist = _gist(cam)
            said = self._said.get(cam.name)
            if not msg.final:
                if gist == said or (said is None and cam.verdict != NEEDS_MORE):
                    continue  # unchanged, or ok from the start: nothing to do there
                if now - self._at.get(cam.name, -np.inf) < self.period_s:
                    continue  # changed again too soon: the next guidance tells it
            self._said[cam.name], self._at[cam.name] = gist, now
            self.log(camera_line(cam, msg.final))


def guidance_log(msgs: list, arrivals_s: list[float]) -> dict:
    """The run log's account of the walk guidance: how many updates, their spacing in the walk's
    time (stamps) and on arrival at the run monitor (`arrivals_s`: seconds, one per message), and the last one's verdicts."""
    if not msgs:
        return {"updates": 0}
    during = [m for m in msgs if not m.final]
    stamps = np.array([stamp_to_ns(m.header.stamp) for m in during], dtype=np.int64) / 1e9
    arrived = np.array([t for t, m in zip(arrivals_s, msgs) if not m.final])

    def gaps(x: np.ndarray) -> dict | None:
        d = np.diff(x)
        return None if len(d) == 0 else {"median": round(float(np.median(d)), 3), "max": round(float(d.max()), 3)}

    last = msgs[-1]
    return {
        "updates": len(during),
        "final": bool(last.final),
        "walk_time_between_updates_s": gaps(stamps),
        "wall_time_between_updates_s": gaps(arrived),
        "cameras": {c.name: {"verdict": c.verdict, "reasons": list(c.reasons)} for c in last.cameras},
    }


NINTH_NAMES = (
    ("top-left corner", "top edge", "top-right corner"),
    ("left edge", "centre", "right edge"),
    ("bottom-left corner", "bottom edge", "bottom-right corner"),
)
PAGE_REFRESH_S = 1  # the page reloads itself this often [s]


def _ninths_html(cam) -> str:
    """The image's ninths as a 3 x 3 grid: filled where the walker was seen."""
    seen = set(cam.regions_seen)
    cells = "".join(
        "<tr>" + "".join(f'<td class="{"seen" if n in seen else "missing"}" title="{n}"></td>' for n in row) + "</tr>"
        for row in NINTH_NAMES
    )
    return f'<table class="ninths">{cells}</table>' if seen or cam.regions_missing else "-"


def guidance_page(msg, title: str) -> str:
    """A self-refreshing HTML page of one walk guidance update: per camera its verdict, what is
    missing, where in its image the walker was seen, and which cameras saw the walker with it."""
    rows = []
    for cam in msg.cameras:
        ok = cam.verdict != NEEDS_MORE
        with_others = ", ".join(f"{n} ({t})" for n, t in zip(cam.covisible_cameras, cam.covisible_times)) or "-"
        rows.append(
            f'<tr><td>{html.escape(cam.name)}</td><td class="{"ok" if ok else "more"}">{html.escape(cam.verdict)}</td>'
            f"<td>{'<br>'.join(html.escape(r) for r in cam.reasons) or '-'}</td><td>{_ninths_html(cam)}</td>"
            f"<td>{cam.observations}</td><td>{html.escape(with_others)}</td></tr>"
        )
    t = stamp_to_ns(msg.header.stamp) / 1e9
    state = (
        "the walk is over: this is its final guidance (guidance.html has the floor plan and a second walk)"
        if msg.final
        else f"during the walk; updated at {time.strftime('%H:%M:%S')} (walk time {t:.1f} s)"
    )
    refresh = "" if msg.final else f'<meta http-equiv="refresh" content="{PAGE_REFRESH_S}">'
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8">{refresh}<title>walk guidance: {html.escape(title)}</title>
<style>body{{font-family:sans-serif;margin:1.5em}} table.cams{{border-collapse:collapse}}
table.cams td,table.cams th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top;text-align:left}}
.ok{{color:#2ca02c;font-weight:bold}} .more{{color:#d62728;font-weight:bold}}
table.ninths{{border-collapse:collapse}} table.ninths td{{width:14px;height:10px;border:1px solid #888;padding:0}}
td.seen{{background:#1f77b4}} td.missing{{background:#fff}}</style></head>
<body><h2>Walk guidance: {html.escape(title)}</h2>
<p>{html.escape(state)}. {msg.needs_more} of {len(msg.cameras)} cameras need more.</p>
<table class="cams"><tr><th>camera</th><th>verdict</th><th>what is missing</th><th>walker seen in the image</th>
<th>observations</th><th>seen with</th></tr>
{"".join(rows)}</table></body></html>
"""


class GuidancePage:
    """Writes each walk guidance update to a page that reloads itself (atomically: a browser
    never reads half a page)."""

    def __init__(self, path, title: str):
        self.path, self.title = Path(path), title

    def __call__(self, msg) -> None:
        tmp = self.path.with_name(f".{self.path.name}.tmp")
        tmp.write_text(guidance_page(msg, self.title))
        tmp.replace(self.path)
