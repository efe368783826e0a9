"""The replay's pacing (yowo_bringup.replay.Pacer): at `rate` x real time, as fast as possible
at rate 0, and without waiting out the silence between recordings read as one."""

import pytest

from yowo_bringup.replay import Pacer

S = 1_000_000_000


def test_messages_are_due_at_the_rate_of_the_recording():
    pacer = Pacer(2.0)
    assert pacer.delay_s(10 * S, now_s=100.0) == 0.0  # the first message sets the clock
    assert pacer.delay_s(12 * S, now_s=100.0) == pytest.approx(1.0)  # 2 s of recording at 2x
    assert pacer.delay_s(12 * S, now_s=100.4) == pytest.approx(0.6)
    pacer.shift(3.0)  # paused 3 s (a catch-up): later messages come that much later
    assert pacer.delay_s(12 * S, now_s=100.4) == pytest.approx(3.6)
    assert Pacer(0.0).delay_s(50 * S, now_s=0.0) == 0.0


def test_the_silence_between_two_walks_is_not_waited_out():
    """A second walk recorded a day after the first plays right after it, at the same rate."""
    day = 86_400 * S
    pacer = Pacer(1.0, gaps_ns=[(20 * S, 20 * S + day)])
    assert pacer.delay_s(0, now_s=0.0) == 0.0
    assert pacer.delay_s(19 * S, now_s=0.0) == pytest.approx(19.0)
    assert pacer.delay_s(20 * S + day, now_s=0.0) == pytest.approx(20.0)
    assert pacer.delay_s(25 * S + day, now_s=21.0) == pytest.approx(4.0)
    # A gap before the replay's first message (playing from inside the second walk) is not skipped.
    late = Pacer(1.0, gaps_ns=[(20 * S, 20 * S + day)])
    assert late.delay_s(21 * S + day, now_s=0.0) == 0.0
    assert late.delay_s(23 * S + day, now_s=0.0) == pytest.approx(2.0)
