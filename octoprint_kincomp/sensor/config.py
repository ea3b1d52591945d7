"""The settings of a ballbar sensor connection, validated, and the parser they make.

``SensorConfig.from_dict`` takes the plain values the plugin stores (JSON types) and raises
:class:`~.errors.SensorError` naming the setting at fault. Units: ``baudrate`` in bit/s,
``sample_rate_hz`` in Hz (0 = fit the rate from the arrival times), ``range`` as
``"low,high"`` in the sensor's own units before the sign, times in s.

``units`` and ``positive`` (``longer``: a longer bar reads more) apply to the plain and pattern
protocols; a KinComp-protocol device declares its own in its header (defaults mm, longer).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Dict

from ..core.messages import Msg
from .convention import Convention
from .diagnostics import Diagnostics
from .parsing import Parser, parse_range
from .protocol_kincomp import KinCompParser
from .protocol_pattern import PatternParser, check_scale, compile_pattern
from .protocol_plain import PlainParser
from .sensor_error import SensorError

PROTOCOLS = ("kincomp", "plain", "pattern")
BAUDRATES = (
    9600,
    19200,
    38400,
    57600,
    115200,
    230400,
    250000,
    460800,
    500000,
    921600,
    1000000,
    2000000,
)


@dataclass
class SensorConfig:
    port: str = ""
    baudrate: int = 115200
    protocol: str = "kincomp"
    units: str = "mm"
    positive: str = "longer"
    pattern: str = ""
    scale: float = 1.0
    range: str = ""
    sample_rate_hz: float = 0.0
    max_bad_lines: int = 200
    no_data_timeout_s: float = 10.0

    @staticmethod
    def from_dict(d: Dict[str, Any]) -> SensorConfig:
        if not isinstance(d, dict):
            raise SensorError(Msg("sensor settings must be an object"))
        known = set(SensorConfig.__dataclass_fields__)
        for key in d:
            if key not in known:
                raise SensorError(
                    Msg(
                        "unknown sensor setting (allowed: %(allowed)s)",
                        allowed=", ".join(sorted(known)),
                    ),
                    key,
                )
        cfg = SensorConfig(**d)
        cfg.validate()
        return cfg

    def to_dict(self) -> Dict[str, Any]:
        return asdict(self)

    def validate(self) -> None:
        if not isinstance(self.port, str) or len(self.port) > 300:
            raise SensorError(Msg("port must be a device path or pyserial URL"), "port")
        self.baudrate = _number(self.baudrate, "baudrate", 50, 10_000_000, integer=True)
        if self.protocol not in PROTOCOLS:
            raise SensorError(
                Msg(
                    "protocol must be one of %(choices)s, got %(got)s",
                    choices=", ".join(PROTOCOLS),
                    got=repr(self.protocol),
                ),
                "protocol",
            )
        self.convention()
        parse_range(self.range, "range")
        self.sample_rate_hz = _number(self.sample_rate_hz, "sample_rate_hz", 0.0, 100_000.0)
        if 0 < self.sample_rate_hz < 1.0:
            raise SensorError(
                Msg("sample_rate_hz must be 0 (fit it) or at least 1"), "sample_rate_hz"
            )
        self.max_bad_lines = _number(self.max_bad_lines, "max_bad_lines", 0, 100_000, integer=True)
        self.no_data_timeout_s = _number(self.no_data_timeout_s, "no_data_timeout_s", 1.0, 600.0)
        if self.protocol == "pattern":
            compile_pattern(self.pattern)
            self.scale = check_scale(self.scale)

    def convention(self) -> Convention:
        return Convention(
            units=self.units, longer_positive=Convention.parse_positive(self.positive)
        )

    def make_parser(self) -> Parser:
        kw = dict(
            convention=self.convention(),
            range_raw=parse_range(self.range),
            diagnostics=Diagnostics(max_bad=self.max_bad_lines),
        )
        if self.protocol == "kincomp":
            return KinCompParser(diagnostics=kw["diagnostics"])
        if self.protocol == "plain":
            return PlainParser(**kw)
        return PatternParser(self.pattern, self.scale, **kw)


def _number(value, field: str, lo: float, hi: float, integer: bool = False):
    if isinstance(value, bool):
        value = None
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and lo <= v <= hi) or (integer and v != int(v)):
        raise SensorError(
            Msg(
                "%(field)s must be a number within %(lo)s..%(hi)s, got %(got)s",
                field=field,
                lo=f"{lo:g}",
                hi=f"{hi:g}",
                got=repr(value)[:30],
            ),
            field,
        )
    return int(v) if integer else v
