"""The simulated printer's firmware side (ballbar/sim/): the play of its drives."""

import pytest

from octoprint_kincomp.ballbar.sim.play import Play
from octoprint_kincomp.core.params import Params


def test_play_operator():
    pl = Play(Params.from_dict({"backlash": {"x": 100.0}}))
    assert pl.carriage(0, 0.0) == 0.0
    assert pl.carriage(0, 1.0) == pytest.approx(1.0 - 0.05)
    assert pl.carriage(0, 0.95) == pytest.approx(0.95)  # inside the play: carriage stays
    assert pl.carriage(0, 0.92) == pytest.approx(0.95)
    assert pl.carriage(0, 0.5) == pytest.approx(0.55)
