"""Serial ports: listing them, and opening one with a clear message when that fails.

Any pyserial URL works (``serial_for_url``): a device path (``/dev/ttyUSB0``, ``COM3``, a
pseudo-terminal), ``socket://127.0.0.1:PORT``, ``loop://`` ... Device paths are opened
exclusively (POSIX lock), so a port the printer or another program holds reports busy.

:func:`read_some` returns the bytes that have arrived, waiting at most about 0.1 s: a device
path reports how many bytes wait, so a read returns as soon as data is there (host time
stamps within a millisecond of arrival); pyserial's network handlers only say whether any
byte waits, so they are read in 10 ms slices.
"""

from __future__ import annotations

import errno
from typing import Dict, List

from ..core.messages import Msg
from .sensor_error import SensorError

READ_TIMEOUT_S = 0.1  # device paths: wait this long for a first byte, then take the rest
URL_TIMEOUT_S = 0.01  # network URLs: read whatever arrived within this time
READ_CHUNK = 65536


def list_ports() -> List[Dict[str, str]]:
    """The serial ports the system knows: [{"device", "description", "hwid"}]."""
    try:
        from serial.tools import list_ports as lp

        found = lp.comports()
    except Exception:
        return []
    return [
        {"device": p.device, "description": p.description or "", "hwid": p.hwid or ""}
        for p in sorted(found, key=lambda p: p.device)
    ]


def open_error(port: str, exc: BaseException) -> SensorError:
    """The SensorError (field ``port``) for an exception raised while opening ``port``."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code is None and isinstance(exc.__context__, OSError):
        code = exc.__context__.errno
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO) or "No such file" in text:
        msg = Msg(
            "port %(port)s does not exist: is the sensor plugged in? (see the list of ports)",
            port=port,
        )
    elif code in (errno.EACCES, errno.EPERM) or "ermission denied" in text:
        msg = Msg(
            "no permission to open %(port)s: add the user that runs OctoPrint to the "
            "'dialout' group (then log in again)",
            port=port,
        )
    elif code in (errno.EBUSY, errno.EAGAIN) or "exclusively lock" in text:
        msg = Msg(
            "port %(port)s is busy: another program (or OctoPrint's printer connection) "
            "has it open",
            port=port,
        )
    elif code == errno.ECONNREFUSED or "refused" in text:
        msg = Msg("nothing accepts connections at %(port)s", port=port)
    elif isinstance(exc, ValueError):
        msg = Msg("%(port)s is not a serial port or pyserial URL: %(error)s", port=port, error=text)
    else:
        msg = Msg("cannot open %(port)s: %(error)s", port=port, error=text)
    return SensorError(msg, "port")


def _network(port: str) -> bool:
    return "://" in port and not port.startswith("loop://")


def open_port(port: str, baudrate: int):
    """An open pyserial port, or SensorError (field ``port``) saying why not."""
    import serial

    if not port:
        raise SensorError(Msg("no sensor port is set"), "port")
    timeout = URL_TIMEOUT_S if _network(port) else READ_TIMEOUT_S
    try:
        return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout, exclusive=True)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise open_error(port, exc) from None


def read_some(ser) -> bytes:
    """The bytes that arrived (b"" after about 0.1 s without any); pyserial's exceptions
    (unplugged, read error) pass through."""
    if ser.timeout is not None and ser.timeout < READ_TIMEOUT_S:
        return ser.read(READ_CHUNK)
    return ser.read(min(max(ser.in_waiting, 1), READ_CHUNK))
