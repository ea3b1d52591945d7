"""Issue 17, case 6: a Z move right after G28 never sends the head across the bed. Where
the printer homes is not known by default: G28 is followed by M114, and the firmware's
position report after it makes the homed axes known where they really are; until then a
move that needs them goes out as written (no correction moves an axis by more than the
correction itself)."""

from octoprint_kincomp.core.compensator import Compensator, Options
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.engines.select import make_compensator
from octoprint_kincomp.service.printing.queue import QueueCompensator, command_of
from octoprint_kincomp.service.settings.schema import defaults, engine_config

SKEW = Params.from_dict(
    {"squareness_um_per_m": {"xy": 800.0, "xz": 1500.0, "yz": -1200.0}, "backlash": {"x": 40.0}}
)


def words(line):
    return {w[0]: float(w[1:]) for w in line.split()[1:]}


def queue():
    _, options = engine_config(defaults(), None)  # the plugin's default: home unknown
    return QueueCompensator(SKEW, options, enabled=True)


def home(q, line, tags=None):
    """A G28 through the hook: the lines it sends (the M114's command) and the M114's tags
    (what OctoPrint hands to the sending hook)."""
    out = q.handle(line, tags)
    assert isinstance(out[-1], tuple) and out[-1][:2] == ("M114", None)
    return [command_of(o) for o in out], out[-1][2]


def test_prusaslicer_start_z_move_goes_out_as_written_until_the_home_is_known():
    q = queue()
    assert home(q, "G28", {"source:file"})[0] == ["G28", "M114"]
    assert q.handle("G1 Z.35 F7800", {"source:file"}) is None  # as written: X, Y unknown
    assert q.comp.known == (False, False, True)
    out = q.handle("G1 X110 Y110 F9000", {"source:file"})
    assert out is not None and out[-1].startswith("G1 X")  # compensated from here on


def test_the_position_report_after_g28_makes_the_home_known_at_x_max():
    q = queue()
    _, asked = home(q, "G28")
    assert not q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})  # before our M114: stale
    q.home_query_sent({"source:api"})  # somebody else's M114
    assert not q.home_query_out
    q.home_query_sent(asked)
    assert q.home_reported({"x": 220.0, "y": 0.0, "z": 0.0})  # homes at X max
    assert q.comp.known == (True, True, True)
    out = q.handle("G1 Z.35 F7800")
    ref = Compensator(SKEW, Options(home_mm=(220.0, 0.0, 0.0)))
    ref.process("G28")
    assert out == ref.process("G1 Z.35 F7800")
    # (the Z move stays a Z move: its X/Y correction goes first, in a move of its own)
    assert "X" not in words(out[-1]) and "Z" in words(out[-1])
    got = {}
    for o in out:
        got.update(words(o))
    # the head stays where it is, give or take the correction: the skew at Z=0.35 (< 1 um)
    # and X's backlash take-up (40 um / 2)
    assert abs(got["X"] - 220.0) <= 0.0215 and abs(got.get("Y", 0.0)) < 0.002


def test_a_move_before_the_report_takes_its_axes_out_of_the_learning():
    q = queue()
    _, asked = home(q, "G28")
    q.handle("G91")
    q.handle("G1 X-5")  # a jog queued before the report: the report is stale for X
    q.home_query_sent(asked)
    assert q.home_reported({"x": 220.0, "y": 0.0, "z": 0.0})
    assert q.comp.known == (False, True, True)
    for stale_all in ("T1", "G2 X5 Y5 I1 J0", "G29"):  # all axes may have moved
        q = queue()
        _, asked = home(q, "G28")
        q.handle(stale_all)
        known = q.comp.known  # (the arc's absolute end makes X and Y known by itself)
        q.home_query_sent(asked)
        assert not q.home_reported({"x": 220.0, "y": 0.0, "z": 0.0}), stale_all
        assert q.comp.known == known and not known[2]
    q = queue()
    _, asked = home(q, "G28")
    q.handle("G92 Y10")  # re-frames Y only
    q.home_query_sent(asked)
    assert q.home_reported({"x": 220.0, "y": 0.0, "z": 0.0})
    assert q.comp.known == (True, False, True)


def test_lines_queued_ahead_of_the_report_that_leave_the_homed_axis_alone():
    """Bambu Studio's start: G28 X, then a relative Z lift the file reader may queue before
    the answer to the M114 is read (OctoPrint queues the next file line on the G28's "ok"
    if the M114 has already left the queue). The report still gives X's home: the output
    from there on is the one of a printer whose home was known all along."""
    lines = [
        "G28 X",
        "G91",
        "G1 Z5 F1200",
        "G90",
        "G0 X128 F30000",
        "G0 Y254 F3000",
        "G1 X20 Y200 Z3",
        "G1 X25",
        "G1 X-0.2 Y5",
    ]
    q = queue()
    sent, asked = home(q, lines[0], {"source:file"})
    assert sent == ["G28 X", "M114"]
    for line in lines[1:4]:
        q.handle(line, {"source:file"})
    q.home_query_sent(asked)
    assert q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})
    got = [q.handle(line, {"source:file"}) for line in lines[4:]]
    ref = Compensator(SKEW, Options(home_mm=(0.0, None, None)))
    want = [ref.process(line) for line in lines]
    assert got == [None if w == line else w for w, line in zip(want[4:], lines[4:])]
    assert got[2] is not None and got[3] is not None  # compensated


def test_an_extruder_reset_before_the_answer_keeps_the_learning():
    q = queue()
    home(q, "G28", {"source:file"})
    q.handle("G92 E0", {"source:file"})  # (the usual line right after G28)
    assert q.awaiting_home == (0, 1, 2)
    q.handle("G92", {"source:file"})  # no words: X, Y, Z and E are set to 0
    assert q.awaiting_home == ()


def test_two_homings_queued_at_once_take_only_the_last_answer():
    """Outside a print OctoPrint queues a whole batch (a macro, a custom control) before it
    sends anything: the answer to the first M114 comes before the second G28 homes."""
    q = queue()
    first, asked_first = home(q, "G28 X")
    second, asked_second = home(q, "G28 Z")
    assert first == ["G28 X", "M114"] and second == ["G28 Z", "M114"]
    assert q.awaiting_home == (0, 2) and asked_first != asked_second
    q.home_query_sent(asked_first)
    assert not q.home_reported({"x": 0.0, "y": 80.0, "z": 12.0})  # before Z was homed
    q.home_query_sent(asked_second)
    assert q.home_reported({"x": 0.0, "y": 80.0, "z": 0.0})
    assert q.comp.known == (True, False, True) and q.comp.state.m[2] == 0.0


def test_an_m114_octoprint_never_sends_does_not_block_the_next_learning():
    """A cancelled print clears OctoPrint's send queue: an M114 queued by its G28 is never
    sent. The next homing's question is answered all the same; the old one, were it sent
    late, answers nothing."""
    q = queue()
    _, dropped = home(q, "G28 X")
    q.reset()  # the print is cancelled
    _, asked = home(q, "G28 X")
    q.home_query_sent(dropped)
    assert not q.home_query_out
    q.home_query_sent(asked)
    assert q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})
    assert q.comp.known[0]


def test_a_second_g28_before_the_answer_asks_again_for_every_axis_awaited():
    q = queue()
    sent, asked = home(q, "G28 X")
    assert sent == ["G28 X", "M114"]
    q.home_query_sent(asked)
    sent, asked = home(q, "G28 Y")
    assert sent == ["G28 Y", "M114"] and q.awaiting_home == (0, 1)
    assert not q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})  # the first answer: not ours
    q.home_query_sent(asked)
    assert q.home_reported({"x": 0.0, "y": 0.0, "z": 0.0})
    assert q.comp.known == (True, True, False)


def test_a_known_home_needs_no_question_and_a_partial_g28_asks_for_its_axes():
    s = dict(defaults(), home_mm=[0.0, 0.0, 0.0])
    params, options = engine_config(s, None)
    q = QueueCompensator(SKEW, options, enabled=True)
    assert q.handle("G28") is None and q.comp.known == (True, True, True)
    s = dict(defaults(), home_mm=[None, 0.0, 0.0])
    q = QueueCompensator(SKEW, engine_config(s, None)[1], enabled=True)
    q.handle("G28")
    assert q.awaiting_home == (0,)
    q = queue()
    _, asked = home(q, "G28")
    q.home_query_sent(asked)
    q.home_reported({"x": 220.0, "y": 200.0, "z": 0.0})
    q.handle("G1 X100 Y100 Z5")
    assert home(q, "G28 Z")[0] == ["G28 Z", "M114"] and q.awaiting_home == (2,)


def test_homing_with_an_unknown_home_keeps_q_drive_for_the_axes_it_did_not_home():
    """G28 Z with XZ skew and Z's home unknown: X's command depends on Z, but its drive
    stays where it was; once Z is learned, the next move starts from that drive."""
    comp = make_compensator(SKEW, Options(home_mm=(0.0, 0.0, None)))
    comp.process("G28")  # X, Y known at 0; Z unknown
    comp.homed_at([2], [None, None, 0.0])
    comp.process("G1 X50 Y50 Z20 F3000")
    drive_x = comp.writer.carriage(comp.state.m)[0]
    comp.process("G28 Z")
    assert comp.state.q_drive is not None and comp.state.q_drive[0] == drive_x
    comp.homed_at([2], [None, None, 0.0])
    assert comp.state.q_drive[0] == drive_x
