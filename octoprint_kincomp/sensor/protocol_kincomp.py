"""KinComp's own ballbar line protocol, version 1 (the best timing: the device's clock).

What the device sends (ASCII, one record a line, LF or CR LF)::

    KINCOMP-BALLBAR 1            header: protocol name and major version (1 or 1.x)
    # sensor: DIY LVDT bar       optional "# key: value" lines (see KEYS)
    # units: mm
    # positive: longer
    # sample_rate_hz: 500
    # resolution_um: 0.5
    # range: -2.5,2.5
    4294966296,1.000412          samples: t_us,reading
    1000,1.000398                (t_us wrapped at 2^32: 2000 us after the sample before)

* ``t_us``: the device's free-running microsecond clock, an unsigned integer; a 32-bit counter
  (e.g. Arduino ``micros()``) wraps every 71.6 min and is unwrapped here. A value that goes
  backwards (other than by a wrap) is a ``clock`` fault; after a repeated header it is taken
  as a device restart (noted). A forward jump of more than 10 s is accepted only when the next
  sample confirms it.
* ``reading``: a decimal number in ``units`` (mm, um or inch; default mm); ``positive: longer``
  (default) means a longer bar reads more; ``shorter`` flips the sign. Internally everything
  is mm, positive = bar longer. ``range: low,high`` (in ``units``, as sent) is the sensor's
  measuring range; readings outside it are ``out_of_range`` faults.
* Fields after the second are reserved and ignored; lines starting with ``#`` that are not
  ``# key: value`` are comments. Keys other than KEYS are kept as ``sensor_<key>`` metadata
  (at most 10).
* Samples before the first header are dropped (counted in ``waiting_for_header``): the units
  and sign are not known yet. The device must send the header block when it starts and repeat
  it at least every 5 s, between two samples, so that a host opening the port mid-stream
  catches it. A repeated header must not change ``units``, ``positive`` or ``range`` once
  samples have been taken (that fails the stream).
"""

from __future__ import annotations

import re
from typing import Optional

from ..core.messages import Msg
from .convention import UNITS, Convention
from .parsing import BadLine, Parser, Sample, parse_number, parse_range
from .sensor_error import SensorError

NAME = "KINCOMP-BALLBAR"
VERSION = 1
HEADER = re.compile(r"KINCOMP-BALLBAR\s+(\d+)(?:\.(\d+))?(?:\s.*)?")
META = re.compile(r"#\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*)")
KEYS = ("sensor", "units", "positive", "range", "sample_rate_hz", "resolution_um", "simulated")
MAX_EXTRA_KEYS = 10
US32 = 1 << 32
MAX_GAP_US = 10_000_000
CONVENTION_KEYS = ("units", "positive", "range")
DEFAULTS = {"units": "mm", "positive": "longer", "range": ""}


class KinCompParser(Parser):
    name = "kincomp"
    device_clock = True

    def __init__(self, **kw):
        super().__init__(**kw)
        self.header_seen = False
        self.version = ""
        self.waiting_for_header = 0
        self.restarts = 0
        self._declared = {}  # units/positive/range as the device declared them
        self._last_raw: Optional[int] = None
        self._us = 0  # unwrapped device time of the last sample, us
        self._jump_raw: Optional[int] = None
        self._restart_ok = False
        self._rate = 0.0

    def _line(self, text: str, t_host: float) -> Optional[Sample]:
        if text.startswith(NAME):
            self._header(text)
            return None
        if text.startswith("#"):
            m = META.fullmatch(text)
            if m and self.header_seen:  # before the header: not known to belong to it
                self._meta(m.group(1).lower(), m.group(2).strip())
            return None
        parts = text.split(",")
        if len(parts) < 2 or not parts[0].strip().isdigit():
            raise BadLine("garbage")
        raw_t = int(parts[0].strip())
        value = parse_number(parts[1])
        if not self.header_seen:
            self.waiting_for_header += 1
            return None
        mm = self.reading_mm(value)
        self._clock(raw_t)
        return Sample(self._us * 1e-6, mm, self.seq)

    def _header(self, text: str) -> None:
        m = HEADER.fullmatch(text)
        if not m:
            raise BadLine("header")
        if int(m.group(1)) != VERSION:
            raise SensorError(
                Msg(
                    "the sensor speaks %(name)s version %(version)s; this KinComp reads version "
                    "%(supported)s",
                    name=NAME,
                    version=m.group(1),
                    supported=VERSION,
                )
            )
        self.version = m.group(1) + (f".{m.group(2)}" if m.group(2) else "")
        if self.header_seen and self._last_raw is not None:
            self._restart_ok = True  # a repeated header may precede a restarted clock
        self.header_seen = True

    def _meta(self, key: str, value: str) -> None:
        value = value[:60]
        try:
            if key == "units":
                Convention(units=value.lower())
            elif key == "positive":
                Convention.parse_positive(value)
            elif key == "range":
                parse_range(value)
            elif key in ("sample_rate_hz", "resolution_um"):
                number = parse_number(value)
                if number <= 0:
                    raise BadLine("header")
                if key == "sample_rate_hz":
                    self._rate = number
        except (SensorError, BadLine):
            raise BadLine("header") from None
        if key in CONVENTION_KEYS:
            self._declare(key, value.lower())
            return
        if key == "simulated":
            self.meta["simulated"] = "true" if value.lower() == "true" else "false"
            return
        name = "sensor_name" if key == "sensor" else f"sensor_{key}"
        if name in self.meta or len(self.meta) < len(KEYS) + MAX_EXTRA_KEYS:
            self.meta[name] = value

    def _declare(self, key: str, value: str) -> None:
        old = self._declared.get(key, DEFAULTS[key])
        if key == "range":
            value = ",".join(f"{v:g}" for v in parse_range(value))
        if value == old:
            return
        if self._last_raw is not None:
            raise SensorError(
                Msg(
                    "the sensor changed '%(key)s' from %(old)s to %(new)s in the "
                    "middle of the stream",
                    key=key,
                    old=repr(old),
                    new=repr(value),
                ),
                key,
            )
        self._declared[key] = value
        units = self._declared.get("units", "mm")
        positive = Convention.parse_positive(self._declared.get("positive", "longer"))
        self.convention = Convention(
            units=units if units in UNITS else "mm", longer_positive=positive
        )
        self.range_raw = parse_range(self._declared.get("range"))

    def _clock(self, raw: int) -> None:
        last = self._last_raw
        if last is None:
            self._last_raw = raw
            self._us = raw
            return
        if raw < US32 and last < US32:
            delta = (raw - last) % US32
            if delta >= US32 // 2:
                delta -= US32
        else:
            delta = raw - last
        if delta < 0:
            if not self._restart_ok:
                raise BadLine("clock")
            self.restarts += 1
            self.diagnostics.note(
                Msg(
                    "the sensor restarted (its clock began again); the time "
                    "across the restart is estimated"
                )
            )
            delta = int(1e6 / self._rate) if self._rate else 1000
        elif delta > MAX_GAP_US:
            jumped = self._jump_raw
            self._jump_raw = raw
            if jumped is None or not 0 <= (raw - jumped) % US32 <= MAX_GAP_US:
                raise BadLine("clock")
            self.diagnostics.note(
                Msg("the device clock jumped forward by %(s)s s", s=f"{delta * 1e-6:.1f}")
            )
        self._jump_raw = None
        self._restart_ok = False
        self._us += delta
        self._last_raw = raw

    def info(self):
        info = super().info()
        info["sensor_protocol"] = f"{NAME} {self.version or VERSION}"
        if self.restarts:
            info["sensor_restarts"] = str(self.restarts)
        return info
