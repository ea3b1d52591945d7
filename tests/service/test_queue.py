"""The queuing hook's adapter (QueueCompensator) without OctoPrint: results as OctoPrint's
comm layer normalises them, pre-compensated prints, errors (suppressed, held back until
resumed, or sent as written), parameters that wait for the next print (issue 3)."""

from unittest import mock

import pytest

from octoprint_kincomp.core.compensator import LimitError, Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.service.printing.queue import QueueCompensator

SKEW = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}, "backlash": {"x": 20.0}})


def normalize(result, cmd="X", cmd_type=None, tags=None):
    """What OctoPrint's comm layer makes of a queuing-hook result."""
    from octoprint.util.comm import _normalize_command_handler_result

    return _normalize_command_handler_result(cmd, cmd_type, None, None, tags or set(), result)


def test_hook_results_normalise_like_octoprint():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    assert q.handle("G28") is None
    res = q.handle("G1 X10 Y50 Z1 F3000")
    norm = normalize(res, "G1 X10 Y50 Z1 F3000")
    assert [c for c, *_ in norm] == res
    # x - 1000 um/m * 50 mm = 9.950, plus half the 20 um take-up: after homing the direction of
    # the last motion is unknown, so the first move takes up half the play either way
    assert norm[-1][0].startswith("G1 X9.96 Y50 ")
    # a reversal: the take-up comes out as its own command, in order
    res = q.handle("G1 X5")
    assert len(res) == 2 and len(normalize(res, "G1 X5")) == 2


def test_disabled_and_non_moves_pass_unchanged():
    q = QueueCompensator(SKEW, Options(), enabled=False)
    assert q.handle("G1 X10 Y10") is None
    q.set_enabled(True)
    for cmd in ("M105", "G28", "M104 S200"):
        assert q.handle(cmd) is None


def test_precompensated_file_lines_are_not_touched():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    q.print_started(precompensated=True)
    q.handle("G28", {"source:file"})
    assert q.handle("G1 X10 Y50 Z1", {"source:file", "fileline:3"}) is None
    # but commands from elsewhere (a jog during the print) are compensated
    q.handle("G28", {"source:api"})
    assert q.handle("G1 X10 Y50 Z1", {"source:api"}) is not None
    q.print_ended()
    assert q.skip_file is False


def test_failure_suppresses_and_reports():
    errors = []
    q = QueueCompensator(
        Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
        Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
        enabled=True,
        on_error=lambda c, e: errors.append((c, e)),
    )
    q.print_started(precompensated=False)
    f = {"source:file"}
    q.handle("G28", f)
    res = q.handle("G1 X0 Y100 Z1", f)  # compensated X would be -0.2: outside
    assert res == [] and normalize(res, "G1 X0 Y100 Z1") == []
    assert errors and isinstance(errors[0][1], LimitError)
    assert q.status()["errors"] == 1 and q.status()["last_error"]["command"] == "G1 X0 Y100 Z1"
    # the refused line changed nothing: the position before it is still known
    assert q.comp.known == (True, True, True) and q.comp.state.m == [0.0, 0.0, 0.0]
    # until the print resumes or ends, the print's later moves are held back (not sent as
    # written); other commands, and moves from scripts or the user, still go through
    assert q.handle("G1 X10 Y10 Z1", f) == [] and q.handle("g01 x5", f) == []
    assert q.handle("M104 S0", f) is None
    assert q.handle("G28", {"source:script"}) is None
    assert q.handle("G1 X10 Y50 Z5", {"source:script"}) is not None
    assert q.status()["held_moves"] == 2 and q.status()["halted"]
    q.resume()
    assert q.handle("G1 X10 Y10 Z1", f) is not None


def test_after_a_refused_line_the_resumed_print_is_compensated_from_where_it_was():
    """XZ skew needs Z for every X command: forgetting positions after the error sent every
    later move as written until the next Z move. The refused line leaves the state as it was
    (take-up direction included), so the resumed print goes on compensated, exactly as a
    stream that never contained the refused line."""
    p = Params.from_dict(
        {"squareness_um_per_m": {"xz": 3000.0, "xy": 1000.0}, "backlash": {"x": 20.0, "y": 10.0}}
    )
    opts = Options(limits=(0, 200, 0, 200, 0, 200), policy="error")
    q = QueueCompensator(p, opts, enabled=True, on_error=lambda c, e: None)
    ref = QueueCompensator(p, opts, enabled=True)
    q.print_started(precompensated=False)
    f = {"source:file"}
    before = ["G28", "G1 X50 Y50 Z10 F3000", "G1 X60 Y40", "G1 X55 Y45"]
    for line in before:
        q.handle(line, f)
        ref.handle(line, f)
    assert q.handle("G1 X0.001 Y199", f) == []  # X command < 0 at Y=199: refused
    assert q.comp.known == (True, True, True)
    assert q.handle("G1 X70 Y70", f) == [] and q.halted  # held until resumed
    q.resume()
    for line in ("G1 X80 Y60", "G1 X30 Y90", "G1 X40 Y80 Z12"):
        got = q.handle(line, f)
        assert got is not None and got == ref.handle(line, f), line
    assert q.comp.report.untouched_unknown == 0


def test_failure_outside_a_print_suppresses_only_that_command():
    q = QueueCompensator(
        Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
        Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
        enabled=True,
        on_error=lambda c, e: None,
    )
    q.handle("G28")
    assert q.handle("G1 X0 Y100 Z1") == []
    assert not q.status()["halted"]
    q.handle("G28")
    assert q.handle("G1 X10 Y100 Z1") is not None


def test_malformed_move_passes_but_is_reported_and_forgets_the_position():
    seen = []
    q = QueueCompensator(
        SKEW, Options(), enabled=True, on_untouched=lambda c, why: seen.append((c, why))
    )
    q.handle("G28")
    q.handle("G1 X50 Y50")
    assert q.handle("G1 X80 Y80 Q") is None  # sent as written: the firmware may run it
    assert seen == [("G1 X80 Y80 Q", "malformed")]
    # the next move is not computed from the stale start: X-only needs Y, now unknown
    assert q.handle("G1 X90") is None and seen[-1] == ("G1 X90", "unknown")


def test_failure_pass_through_when_chosen():
    q = QueueCompensator(
        Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
        Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
        enabled=True,
        pass_through_on_error=True,
        on_error=lambda c, e: None,
    )
    q.handle("G28")
    assert q.handle("G1 X0 Y100 Z1") is None
    assert q.status()["passed_on_error"] == 1


@pytest.mark.parametrize("failing", ["compensator", "kernel offered first"])
def test_internal_exception_never_sends_the_move_raw(failing):
    errors = []
    q = QueueCompensator(SKEW, Options(), enabled=True, on_error=lambda c, e: errors.append(e))
    q.handle("G28")
    boom = mock.Mock(side_effect=RuntimeError("boom"))
    kernel = boom if failing == "kernel offered first" else None  # (None: none offered)
    with mock.patch.object(q.comp, "process", boom), mock.patch.object(q, "_route", kernel):
        assert q.handle("G1 X10 Y10") == []
    assert boom.called and len(errors) == 1 and q.status()["errors"] == 1
    assert q.comp.known == (False, False, False)  # nothing builds on a half-updated state


def test_new_params_wait_for_the_next_print_unless_forced():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    q.print_started(False)
    new = Params.from_dict({"scale_ppm": {"x": 500.0}})
    assert q.configure(new, Options(), True, immediately=False) is False
    assert q.params.hash() == SKEW.hash() and q.status()["pending_params_hash"] == new.hash()
    q.print_ended()
    assert q.params.hash() == new.hash()
    # forced: applies now and keeps the tracked position
    q.handle("G28")
    q.handle("G1 X100 Y100 Z1")
    q.print_started(False)
    q.handle("G28")
    q.handle("G1 X100 Y100 Z1")
    assert q.configure(SKEW, Options(), True, immediately=True) is True
    assert q.comp.known == (True, True, True)
    out = q.handle("G1 X100 Y101")
    # new model at once: x = 100 - 1000 um/m * 101 mm = 99.899, X reverses: -10 um backlash
    assert out is not None and out[-1].startswith("G1 X99.889 Y101")


def test_reset_forgets_positions():
    q = QueueCompensator(SKEW, Options(), enabled=True)
    q.handle("G28")
    q.reset()
    assert q.handle("G1 X10") is None  # unknown position: passes untouched (counted)
    assert q.status()["report"]["untouched_unknown_position"] == 1


def test_switching_on_mid_print_waits_for_the_next_print_unless_forced():
    """Turning compensation on (or off) in the middle of a print would shift every later
    move by the correction; like new parameters it waits for the next print."""
    q = QueueCompensator(SKEW, Options(), enabled=False)
    q.print_started(False)
    new = Params.from_dict({"squareness_um_per_m": {"xy": -500.0}})
    assert q.configure(new, Options(), True, immediately=False) is False
    assert q.status()["pending_enabled"] is True
    f = {"source:file"}
    q.handle("G28", f)
    assert q.handle("G1 X10 Y50 Z1", f) is None  # still off, and not with the old params
    q.print_ended()
    assert q.enabled and q.params.hash() == new.hash() and q.pending is None
    # switching off waits too; forcing applies at once
    q.print_started(False)
    assert q.configure(new, Options(), False, immediately=False) is False and q.enabled
    assert q.configure(new, Options(), True, immediately=False) is True  # back to as-is
    assert q.pending is None
    assert q.configure(new, Options(), False, immediately=True) is True and not q.enabled


def test_a_failing_notification_never_lets_the_raw_move_out():
    def boom(*args):
        raise RuntimeError("notification failed")

    q = QueueCompensator(
        Params.from_dict({"squareness_um_per_m": {"xy": 2000.0}}),
        Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
        enabled=True,
        on_error=boom,
        on_untouched=boom,
    )
    assert q.handle("G1 X5") is None  # unknown position: sent as written, as reported
    q.handle("G28")
    assert q.handle("G1 X0 Y100 Z1") == []  # refused, and still refused


def test_a_line_sent_as_written_after_an_error_forgets_the_position():
    """With "send as written on error" the refused line does go out: the head is where the
    program put it, not where the compensator left it (review finding: the next Y-only move
    drove X back by 100 mm)."""
    q = QueueCompensator(
        Params.from_dict({"squareness_um_per_m": {"xy": 1000}}),
        Options(limits=(0, 200, 0, 200, 0, 200), policy="error"),
        enabled=True,
        pass_through_on_error=True,
    )
    for cmd in ("G28", "G1 X100 Y100 Z1"):
        q.handle(cmd, {"source:file"})
    assert q.handle("G1 X0.05 Y150", {"source:file"}) is None  # sent as written
    assert q.comp.known == (False, False, False)
    assert q.handle("G1 Y160", {"source:file"}) is None  # no X move the program never made


@pytest.mark.parametrize("home_mm", [(0.0, 0.0, 0.0), (None, None, 0.0)])
def test_the_kernel_offered_first_writes_what_the_compensator_writes(home_mm):
    # the hook offers every line to the compiled kernel without Compensator.process (one
    # call less per line; the engine contract decides): the same lines, the same report,
    # whichever takes each line
    from octoprint_kincomp.engines.select import make_compensator
    from octoprint_kincomp.service.printing.queue import FILE_TAG, command_of

    lines = [
        "G28",
        "G1 X10 Y10 Z1 F3000",
        "G1 X20 Y5 E1",
        "G2 X30 Y15 I10 J0 E2",
        "G1 X5 Y5 E3",
        "M400",
        "G1 X-0 Y0",
        "G91",
        "G1 X2",
        "G90",
        "G1 X8 Y3",
        "G1 X10 Y10 Z1 ; comment",
        "G0 X12",
        "G1 X128 Y28",
        "G1 X12 Y8",
    ]
    options = Options(home_mm=home_mm)
    q = QueueCompensator(SKEW, options, enabled=True)
    comp = make_compensator(SKEW, options)
    kernel = q.comp.fast
    if comp.fast is not None:  # the compiled engine: count what the kernel is offered
        assert q._route is not None
        kernel = q.comp.fast = mock.Mock(wraps=kernel)
        q._reroute()
    for line in lines:
        raw = q.handle(line, {FILE_TAG})
        want = comp.process(line)
        got = [line] if raw is None else [command_of(e) for e in raw]
        want = [line] if want is line else list(want)
        if line == "G28" and None in home_mm:
            # the question where it homed, and the firmware's answer: X0 Y0 (known to the
            # reference at once)
            want.append("M114")
            q.home_query_sent(raw[-1][2])
            assert q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})
            comp.homed_at((0, 1), (0.0, 0.0, None))
        assert got == want, line
    assert q.comp.report.to_dict() == comp.report.to_dict()
    assert q.comp.report.moves_compensated >= 10
    if comp.fast is not None:  # every line was offered (the G28 before its question)
        assert kernel.line.call_count == len(lines)


@pytest.mark.parametrize("gate", ["off", "precompensated file", "halted", "home asked"])
def test_no_line_goes_to_the_kernel_first_while_the_gate_is_closed(gate):
    # the hook offers lines to the kernel only while compensation is on, the file is not
    # passed through, the print is not halted and no home question is open: otherwise the
    # reference path decides (held back, untouched, ...), and the route opens again after
    from octoprint_kincomp.service.printing.queue import FILE_TAG

    def queue():
        home = (None, None, 0.0) if gate == "home asked" else (0.0, 0.0, 0.0)
        q = QueueCompensator(SKEW, Options(home_mm=home), enabled=gate != "off")
        q.print_started(precompensated=gate == "precompensated file")
        asked = q.handle("G28", {"source:api"})
        if gate != "home asked":
            q.handle("G1 X10 Y10 Z1", {"source:api"})
        if gate == "halted":
            q.halted = True  # (as after a failure in the print)
        return q, asked

    (q, asked), (ref, _) = queue(), queue()
    if q.comp.fast is None:
        pytest.skip("no compiled kernel here")
    assert ref.comp.state is not None  # (the state back from its kernel: Python's alone)
    ref.comp.fast = None  # the reference path alone
    ref._reroute()
    q.comp.fast = mock.Mock(wraps=q.comp.fast)
    q._reroute()
    lines = ["G1 X20 Y15 Z2 E1", "G2 X30 Y25 I10 J0 E2", "G1 Z3 F600"]
    if gate == "home asked":  # (lines that leave the question open: X and Y stay put)
        lines = ["G1 Z2 F600", "G1 E1", "G1 Z3"]
    for line in lines:
        got, want = q.handle(line, {FILE_TAG}), ref.handle(line, {FILE_TAG})
        assert got == want, line
        if gate in ("off", "precompensated file"):
            assert got is None  # sent as written
        elif gate == "halted":
            assert got == []  # held back
    assert q._route is None
    # (with the home question open Compensator.process still offers the kernel each move:
    # the hook only does not offer it first)
    offered = q.comp.fast.line.call_count
    assert offered == (3 if gate == "home asked" else 0)
    if gate == "off":
        q.set_enabled(True)
    elif gate == "precompensated file":
        q.print_ended()
    elif gate == "halted":
        q.resume()
    else:
        q.home_query_sent(asked[-1][2])
        assert q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})
    q.handle("G1 X20 Y15", {FILE_TAG})
    assert q._route is not None
    assert q.comp.fast.line.call_count == offered + 1  # offered again


def test_an_empty_command_is_neither_compensated_nor_counted(engine):
    # (the kernel takes a blank line as Compensator.process does, counting it: the hook
    # must not offer it one, as it does not hand it to the reference path either)
    params = Params.from_dict({"squareness_um_per_m": {"xy": 1000.0}})
    q = QueueCompensator(params, Options(home_mm=(0.0, 0.0, 0.0)), enabled=True)
    out = [q.handle(line, {"source:file"}) for line in ("G28", "G1 X10 Y10", "", "G1 X20", "")]
    assert out[2] is None and out[4] is None  # (sent as it is)
    assert q.comp.report.lines == 3 and q.comp.report.lines_out == 3
