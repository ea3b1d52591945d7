"""Live ballbar capture from a serial sensor (imports core/ and ballbar/, never OctoPrint).

Readings are the change of bar length in mm, positive = bar longer, everywhere inside this
floor; times are in s. Modules, bottom up:

* :mod:`.sensor_error` (SensorError), :mod:`.convention` (units and sign), :mod:`.line_splitter`
  (bounded line splitting), :mod:`.diagnostics` (fault counts and limits);
* the protocol parsers, fed bytes, returning samples: :mod:`.parsing` (shared),
  :mod:`.protocol_kincomp` (KinComp's own line protocol, device clock),
  :mod:`.protocol_plain` (one number a line, host time), :mod:`.protocol_pattern` (a regular
  expression and a scale); :mod:`.config` (the validated settings, and the parser they make);
* :mod:`.retime` (host arrival times -> sample times), :mod:`.run_detection` (runs, dwells and
  feed-in/out found in the data), :mod:`.stream` (raw stream <-> native trace);
* :mod:`.live` (current reading, moving chart, noise), :mod:`.ports` (list and open ports),
  :mod:`.capture` (the capture thread and its states), :mod:`.virtual` (a SIMULATED sensor on
  a pseudo-terminal or loopback socket).
"""

from .capture import STATES, Capture, CaptureResult
from .config import PROTOCOLS, SensorConfig
from .ports import list_ports
from .sensor_error import SensorError
from .stream import RawStream, parse_raw_stream, trace_from_stream

__all__ = [
    "Capture",
    "CaptureResult",
    "STATES",
    "PROTOCOLS",
    "SensorConfig",
    "SensorError",
    "list_ports",
    "RawStream",
    "parse_raw_stream",
    "trace_from_stream",
]
