"""The klippy process of ``tests/support/klipper.py``: imports the copied klippy, wraps a few of
its methods to watch what it does, runs ``klippy.main()`` in batch mode and writes what it saw
to a JSON file (also when klippy exits on an error or crashes on its way out).

Run as ``python klipper_child.py '<json options>'`` (see ``klipper.run``). Watched:

* ``GCodeDispatch._process_commands``: one input line at a time, so that every response and
  every planned move knows its input line (1-based); after each G0-G3 line the toolhead's
  commanded position (after the move transform) and the G-code position (``positions``);
* ``GCodeDispatch.respond_raw``: every response with its line;
* ``Move.__init__``, ``LookAheadQueue.flush``, ``ToolHead._process_lookahead`` and
  ``ToolHead._drip_load_trapq``: every planned move with its timing (``record_moves``);
* ``keep_going``: ``_respond_error`` runs as for a host's command (the failed command is
  dropped, the run goes on) instead of ending the run as an error from a file does;
* ``steady_feed``: the batch-mode flush of the lookahead when an input chunk has no move and
  the wall-clock priming timer are suppressed (``klipper.py``'s module docstring).

Nothing of Klipper's code is copied here; this only calls and wraps it.
"""

import json
import os
import re
import sys

MOTION = re.compile(r"^\s*(?:N\d+\s*)?G0*[0-3](?:\D|$)", re.IGNORECASE)


def _move_dict(move, line, kind, t0):
    dt = move.accel_t + move.cruise_t + move.decel_t
    return {
        "line": line,
        "kind": kind,
        "kin": move.is_kinematic_move,
        "t0": t0,
        "t": dt,
        "p0": list(move.start_pos[:4]),
        "p1": list(move.end_pos[:4]),
        "d": move.move_d,
        "v0": move.start_v,
        "vc": move.cruise_v,
        "v1": move.end_v,
        "a": move.accel,
        "ta": move.accel_t,
        "tc": move.cruise_t,
        "td": move.decel_t,
    }


def _watch_lines(state, gcode):
    process = gcode.GCodeDispatch._process_commands

    def one_at_a_time(self, commands, need_ack=True):
        if not need_ack:  # a script run by a command or macro: the same input line
            return process(self, commands, need_ack)
        for line in commands:
            state["line"] += 1
            process(self, [line], need_ack)
            if state["want_positions"] and MOTION.match(line):
                th = self.printer.lookup_object("toolhead", None)
                gm = self.printer.lookup_object("gcode_move", None)
                if th is not None and gm is not None:
                    state["positions"].append(
                        [state["line"]] + list(th.commanded_pos[:4]) + list(gm.last_position[:4])
                    )

    gcode.GCodeDispatch._process_commands = one_at_a_time
    respond = gcode.GCodeDispatch.respond_raw

    def respond_raw(self, msg):
        state["responses"].append([state["line"], msg])
        return respond(self, msg)

    gcode.GCodeDispatch.respond_raw = respond_raw


def _keep_going(gcode):
    respond_error = gcode.GCodeDispatch._respond_error

    def as_from_a_host(self, msg):
        was, self.is_fileinput = self.is_fileinput, False
        try:
            return respond_error(self, msg)
        finally:
            self.is_fileinput = was

    gcode.GCodeDispatch._respond_error = as_from_a_host


def _record_moves(state, toolhead):
    init = toolhead.Move.__init__

    def move_init(self, *a, **kw):
        init(self, *a, **kw)
        self.kincomp_line = state["line"]

    toolhead.Move.__init__ = move_init
    flush = toolhead.LookAheadQueue.flush

    def flushed(self, lazy=False):
        res = flush(self, lazy)
        state["pending"].extend(res)
        return res

    toolhead.LookAheadQueue.flush = flushed
    process = toolhead.ToolHead._process_lookahead

    def process_lookahead(self, lazy=False):
        state["pending"] = []
        process(self, lazy)
        moves, state["pending"] = state["pending"], []
        t = self.print_time - sum(m.accel_t + m.cruise_t + m.decel_t for m in moves)
        for m in moves:
            state["moves"].append(_move_dict(m, getattr(m, "kincomp_line", -1), "move", t))
            t += state["moves"][-1]["t"]

    toolhead.ToolHead._process_lookahead = process_lookahead
    drip = toolhead.ToolHead._drip_load_trapq

    def drip_load(self, submit_move):
        state["pending"] = []
        start, end = drip(self, submit_move)
        moves, state["pending"] = state["pending"], []
        t = start
        for m in moves:
            state["moves"].append(_move_dict(m, getattr(m, "kincomp_line", -1), "drip", t))
            t += state["moves"][-1]["t"]
        return start, end

    toolhead.ToolHead._drip_load_trapq = drip_load


def _steady_feed(state, toolhead):
    import extras.motion_queuing as motion_queuing

    flush_debug = motion_queuing.PrinterMotionQueuing._flush_handler_debug

    def flush_handler_debug(self, eventtime):
        gio = self.printer.lookup_object("gcode_io", None)
        streaming = gio is not None and (gio.fd_handle is not None or gio.is_processing_data)
        if streaming and self.last_step_gen_time >= self.need_flush_time - 1.5:
            # batch mode would flush past the queued moves here, and the toolhead would
            # flush its lookahead as if the input had run dry
            self.do_kick_flush_timer = True
            return self.reactor.NEVER
        return flush_debug(self, eventtime)

    motion_queuing.PrinterMotionQueuing._flush_handler_debug = flush_handler_debug

    def priming_handler(self, eventtime):
        # a 100 ms wall-clock timer: in batch mode it fires whenever klippy runs slower
        # than real time, not when the input runs dry
        self.reactor.unregister_timer(self.priming_timer)
        self.priming_timer = None
        return self.reactor.NEVER

    toolhead.ToolHead._priming_handler = priming_handler


def main(args):
    sys.path.insert(0, args["klippy"])
    os.chdir(os.path.dirname(args["result"]))
    import gcode
    import klippy
    import serialhdl
    import toolhead

    state = {
        "line": 0,
        "responses": [],
        "positions": [],
        "moves": [],
        "pending": [],
        "want_positions": args["positions"],
    }
    _watch_lines(state, gcode)
    if args["keep_going"]:
        _keep_going(gcode)
    if args["record_moves"]:
        _record_moves(state, toolhead)
    if args["steady_feed"]:
        _steady_feed(state, toolhead)

    def dump():
        keys = ("responses", "positions", "moves")
        with open(args["result"], "w") as f:
            json.dump(dict({k: state[k] for k in keys}, lines_done=state["line"]), f)

    disconnect = serialhdl.SerialReader.disconnect

    def dump_first(self):
        dump()  # before chelper frees its queues: a crash there loses nothing
        return disconnect(self)

    serialhdl.SerialReader.disconnect = dump_first
    sys.argv = ["klippy.py", args["config"], "-i", args["gcode"], "-o", args["serial"]]
    sys.argv += ["-v", "-d", args["dictionary"], "-l", args["log"]]
    code = 0
    try:
        klippy.main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        dump()
    sys.exit(code)


if __name__ == "__main__":
    main(json.loads(sys.argv[1]))
