"""Plain readings: one number a line, time-stamped on arrival by the host.

What the device sends: ``0.01234`` (a decimal number, optional sign and exponent) and a line
end, nothing else; lines starting with ``#`` are comments. The units and the sign come from
the settings (:class:`~.convention.Convention`), the range too (in those units).

Timing: the host stamps each chunk of bytes when the read returns, so a sample's time is its
true time plus the USB-serial latency and buffering: a USB full-speed CDC device delivers
every 1 ms frame, an FTDI-style adapter every 1-16 ms (its latency timer), and OctoPrint's
host adds scheduling jitter; several lines often arrive in one chunk with one time. Typical
error: 1-16 ms, always late, in bursts. :mod:`.retime` re-times the samples from their line
numbers (a device that samples at a steady rate: t = t0 + n / rate, rate and t0 fitted to the
lower envelope of the arrival times), and the run detection and analysis use features of the
data itself (dwells, feed-in/feed-out steps), so a constant delay does not matter.
"""

from __future__ import annotations

from typing import Optional

from .parsing import Parser, Sample, parse_number


class PlainParser(Parser):
    name = "plain"

    def _line(self, text: str, t_host: float) -> Optional[Sample]:
        if text.startswith("#"):
            return None
        return Sample(t_host, self.reading_mm(parse_number(text)), self.seq)
