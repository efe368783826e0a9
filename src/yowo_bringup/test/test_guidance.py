"""The walk guidance on `yowo live`'s console (issue #48, part 3): one line per camera that needs
more, naming it and what is missing, printed when that changes (a growing count is no change),
at most every few seconds per camera; the end of the walk's guidance for every camera; and the
run log's account of how often it came."""

from yowo_bringup.guidance import REASONS_SHOWN, GuidanceLines, camera_line, guidance_log
from yowo_common.rosconv import ns_to_time
from yowo_msgs.msg import CameraGuidance, WalkGuidance

OK, MORE = CameraGuidance.VERDICT_OK, CameraGuidance.VERDICT_NEEDS_MORE
CORNER = "agent seen only in the image's top-left corner"


def _msg(t_s: float, cams: dict[str, list[str]], final: bool = False) -> WalkGuidance:
    """Guidance at walk time t_s: camera -> its reasons (none: ok)."""
    msg = WalkGuidance(
        final=final,
        cameras=[CameraGuidance(name=n, verdict=MORE if r else OK, reasons=r) for n, r in cams.items()],
    )
    msg.header.stamp = ns_to_time(int(t_s * 1e9))
    return msg


class Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_a_line_per_camera_that_needs_more_on_change_only():
    said, clock = [], Clock()
    lines = GuidanceLines(said.append, period_s=5.0, clock=clock)
    lines(_msg(1, {"cam00": ["only 63 agent observations (needs 200)", CORNER], "cam01": []}))
    assert said == [f"guidance: cam00 needs more: only 63 agent observations (needs 200); {CORNER}"]
    # A second later: more observations, the same gist -> nothing.
    clock.now = 1.0
    lines(_msg(2, {"cam00": ["only 99 agent observations (needs 200)", CORNER], "cam01": []}))
    assert len(said) == 1
    # The corner is resolved at 2 s: too soon after the last line; told at the first guidance after 5 s.
    for t in (2.0, 3.0, 4.0):
        clock.now = t
        lines(_msg(t + 1, {"cam00": ["agent seen in 12% of the image's grid cells (needs 20%)"], "cam01": []}))
    assert len(said) == 1
    clock.now = 5.5
    lines(_msg(6.5, {"cam00": ["agent seen in 14% of the image's grid cells (needs 20%)"], "cam01": []}))
    assert said[1:] == ["guidance: cam00 needs more: agent seen in 14% of the image's grid cells (needs 20%)"]
    # cam01 turns from ok to needs more: told at once (its own first line); cam00 becomes ok later.
    clock.now = 6.0
    lines(_msg(7, {"cam00": ["agent seen in 18% of the image's grid cells (needs 20%)"], "cam01": [CORNER]}))
    assert said[2:] == [f"guidance: cam01 needs more: {CORNER}"]
    clock.now = 11.0
    lines(_msg(12, {"cam00": [], "cam01": [CORNER]}))
    assert said[3:] == ["guidance: cam00 ok"]
    # The end of the walk: every camera, at once.
    clock.now = 11.2
    lines(_msg(12.2, {"cam00": [], "cam01": [CORNER]}, final=True))
    assert said[4:] == ["guidance (end of walk): cam00 ok", f"guidance (end of walk): cam01 needs more: {CORNER}"]


def test_a_line_shows_the_first_reasons_and_counts_the_rest():
    reasons = [f"reason {k}" for k in range(REASONS_SHOWN + 2)]
    line = camera_line(CameraGuidance(name="cam07", verdict=MORE, reasons=reasons))
    assert line == "guidance: cam07 needs more: reason 0; reason 1 (+2 more)"


def test_the_run_log_tells_how_often_the_guidance_came_and_what_it_said_last():
    msgs = [_msg(t, {"cam00": [CORNER], "cam01": []}) for t in (1.0, 2.0, 3.5)]
    msgs.append(_msg(3.6, {"cam00": [CORNER], "cam01": []}, final=True))
    log = guidance_log(msgs, [10.0, 11.1, 12.1, 15.0])
    assert log["updates"] == 3 and log["final"]
    assert log["walk_time_between_updates_s"] == {"median": 1.25, "max": 1.5}
    assert log["wall_time_between_updates_s"] == {"median": 1.05, "max": 1.1}  # the final one apart
    assert log["cameras"] == {"cam00": {"verdict": MORE, "reasons": [CORNER]}, "cam01": {"verdict": OK, "reasons": []}}
    assert guidance_log([], []) == {"updates": 0}


def test_the_page_shows_every_camera_and_reloads_itself_until_the_walk_is_over(tmp_path):
    from html.parser import HTMLParser

    from yowo_bringup.guidance import GuidancePage

    msg = _msg(3.5, {"cam00": [CORNER], "cam01": [], "cam<2>": ["only 5 agent observations (needs 200)"]})
    msg.cameras[0].regions_seen, msg.cameras[0].regions_missing = ["top-left corner"], ["centre"] * 8
    msg.cameras[1].covisible_cameras, msg.cameras[1].covisible_times = ["cam00"], [12]
    msg.needs_more = 2
    page = GuidancePage(tmp_path / "guidance_live.html", "bags/x")
    page(msg)
    text = (tmp_path / "guidance_live.html").read_text()

    class Cells(HTMLParser):
        def __init__(self):
            super().__init__()
            self.seen, self.missing, self.refresh = 0, 0, False

        def handle_starttag(self, tag, attrs):
            a = dict(attrs)
            self.seen += tag == "td" and a.get("class") == "seen"
            self.missing += tag == "td" and a.get("class") == "missing"
            self.refresh |= tag == "meta" and a.get("http-equiv") == "refresh"

    cells = Cells()
    cells.feed(text)
    assert cells.refresh and (cells.seen, cells.missing) == (1, 8)  # cam00's ninths; the others have none
    assert "cam&lt;2&gt;" in text and "cam<2>" not in text  # names are escaped
    assert CORNER.replace("'", "&#x27;") in text and "cam00 (12)" in text and "2 of 3 cameras need more" in text
    assert "walk time 3.5 s" in text
    msg.final = True
    page(msg)
    final = Cells()
    final.feed((tmp_path / "guidance_live.html").read_text())
    assert not final.refresh and "final guidance" in (tmp_path / "guidance_live.html").read_text()
    assert not list(tmp_path.glob(".*.tmp"))
