"""benchmarks/python_floor.py times a lower bound for any pure-Python compensator: it must
do the transform's arithmetic for real (else its ratio would bound nothing)."""

import importlib.util
import os

from octoprint_kincomp.core.compensator import Compensator
from octoprint_kincomp.core.kinematics import KinematicModel
from octoprint_kincomp.core.params import Params
from octoprint_kincomp.tools.benchmark import BENCH_PARAMS

HERE = os.path.dirname(os.path.abspath(__file__))
SCRIPT = os.path.join(HERE, "..", "..", "benchmarks", "python_floor.py")

PARAMS = {k: v for k, v in BENCH_PARAMS.items() if k != "backlash"}  # (the affine part)


def _floor_copy():
    spec = importlib.util.spec_from_file_location("python_floor", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.floor_copy


def _numbers(line):
    return {w[0]: float(w[1:]) for w in line.split()[1:] if w[0] in "XYZE"}


def test_the_floor_loop_writes_the_compensated_positions(tmp_path):
    src, dst = tmp_path / "in.gcode", tmp_path / "out.gcode"
    program = ["G28", "G1 X10 Y20 Z0.3 F3000", "; a comment", "G1 X150.5 Y80.25 E1.5"]
    program += ["G0 X200 Y190", "M104 S0"]
    src.write_text("".join(line + "\n" for line in program))
    params = Params.from_dict(PARAMS)
    _floor_copy()(str(src), str(dst), KinematicModel(params).inverse_rows)
    got = dst.read_text().splitlines()
    assert len(got) == len(program)
    comp = Compensator(params)
    for line, floor in zip(program, got):
        ref = comp.process(line)
        if not line.startswith("G1 ") and not line.startswith("G0 "):
            assert floor == line
            continue
        want, have = _numbers(ref if isinstance(ref, str) else ref[-1]), _numbers(floor)
        for axis in "XY":
            assert abs(have[axis] - want[axis]) <= 0.0005
            assert have[axis] != _numbers(line)[axis]  # (moved by the model: not a copy)
        assert have.get("E") == _numbers(line).get("E")
