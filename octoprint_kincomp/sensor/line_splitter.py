"""Bytes from a serial port to text lines, with bounded memory.

A line ends with LF, CR or CR LF (empty lines are dropped). A line longer than
``max_line`` bytes is not kept: it is reported as ``None`` (an over-long line), once per
``max_line`` bytes, so a stream that never sends a line end (wrong baud rate, binary
protocol) shows as a steady run of over-long lines while the buffer never grows beyond
``max_line`` bytes.
"""

from __future__ import annotations

from typing import List, Optional

DEFAULT_MAX_LINE = 200  # bytes


class LineSplitter:
    def __init__(self, max_line: int = DEFAULT_MAX_LINE):
        self.max_line = int(max_line)
        self._buf = bytearray()
        self._discarding = 0  # >0: inside an over-long line, bytes dropped since the last report

    def feed(self, data: bytes) -> List[Optional[bytes]]:
        """Complete lines in ``data`` (after what was fed before); ``None`` = over-long line."""
        out: List[Optional[bytes]] = []
        parts = data.replace(b"\r", b"\n").split(b"\n")
        last = len(parts) - 1
        for k, part in enumerate(parts):
            if self._discarding:
                self._discarding += len(part)
                while self._discarding > self.max_line:
                    out.append(None)
                    self._discarding -= self.max_line
                if k < last:  # the over-long line ended here
                    self._discarding = 0
                continue
            self._buf += part
            if k < last:
                if len(self._buf) > self.max_line:
                    out.append(None)
                elif self._buf:
                    out.append(bytes(self._buf))
                self._buf.clear()
            elif len(self._buf) > self.max_line:
                out.append(None)
                self._discarding = len(self._buf) - self.max_line
                self._buf.clear()
        return out

    def pending(self) -> int:
        """Bytes held for the line in progress (always <= max_line)."""
        return len(self._buf)
