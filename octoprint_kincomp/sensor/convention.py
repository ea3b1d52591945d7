"""Units and sign of a sensor's readings, and their conversion to KinComp's convention.

Inside KinComp a reading is the change of bar length in **mm, positive = bar longer** (the
convention of the native trace format, ``calibration/ballbar/formats.py``). A sensor may send mm, um
or inch, and may read positive when the bar gets shorter (a dial indicator pushed in by a shortening
bar does). :class:`Convention` says which, and :meth:`Convention.to_mm` converts.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..core.messages import Msg
from .sensor_error import SensorError

UNITS = {"mm": 1.0, "um": 1e-3, "inch": 25.4}  # mm per unit
POSITIVE = ("longer", "shorter")  # what a positive reading means


@dataclass(frozen=True)
class Convention:
    units: str = "mm"
    longer_positive: bool = True

    def __post_init__(self):
        if self.units not in UNITS:
            raise SensorError(
                Msg(
                    "units must be one of %(choices)s, got %(got)s",
                    choices=", ".join(UNITS),
                    got=repr(self.units),
                ),
                "units",
            )

    @property
    def factor(self) -> float:
        """Signed mm (positive = longer) per unit of the sensor's reading."""
        return UNITS[self.units] * (1.0 if self.longer_positive else -1.0)

    def to_mm(self, value: float) -> float:
        return value * self.factor

    @staticmethod
    def parse_positive(text: str, field: str = "positive") -> bool:
        """``longer`` -> True, ``shorter`` -> False (what a positive reading means)."""
        t = str(text).strip().lower()
        if t not in POSITIVE:
            raise SensorError(
                Msg(
                    "%(field)s must be 'longer' or 'shorter', got %(got)s",
                    field=field,
                    got=repr(str(text)[:20]),
                ),
                field,
            )
        return t == "longer"
