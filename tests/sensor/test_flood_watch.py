"""A flood (sustained lines beyond the limit) against a backlog (lines held up, then read at
once): FloodWatch on host times and line counts as the capture's thread sees them."""

import pytest

from octoprint_kincomp.sensor.capture import BACKLOG_S, MAX_LINE_RATE, FloodWatch


def feed(watch, start_s, rate, seconds, lines=0, step_s=0.05):
    """Reads every ``step_s`` for ``seconds`` at ``rate`` lines/s; returns (the first flood
    rate or None, its time, the line count at the end)."""
    t = start_s
    while t < start_s + seconds - 1e-9:
        t += step_s
        lines += int(round(rate * step_s))
        flooded = watch.update(t, lines)
        if flooded is not None:
            return flooded, t, lines
    return None, t, lines


def test_a_normal_rate_is_no_flood_for_ever():
    watch = FloodWatch(0.0, 0)
    assert feed(watch, 0.0, 10_000, 600.0)[0] is None
    assert feed(FloodWatch(0.0, 0), 0.0, MAX_LINE_RATE * 0.99, 60.0)[0] is None


def test_a_sensor_catching_up_after_a_stall_is_no_flood():
    """The false alarm of a busy CI machine: a 10 kHz bar's sender thread held up for
    1.5 s, then sending what it owes at once (22,479 lines in that second were reported a
    flood by the old per-second check)."""
    watch = FloodWatch(0.0, 0)
    _, t, lines = feed(watch, 0.0, 10_000, 5.0)
    assert watch.update(t + 1.5, lines) is None  # nothing arrives for 1.5 s
    lines += 15_000  # then the backlog, in one read
    assert watch.update(t + 1.55, lines) is None
    assert feed(watch, t + 1.55, 10_000, 30.0, lines)[0] is None


def test_a_backlog_beyond_a_second_at_the_limit_is_a_flood():
    watch = FloodWatch(0.0, 0)
    _, t, lines = feed(watch, 0.0, 10_000, 2.0)
    assert watch.update(t + 0.05, lines + int(MAX_LINE_RATE * BACKLOG_S) + 2_000) is not None


@pytest.mark.parametrize("rate, within_s", [(50_000, 0.75), (25_000, 4.2)])
def test_a_sustained_flood_is_found_and_its_rate_reported(rate, within_s):
    flooded, t, _ = feed(FloodWatch(0.0, 0), 0.0, rate, 10.0)
    assert flooded == pytest.approx(rate, rel=0.02)
    assert t <= within_s
